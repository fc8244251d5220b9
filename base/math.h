// Small geometry shared by several modules: pi in float, the orthonormal basis around a unit
// normal (the sampler, the reference integrator and the rasterizer's frames all use this one),
// the GGX lobe's integral (the reference's sampler and the lobe-aware cut), and the eigen
// decomposition of a symmetric 3x3 matrix (the builder's normal estimate, the tests of
// sh::PrincipalAxis).
// The SH basis constants and pi in double live in the public pbgi/sh.h (its inline projection
// needs them); this header only derives from them. Internal.
#ifndef PBGI_BASE_MATH_H_
#define PBGI_BASE_MATH_H_

#include <algorithm>
#include <array>
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

// Content whose area-weighted normal is `normal_sum` (not zero) and whose surfel centres span a
// box of extents `ext`: a surface with something standing on its front (the ground and a
// tree's trunk, the street and a building's wall) when the box reaches farther along the
// normal's dominant axis than the plane's tilt explains, by more than half of
// kStandingTolerance times the box's in-plane size (a curved patch whose normals lie within
// the flatness cone sags less). Returns how far to move the plane from the box centre towards
// the box's back along that axis (0: it is not standing; the whole excess / 2 from the
// tolerance on, ramping up continuously from half of it) and the axis in *axis.
// docs/design.md, "Surfaces with things standing on them".
inline constexpr float kStandingTolerance = 0.4f;
inline float StandingShift(const glm::vec3& normal_sum, const glm::vec3& ext, int* axis) {
  const glm::vec3 a(std::fabs(normal_sum.x), std::fabs(normal_sum.y), std::fabs(normal_sum.z));
  const int k = a.x >= a.y && a.x >= a.z ? 0 : a.y >= a.z ? 1 : 2;
  const int i = (k + 1) % 3, j = (k + 2) % 3;
  *axis = k;
  if (!(a[k] > 0.0f)) return 0.0f;
  const float excess = ext[k] - (a[i] * ext[i] + a[j] * ext[j]) / a[k];
  const float tol = kStandingTolerance * std::max(ext[i], ext[j]);
  return std::min(0.5f * excess, std::max(0.0f, excess - 0.5f * tol));
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

// The eigen decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations: on return a's
// diagonal holds the eigenvalues and column i of v the unit eigenvector of a[i][i].
inline void SymmetricEigen3(std::array<std::array<double, 3>, 3>* a_io,
                            std::array<std::array<double, 3>, 3>* v_out) {
  std::array<std::array<double, 3>, 3>& a = *a_io;
  std::array<std::array<double, 3>, 3>& v = *v_out;
  v = {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  for (int sweep = 0; sweep < 32; ++sweep) {
    const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    const double diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
    if (off <= 1e-24 * diag || off == 0) break;
    for (int p = 0; p < 2; ++p) {
      for (int q = p + 1; q < 3; ++q) {
        if (a[p][q] == 0) continue;
        const double theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
        const double t = (theta >= 0 ? 1 : -1) / (std::abs(theta) + std::sqrt(theta * theta + 1));
        const double c = 1 / std::sqrt(t * t + 1), s = t * c;
        for (int k = 0; k < 3; ++k) {  // A <- A J
          const double akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (int k = 0; k < 3; ++k) {  // A <- J^T A
          const double apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (int k = 0; k < 3; ++k) {
          const double vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
}

}  // namespace pbgi::internal

#endif  // PBGI_BASE_MATH_H_
