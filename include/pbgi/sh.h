// Order-2 real spherical harmonics (9 coefficients) for the node aggregates of the PBGI octree.
// Header-only: the builder projects with it, the query layer and the rasterizer evaluate with it.
//
// Basis (Sloan, "Stupid SH tricks"), for a unit direction w = (x, y, z):
//   Y0 = 0.282095                      Y4 = 1.092548 xy
//   Y1 = 0.488603 y                    Y5 = 1.092548 yz
//   Y2 = 0.488603 z                    Y6 = 0.315392 (3z^2 - 1)
//   Y3 = 0.488603 x                    Y7 = 1.092548 xz
//                                      Y8 = 0.546274 (x^2 - y^2)
// A clamped cosine lobe max(0, n.w) has zonal coefficients pi, 2pi/3, pi/4 for bands 0, 1, 2,
// so a disk of area A and normal n projects to c_i = A * zonal(band(i)) * Y_i(n); projection is
// linear, so a node's coefficients are the sum of its children's (docs/design.md, "Build").
#ifndef PBGI_SH_H_
#define PBGI_SH_H_

#include <algorithm>
#include <array>
#include <cmath>

#include "glm/geometric.hpp"
#include "glm/vec3.hpp"

namespace pbgi::sh {

inline constexpr int kCoeffs = 9;
// The one home of pi and of the basis constants (everything else derives from these).
inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kY0 = 0.282094791773878;  // 1 / (2 sqrt(pi))
inline constexpr double kY1 = 0.488602511902920;  // sqrt(3 / (4 pi)): Y1, Y2, Y3
inline constexpr double kY2 = 1.092548430592079;  // sqrt(15 / (4 pi)): Y4, Y5, Y7
inline constexpr double kY6 = 0.315391565252520;  // sqrt(5 / (16 pi))
inline constexpr double kY8 = 0.546274215296040;  // sqrt(15 / (16 pi))

template <typename T>
inline std::array<T, 9> Basis(T x, T y, T z) {
  return {T(kY0),
          T(kY1) * y,
          T(kY1) * z,
          T(kY1) * x,
          T(kY2) * x * y,
          T(kY2) * y * z,
          T(kY6) * (T(3) * z * z - T(1)),
          T(kY2) * x * z,
          T(kY8) * (x * x - y * y)};
}

// Coefficients of area * max(0, n.w) for a unit normal n.
template <typename T>
inline std::array<T, 9> ProjectClampedCosine(T nx, T ny, T nz, T area) {
  const T a0 = T(kPi) * area, a1 = T(2.0 * kPi / 3.0) * area, a2 = T(kPi / 4.0) * area;
  auto y = Basis(nx, ny, nz);
  return {a0 * y[0], a1 * y[1], a1 * y[2], a1 * y[3], a2 * y[4],
          a2 * y[5], a2 * y[6], a2 * y[7], a2 * y[8]};
}

// A two-sided surfel's power: front * (A max(0, n.w)) + back * (A max(0, -n.w)), from c =
// ProjectClampedCosine(n, A). -n's lobe is c with band 1 negated (the odd band), so the even
// bands take front + back and band 1 front - back.
template <typename T>
inline void ProjectTwoSided(const T* c, T front, T back, T* out) {
  const T sum = front + back, diff = front - back;
  for (int k = 0; k < 9; ++k) out[k] = c[k] * ((k >= 1 && k <= 3) ? diff : sum);
}

// Value of the function with coefficients c in the unit direction w (may ring slightly negative
// where the true function is zero: callers clamp at 0).
template <typename T, typename C>
inline T Eval(const C& c, const glm::vec<3, T>& w) {
  auto y = Basis(w.x, w.y, w.z);
  T v = 0;
  for (int i = 0; i < kCoeffs; ++i) v += T(c[i]) * y[i];
  return v;
}

// Bands 0 and 1 of a projected-area SH c (the sum of clamped cosine lobes A_i max(0, n_i.w)):
// band 0 holds pi Y0 sum A_i, band 1 holds (2 pi / 3) Y1 N for N = sum A_i n_i.
struct FirstMoments {
  float area;            // sum A_i
  glm::vec3 normal_sum;  // N = sum A_i n_i
};
inline FirstMoments AreaAndNormalSum(const float* c) {
  const float k = static_cast<float>(3.0 / (2.0 * kPi * kY1));
  return {c[0] * static_cast<float>(1.0 / (kPi * kY0)), glm::vec3(c[3] * k, c[1] * k, c[2] * k)};
}

// The second moment M = sum A_i n_i n_i^T of a projected-area SH c (the sum of clamped cosine
// lobes A_i max(0, n_i.w), band 0 holding pi Y0 sum A_i): bands 0 and 2 hold it exactly, and
// trace M = sum A_i. Returned as {xx, yy, zz, xy, yz, xz}.
inline std::array<float, 6> SecondMoment(const float* c) {
  const float area = c[0] * static_cast<float>(1.0 / (kPi * kY0));
  const float zz = (c[6] * static_cast<float>(4.0 / (kPi * kY6)) + area) * (1.0f / 3.0f);
  const float diff = c[8] * static_cast<float>(4.0 / (kPi * kY8));  // sum A (x^2 - y^2)
  constexpr float kInvXy = static_cast<float>(4.0 / (kPi * kY2));
  return {0.5f * (area - zz + diff),
          0.5f * (area - zz - diff),
          zz,
          c[4] * kInvXy,
          c[5] * kInvXy,
          c[7] * kInvXy};
}

// Whether the normals of the SH c lie near one axis e, sides counted apart: the largest
// eigenvalue of M exceeds k * trace M, for k in (1/2, 1). Then exactly one eigenvalue does
// (they sum to trace M), so the test is det(k trace(M) I - M) < 0, with no eigen solve.
inline bool AxisDominates(const float* c, float k) {
  const std::array<float, 6> m = SecondMoment(c);
  const float s = k * (m[0] + m[1] + m[2]);
  if (!(s > 0.0f)) return false;
  const float a = s - m[0], b = s - m[1], d = s - m[2];
  // det of [[a, -xy, -xz], [-xy, b, -yz], [-xz, -yz, d]].
  const float det = a * (b * d - m[4] * m[4]) - d * (m[3] * m[3]) - b * (m[5] * m[5]) -
                    2.0f * (m[3] * m[4] * m[5]);
  return det < 0.0f;
}

// The unit eigenvector of M's largest eigenvalue (any sign): the plane normal of a flat
// cluster whose sides cancel in band 1 (a two-sided card). Zero when M is zero.
inline glm::vec3 PrincipalAxis(const float* c) {
  const std::array<float, 6> m = SecondMoment(c);
  // Largest eigenvalue of the symmetric 3x3 matrix: the largest root of its characteristic
  // polynomial, by Newton's method from above (the Gershgorin bound: the polynomial is
  // increasing and convex past its largest root, so the iterates fall to it monotonically), with
  // no transcendental function (the trigonometric closed form's acos and cos were 1.5 % of the
  // city's shading profile).
  const double xx = m[0], yy = m[1], zz = m[2], xy = m[3], yz = m[4], xz = m[5];
  const double tr = xx + yy + zz;
  const double c2 = xx * yy + yy * zz + zz * xx - xy * xy - yz * yz - xz * xz;
  const double det3 =
      xx * (yy * zz - yz * yz) - xy * (xy * zz - yz * xz) + xz * (xy * yz - yy * xz);
  double l = std::max({xx + std::fabs(xy) + std::fabs(xz), yy + std::fabs(xy) + std::fabs(yz),
                       zz + std::fabs(xz) + std::fabs(yz)});
  for (int it = 0; it < 64; ++it) {
    const double f = ((l - tr) * l + c2) * l - det3;
    const double df = (3.0 * l - 2.0 * tr) * l + c2;
    if (!(df > 0.0)) break;
    const double next = l - f / df;
    if (!(next < l)) break;  // converged (or rounding turned it back)
    l = next;
  }
  // The eigenvector is orthogonal to the rows of M - l I: the longest cross product of two.
  const glm::dvec3 r0(xx - l, xy, xz), r1(xy, yy - l, yz), r2(xz, yz, zz - l);
  glm::dvec3 best = glm::cross(r0, r1);
  for (const glm::dvec3& v : {glm::cross(r0, r2), glm::cross(r1, r2)}) {
    if (glm::dot(v, v) > glm::dot(best, best)) best = v;
  }
  const double len = glm::length(best);
  if (!(len > 0.0)) {
    // M is a multiple of one axis' projector or zero: its largest diagonal entry's axis.
    if (!(xx + yy + zz > 0.0)) return glm::vec3(0.0f);
    return xx >= yy && xx >= zz ? glm::vec3(1, 0, 0)
           : yy >= zz           ? glm::vec3(0, 1, 0)
                                : glm::vec3(0, 0, 1);
  }
  return glm::vec3(best / len);
}

}  // namespace pbgi::sh

#endif  // PBGI_SH_H_
