// What kShared interpolates and how it decides that shaded neighbours agree (include/pbgi/
// shade.h, SharingOptions::tolerance): the shaded fields of a ShadeResult as one small vector,
// and the tolerances in the units of the batch. Internal.
#ifndef PBGI_SHADE_SHARED_VALUE_H_
#define PBGI_SHADE_SHARED_VALUE_H_

#include <algorithm>
#include <cmath>

#include "absl/types/span.h"
#include "glm/common.hpp"
#include "glm/vec3.hpp"
#include "pbgi/shade.h"

namespace pbgi::internal {

// The interpolated fields of a ShadeResult (the element counts are not interpolated).
struct SharedValue {
  float occlusion = 0, coverage = 0;
  glm::vec3 irradiance{0.0f}, glossy{0.0f};

  static SharedValue Of(const ShadeResult& r) {
    return {r.occlusion, r.coverage, r.irradiance, r.glossy};
  }
  SharedValue& operator+=(const SharedValue& o) {
    occlusion += o.occlusion, coverage += o.coverage, irradiance += o.irradiance;
    glossy += o.glossy;
    return *this;
  }
  friend SharedValue operator*(float w, const SharedValue& v) {
    return {w * v.occlusion, w * v.coverage, w * v.irradiance, w * v.glossy};
  }
  friend SharedValue operator+(SharedValue a, const SharedValue& b) { return a += b; }
  friend SharedValue operator-(const SharedValue& a, const SharedValue& b) {
    return a + (-1.0f) * b;
  }
  // An interpolated result: the values (clamped like the rasterizer's when `clamp`), no counts.
  ShadeResult Result(bool clamp) const {
    ShadeResult r;
    r.occlusion = occlusion, r.coverage = coverage, r.irradiance = irradiance, r.glossy = glossy;
    if (clamp) {
      r.occlusion = std::clamp(r.occlusion, 0.0f, 1.0f);
      r.coverage = std::clamp(r.coverage, 0.0f, 1.0f);
      r.irradiance = glm::max(r.irradiance, glm::vec3(0.0f));
      r.glossy = glm::max(r.glossy, glm::vec3(0.0f));
    }
    return r;
  }
};

// The largest spread (max - min over shaded neighbours) of each field that still counts as
// agreement: SharingOptions::tolerance, for radiance relative to the mean of the first shaded
// set (so that the tolerance has the same meaning whatever the scene's unit of radiance).
class Agreement {
 public:
  Agreement(const ShadeOptions& options, absl::Span<const ShadeResult* const> first_shaded);
  // Whether the values agree within the tolerances.
  bool operator()(absl::Span<const ShadeResult* const> values) const;
  // How far apart two results are, in tolerances (the largest field's |a - b| over its
  // tolerance; <= 1 agrees).
  float Spread(const ShadeResult& a, const ShadeResult& b) const;
  // Whether every field of `d` (a deviation, such as a fit's residual) lies within `scale`
  // tolerances of zero.
  bool Within(const SharedValue& d, float scale) const;

 private:
  float occlusion_ = 0;
  bool radiance_ = false, glossy_ = false;
  glm::vec3 irradiance_{0.0f}, glossy_tol_{0.0f};
};

}  // namespace pbgi::internal

#endif  // PBGI_SHADE_SHARED_VALUE_H_
