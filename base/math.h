// Small geometry shared by several modules: pi in float, the orthonormal basis around a unit
// normal (the sampler, the reference integrator and the rasterizer's frames all use this one),
// and the GGX lobe's integral (the reference's sampler and the lobe-aware cut).
// The SH basis constants and pi in double live in the public pbgi/sh.h (its inline projection
// needs them); this header only derives from them. Internal.
#ifndef PBGI_BASE_MATH_H_
#define PBGI_BASE_MATH_H_

#include <algorithm>
#include <cmath>

#include "glm/vec3.hpp"
#include "pbgi/sh.h"

namespace pbgi::internal {

inline constexpr float kPiFloat = static_cast<float>(sh::kPi);

// An orthonormal basis (t, b) perpendicular to the unit normal n, right-handed with n (Duff et
// al., "Building an Orthonormal Basis, Revisited", JCGT 2017): continuous everywhere but across
// n.z = 0's sign flip, no normalization, no branch on the axis.
inline void OrthonormalBasis(const glm::vec3& n, glm::vec3* t, glm::vec3* b) {
  const float sign = std::copysign(1.0f, n.z);
  const float a = -1.0f / (sign + n.z);
  const float bb = n.x * n.y * a;
  *t = glm::vec3(1.0f + sign * n.x * n.x * a, sign * bb, -sign * n.x);
  *b = glm::vec3(bb, sign + n.y * n.y * a, -n.y);
}

// GGX as pbgi/raster.h defines it, D(x) = alpha^2 / (pi (1 + k x^2)^2), k = alpha^2 - 1 in
// (-1, 0]: the integral of 1 / (1 + k t^2)^2 over [0, x] is
//   x / (2 (1 + k x^2)) + atanh(m x) / (2 m),  m = sqrt(-k) = sqrt(1 - alpha^2)
// (the second term tends to x / 2 as m -> 0, the uniform lobe of alpha = 1).
inline double GgxLobeIntegral(double x, double alpha) {
  const double k = alpha * alpha - 1.0;
  const double m = std::sqrt(std::max(0.0, -k));
  const double at = m > 1e-8 ? std::atanh(m * x) / m : x;
  return 0.5 * (x / (1.0 + k * x * x) + at);
}

}  // namespace pbgi::internal

#endif  // PBGI_BASE_MATH_H_
