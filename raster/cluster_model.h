// A cluster's projected area and radiance towards a direction, reconstructed from its SH.
#ifndef PBGI_RASTER_CLUSTER_MODEL_H_
#define PBGI_RASTER_CLUSTER_MODEL_H_

#include <algorithm>
#include <cmath>

#include "glm/geometric.hpp"
#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/sh.h"
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

namespace cluster_model_internal {
// Inverse of sh::ProjectClampedCosine's scale per coefficient: zonal factor * basis constant.
constexpr double kPi = sh::kPi;
constexpr double kBand0 = kPi * 0.282094791773878;
constexpr double kBand1 = 2.0 * kPi / 3.0 * 0.488602511902920;
constexpr double kBand2Xy = kPi / 4.0 * 1.092548430592079;
constexpr double kBand2Z = kPi / 4.0 * 0.315391565252520;
constexpr double kBand2Xx = kPi / 4.0 * 0.546274215296040;
}  // namespace cluster_model_internal

// Plain SH evaluation of the projected area (ClusterModel::kShEval).
float ProjectedAreaShEval(const Cluster& cluster, const glm::vec3& w, HitSides sides);

inline ClusterMoments MomentsFromSh(const Sh9& c) {
  using namespace cluster_model_internal;
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

// Projected area of a cluster with moments m seen from direction w (unit, world space, pointing
// from the cluster towards the viewer), counting the sides that `sides` selects. Never negative.
inline float ProjectedArea(const ClusterMoments& m, const glm::vec3& w, HitSides sides) {
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

// The same from the cluster's SH, with the chosen reconstruction.
inline float ProjectedArea(const Cluster& cluster, const glm::vec3& w, HitSides sides,
                           ClusterModel model) {
  if (model == ClusterModel::kShEval) return ProjectedAreaShEval(cluster, w, sides);
  return ProjectedArea(MomentsFromSh(cluster.sh_area), w, sides);
}

// Radiance P(w)/A(w) per colour seen from w, with the same side rule. The ratio is regularised
// towards the cluster's mean radiance where A(w) is small (exact for a uniform radiance, however
// much the SH rings); never negative.
glm::vec3 ClusterRadiance(const Cluster& cluster, const glm::vec3& w, HitSides sides);

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_CLUSTER_MODEL_H_
