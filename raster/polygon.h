// Convex polygons on the micro-buffer: the footprints that tile (docs/design.md, "Raster").
//
// An element's footprint is the part of its plane inside its box (a flat cluster or a group of
// co-planar surfels), or a face of its box (an element that is not flat). Boxes of neighbouring
// octree cells share their faces exactly, so the footprints of one surface cut into cells tile
// the sphere of directions without gap or overlap, and a pixel's coverage is the exact area of
// the polygons in it: a covered pixel holds 1, not a sum of round splats that overlap here and
// leave gaps there.
//
// Coverage is exact area coverage on the cube face's plane (signed-area accumulation over the
// pixel grid, the way font rasterizers compute it), so it is continuous in the polygon's
// vertices: a receiver that moves a little moves its footprints a little.
#ifndef PBGI_RASTER_POLYGON_H_
#define PBGI_RASTER_POLYGON_H_

#include <cstdint>
#include <vector>

#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// Polygon and PixelCoverage are declared in pbgi/raster.h (the MicroBuffer keeps them).

// The polygon {x : dot(normal, x) = offset} inside the box [lo, hi], its vertices in order
// around the normal; n = 0 when the plane misses the box. A box thinner than 1e-4 of its
// largest extent along an axis is treated as that thick (a wall's cluster has a flat box).
void PlaneBoxPolygon(const glm::vec3& normal, float offset, const glm::vec3& lo,
                     const glm::vec3& hi, Polygon* out);

// Keeps the part of p with dot(m, x) >= 0 (a half-space bounded by a plane through the origin).
void ClipHalfSpace(const glm::vec3& m, Polygon* p);
// Keeps the part of p with dot(m, x) >= c.
void ClipHalfSpace(const glm::vec3& m, float c, Polygon* p);

// Area of a planar polygon (any orientation).
double PolygonArea(const Polygon& p);

// The outline of the faces of the box [lo, hi] (given relative to a point outside it, the
// origin) across the axes in `faces` (bit k: the face at lo[k] if lo[k] > 0, else the face at
// hi[k]), its vertices in order around it; n = 0 when `faces` is empty. With every axis whose
// face the origin sees, it is the box's silhouette from the origin: the faces tile it, so its
// coverage and its solid angle are theirs summed.
void BoxSilhouette(const glm::vec3& lo, const glm::vec3& hi, int faces, Polygon* out);

// The least and greatest of glm::dot(n, x - o) over the corners x of the box b (not empty),
// the same values as the corners' own (a zero's sign aside): each is (t0 + t1) + t2 with
// t_k = n[k] * (x[k] - o[k]), and rounding is monotonic, so the least sum is that of each axis's
// least term (the greatest likewise). Six products instead of eight dot products.
void BoxDotRange(const Bounds& b, const glm::vec3& n, const glm::vec3& o, float* lo, float* hi);

// The solid angle of the cone from the origin over a convex polygon that does not surround the
// origin (less than 2 pi), either orientation.
float ConeSolidAngle(const Polygon& p);

// Rasterizes a polygon given in the micro-buffer's frame (relative to the receiver; the
// caller clips it to the upper hemisphere first) onto the cube faces of a res x res buffer
// (pixel numbering of MicroBuffer). Appends to `out`; `acc` is scratch.
void RasterizePolygon(const Polygon& p, int res, std::vector<float>* acc,
                      std::vector<PixelCoverage>* out);

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_POLYGON_H_
