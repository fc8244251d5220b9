// A cluster's projected area and radiance towards a direction, reconstructed from its SH.
#ifndef PBGI_RASTER_CLUSTER_MODEL_H_
#define PBGI_RASTER_CLUSTER_MODEL_H_

#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// What the order-2 SH of A(w) = sum A_i max(0, n_i.w) holds exactly: the total area A
// (band 0), the area-weighted normal sum N = sum A_i n_i (band 1) and the second moment
// M = sum A_i n_i n_i^T (bands 0 and 2), plus a factor derived from M's anisotropy.
struct ClusterMoments {
  float area = 0.0f;
  glm::vec3 normal_sum{0.0f};
  float mxx = 0, myy = 0, mzz = 0, mxy = 0, myz = 0, mxz = 0;
  // E|n.w| ~ sqrt(E[(n.w)^2]) * even_factor: 1 for a flat (or two-sided flat) cluster, whose
  // normals are +-n, sqrt(3)/2 for an isotropic one; linear in between in the anisotropy
  // t = (3 |M/A|_F^2 - 1) / 2 (1 flat, 0 isotropic).
  float even_factor = 1.0f;
};

ClusterMoments MomentsFromSh(const Sh9& sh_area);

// Projected area of the cluster seen from direction w (unit, world space, pointing from the
// cluster towards the viewer), counting the sides that `sides` selects. Never negative.
float ProjectedArea(const Cluster& cluster, const glm::vec3& w, HitSides sides, ClusterModel model);

// Radiance P(w)/A(w) per colour seen from w, with the same side rule. The ratio is regularised
// towards the cluster's mean radiance where A(w) is small (exact for a uniform radiance, however
// much the SH rings); never negative.
glm::vec3 ClusterRadiance(const Cluster& cluster, const glm::vec3& w, HitSides sides);

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_CLUSTER_MODEL_H_
