#include "raster/cluster_model.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "pbgi/sh.h"

namespace pbgi::internal {
namespace {

// Inverse of sh::ProjectClampedCosine's scale per coefficient: zonal factor * basis constant.
constexpr double kPi = sh::kPi;
constexpr double kBand0 = kPi * 0.282094791773878;
constexpr double kBand1 = 2.0 * kPi / 3.0 * 0.488602511902920;
constexpr double kBand2Xy = kPi / 4.0 * 1.092548430592079;
constexpr double kBand2Z = kPi / 4.0 * 0.315391565252520;
constexpr double kBand2Xx = kPi / 4.0 * 0.546274215296040;
constexpr float kY0 = 0.282094791773878f;
// Weight of the mean radiance in the regularised ratio P(w) / A(w).
constexpr float kRadianceBlend = 0.1f;

// The basis at w; the basis at -w flips the sign of band 1 only.
struct Basis9 {
  std::array<float, 9> y;
};

float Dot(const Sh9& c, const Basis9& b, float odd_sign) {
  const float even =
      c[0] * b.y[0] + c[4] * b.y[4] + c[5] * b.y[5] + c[6] * b.y[6] + c[7] * b.y[7] + c[8] * b.y[8];
  const float odd = c[1] * b.y[1] + c[2] * b.y[2] + c[3] * b.y[3];
  return even + odd_sign * odd;
}

float EvalSides(const Sh9& c, const Basis9& b, HitSides sides) {
  switch (sides) {
    case HitSides::kFront:
      return std::max(0.0f, Dot(c, b, 1.0f));
    case HitSides::kBack:
      return std::max(0.0f, Dot(c, b, -1.0f));
    case HitSides::kBoth:
      return std::max(0.0f, Dot(c, b, 1.0f)) + std::max(0.0f, Dot(c, b, -1.0f));
  }
  return 0.0f;
}

}  // namespace

ClusterMoments MomentsFromSh(const Sh9& c) {
  constexpr float kInv0 = static_cast<float>(1.0 / kBand0);
  constexpr float kInv1 = static_cast<float>(1.0 / kBand1);
  constexpr float kInvXy = static_cast<float>(1.0 / kBand2Xy);
  constexpr float kInvZ = static_cast<float>(1.0 / kBand2Z);
  constexpr float kInvXx = static_cast<float>(1.0 / kBand2Xx);
  ClusterMoments m;
  const float area = c[0] * kInv0;
  m.area = area;
  m.normal_sum = glm::vec3(c[3] * kInv1, c[1] * kInv1, c[2] * kInv1);
  m.mzz = (c[6] * kInvZ + area) * (1.0f / 3.0f);
  const float diff = c[8] * kInvXx;  // sum A (x^2 - y^2)
  m.mxx = 0.5f * (area - m.mzz + diff);
  m.myy = 0.5f * (area - m.mzz - diff);
  m.mxy = c[4] * kInvXy;
  m.myz = c[5] * kInvXy;
  m.mxz = c[7] * kInvXy;
  if (area > 0.0f) {
    const float frob = (m.mxx * m.mxx + m.myy * m.myy + m.mzz * m.mzz +
                        2.0f * (m.mxy * m.mxy + m.myz * m.myz + m.mxz * m.mxz)) /
                       (area * area);
    const float t = std::clamp((3.0f * frob - 1.0f) * 0.5f, 0.0f, 1.0f);
    constexpr float kIso = 0.8660254037844386f;  // sqrt(3) / 2
    m.even_factor = kIso + (1.0f - kIso) * t;
  }
  return m;
}

float ProjectedArea(const Cluster& cluster, const glm::vec3& w, HitSides sides,
                    ClusterModel model) {
  if (model == ClusterModel::kShEval) {
    return EvalSides(cluster.sh_area, Basis9{sh::Basis(w.x, w.y, w.z)}, sides);
  }
  const ClusterMoments m = MomentsFromSh(cluster.sh_area);
  if (!(m.area > 0.0f)) return 0.0f;
  // w^T M w = sum A_i (n_i.w)^2.
  const float m2 = m.mxx * w.x * w.x + m.myy * w.y * w.y + m.mzz * w.z * w.z +
                   2.0f * (m.mxy * w.x * w.y + m.myz * w.y * w.z + m.mxz * w.x * w.z);
  const float odd = glm::dot(m.normal_sum, w);  // sum A_i n_i.w
  // sum A_i |n_i.w| >= |sum A_i n_i.w| always; keeps both sides non-negative.
  const float even =
      std::max(std::sqrt(std::max(0.0f, m.area * m2)) * m.even_factor, std::fabs(odd));
  switch (sides) {
    case HitSides::kFront:
      return 0.5f * (even + odd);
    case HitSides::kBack:
      return 0.5f * (even - odd);
    case HitSides::kBoth:
      return even;
  }
  return 0.0f;
}

glm::vec3 ClusterRadiance(const Cluster& cluster, const glm::vec3& w, HitSides sides) {
  const Basis9 b{sh::Basis(w.x, w.y, w.z)};
  const float a = EvalSides(cluster.sh_area, b, sides);
  const float a_mean = kY0 * cluster.sh_area[0];
  const float den = a + kRadianceBlend * a_mean;
  glm::vec3 out(0.0f);
  if (!(den > 0.0f)) return out;
  for (int ch = 0; ch < 3; ++ch) {
    const float p = EvalSides(cluster.sh_power[ch], b, sides);
    const float p_mean = std::max(0.0f, kY0 * cluster.sh_power[ch][0]);
    out[ch] = (p + kRadianceBlend * p_mean) / den;
  }
  return out;
}

}  // namespace pbgi::internal
