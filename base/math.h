// Small geometry shared by several modules: pi in float, and the orthonormal basis around a unit
// normal (the sampler, the reference integrator and the rasterizer's frames all use this one).
// The SH basis constants and pi in double live in the public pbgi/sh.h (its inline projection
// needs them); this header only derives from them. Internal.
#ifndef PBGI_BASE_MATH_H_
#define PBGI_BASE_MATH_H_

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

}  // namespace pbgi::internal

#endif  // PBGI_BASE_MATH_H_
