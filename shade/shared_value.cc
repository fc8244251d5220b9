// Agreement (shade/shared_value.h).
#include "shade/shared_value.h"

#include <limits>

namespace pbgi::internal {

Agreement::Agreement(const ShadeOptions& options,
                     absl::Span<const ShadeResult* const> first_shaded) {
  const float tol = options.sharing.tolerance;
  occlusion_ = tol;
  radiance_ = options.raster.compute_radiance;
  glossy_ = radiance_ && options.raster.lobe != GlossyLobe::kNone;
  glm::dvec3 irr(0.0), gl(0.0);
  for (const ShadeResult* r : first_shaded) {
    irr += glm::abs(glm::dvec3(r->irradiance));
    gl += glm::abs(glm::dvec3(r->glossy));
  }
  const double n = double(std::max<size_t>(1, first_shaded.size()));
  irradiance_ = tol * glm::vec3(irr / n);
  glossy_tol_ = tol * glm::vec3(gl / n);
}

bool Agreement::operator()(absl::Span<const ShadeResult* const> values) const {
  if (values.empty()) return true;
  float occ_lo = values[0]->occlusion, occ_hi = occ_lo;
  float cov_lo = values[0]->coverage, cov_hi = cov_lo;
  glm::vec3 irr_lo = values[0]->irradiance, irr_hi = irr_lo;
  glm::vec3 gl_lo = values[0]->glossy, gl_hi = gl_lo;
  for (const ShadeResult* r : values.subspan(1)) {
    occ_lo = std::min(occ_lo, r->occlusion), occ_hi = std::max(occ_hi, r->occlusion);
    cov_lo = std::min(cov_lo, r->coverage), cov_hi = std::max(cov_hi, r->coverage);
    irr_lo = glm::min(irr_lo, r->irradiance), irr_hi = glm::max(irr_hi, r->irradiance);
    gl_lo = glm::min(gl_lo, r->glossy), gl_hi = glm::max(gl_hi, r->glossy);
  }
  // Written so that a NaN (never produced from finite inputs) disagrees.
  if (!(occ_hi - occ_lo <= occlusion_) || !(cov_hi - cov_lo <= occlusion_)) return false;
  if (radiance_) {
    const glm::vec3 d = irr_hi - irr_lo;
    if (!(d.x <= irradiance_.x && d.y <= irradiance_.y && d.z <= irradiance_.z)) return false;
  }
  if (glossy_) {
    const glm::vec3 d = gl_hi - gl_lo;
    if (!(d.x <= glossy_tol_.x && d.y <= glossy_tol_.y && d.z <= glossy_tol_.z)) return false;
  }
  return true;
}

float Agreement::Spread(const ShadeResult& a, const ShadeResult& b) const {
  auto ratio = [](float d, float tol) {
    d = std::abs(d);
    return d <= 0 ? 0.0f : (tol > 0 ? d / tol : std::numeric_limits<float>::infinity());
  };
  float s = std::max(ratio(a.occlusion - b.occlusion, occlusion_),
                     ratio(a.coverage - b.coverage, occlusion_));
  for (int c = 0; c < 3; ++c) {
    if (radiance_) s = std::max(s, ratio(a.irradiance[c] - b.irradiance[c], irradiance_[c]));
    if (glossy_) s = std::max(s, ratio(a.glossy[c] - b.glossy[c], glossy_tol_[c]));
  }
  return std::isnan(s) ? std::numeric_limits<float>::infinity() : s;
}

bool Agreement::Within(const SharedValue& d, float scale) const {
  // Written so that a NaN disagrees.
  if (!(std::abs(d.occlusion) <= scale * occlusion_) ||
      !(std::abs(d.coverage) <= scale * occlusion_)) {
    return false;
  }
  for (int c = 0; c < 3; ++c) {
    if (radiance_ && !(std::abs(d.irradiance[c]) <= scale * irradiance_[c])) return false;
    if (glossy_ && !(std::abs(d.glossy[c]) <= scale * glossy_tol_[c])) return false;
  }
  return true;
}

}  // namespace pbgi::internal
