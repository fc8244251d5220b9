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

#include <array>

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

// Value of the function with coefficients c in the unit direction w (may ring slightly negative
// where the true function is zero: callers clamp at 0).
template <typename T, typename C>
inline T Eval(const C& c, const glm::vec<3, T>& w) {
  auto y = Basis(w.x, w.y, w.z);
  T v = 0;
  for (int i = 0; i < kCoeffs; ++i) v += T(c[i]) * y[i];
  return v;
}

}  // namespace pbgi::sh

#endif  // PBGI_SH_H_
