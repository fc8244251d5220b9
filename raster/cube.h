// Geometry of the micro-buffer cube: face axes, exact pixel solid angles and cosine weights,
// and the conservative pixel range of a cone on a face.
#ifndef PBGI_RASTER_CUBE_H_
#define PBGI_RASTER_CUBE_H_

#include "glm/vec3.hpp"

namespace pbgi::internal {

// Face f looks along sign * axis k; its column coordinate runs along axis k1, its row
// coordinate along k2 (k1 < k2). A direction u on the face has coordinates
// (u[k1], u[k2]) / (sign * u[k]) in [-1, 1]^2.
struct FaceAxes {
  int k, k1, k2;
  float sign;
};

inline FaceAxes Face(int f) {
  const int k = f / 2;
  return FaceAxes{k, k == 0 ? 1 : 0, k == 2 ? 1 : 2, (f % 2) ? -1.0f : 1.0f};
}

// Solid angle of the rectangle [a0,a1] x [b0,b1] on the plane at distance 1 (closed form:
// F(x, y) = atan(x y / sqrt(1 + x^2 + y^2)) summed over the corners with alternating signs).
double RectSolidAngle(double a0, double a1, double b0, double b1);

// Integral of max(0, v.z) over the spherical polygon with the given vertices (any lengths),
// which must lie in z >= 0: Lambert's formula, 1/2 sum_i angle(v_i, v_i+1) * unit(v_i x v_i+1).z.
double PolygonCosineWeight(const glm::dvec3* v, int n);

// The pixel rows and columns of face `face` that the cone {u : |u - d| <= chord} can touch
// (chord = straight-line distance on the unit sphere, d unit). False when it touches none.
// `contained`, when given, tells whether the whole cone maps inside this face (then no other
// face can see it).
bool FaceRange(const FaceAxes& face, const glm::vec3& d, float chord, int res, int* col0, int* col1,
               int* row0, int* row1, bool* contained = nullptr);

// The pixel rows and columns of face `face` that the disk {c + x e1 + y e2 : x^2 + y^2 <= r^2}
// (e1, e2 orthonormal) covers, exactly: the disk's image on the face plane is an ellipse whose
// extent along each face axis solves a quadratic (the range of a ratio of sinusoids).
enum class DiskRange { kNone, kExact, kUnknown };  // kUnknown: the rim crosses the face plane
DiskRange DiskFaceRange(const FaceAxes& face, const glm::vec3& c, const glm::vec3& e1,
                        const glm::vec3& e2, float r, int res, int* col0, int* col1, int* row0,
                        int* row1);

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_CUBE_H_
