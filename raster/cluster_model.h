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
#include "raster/simd.h"

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
constexpr double kBand0 = kPi * sh::kY0;
constexpr double kBand1 = 2.0 * kPi / 3.0 * sh::kY1;
constexpr double kBand2Xy = kPi / 4.0 * sh::kY2;
constexpr double kBand2Z = kPi / 4.0 * sh::kY6;
constexpr double kBand2Xx = kPi / 4.0 * sh::kY8;
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
  // kBoth: the larger side, max(front, back), not front + back: a closed object (N = 0) shows
  // its silhouette once, a one-sided sheet its full area, and a two-sided surfel, whose pair
  // already counts both sides in `even`, its area once (docs/design.md, "Two-sided surfels").
  switch (sides) {
    case HitSides::kFront:
      return 0.5f * (even + odd);
    case HitSides::kBack:
      return 0.5f * (even - odd);
    case HitSides::kBoth:
      return 0.5f * (even + std::fabs(odd));
  }
  return 0.0f;
}

// The same from the cluster's SH, with the chosen reconstruction.
inline float ProjectedArea(const Cluster& cluster, const glm::vec3& w, HitSides sides,
                           ClusterModel model) {
  if (model == ClusterModel::kShEval) return ProjectedAreaShEval(cluster, w, sides);
  return ProjectedArea(MomentsFromSh(cluster.sh_area), w, sides);
}

// Content whose normals all lie along the world axes, either way (a building's roof and walls,
// a street): its SH holds the areas of its six faces exactly. Band 1 is N_k = A(+k) - A(-k)
// and bands 0 and 2 give M_kk = A(+k) + A(-k), with M's off-diagonal entries 0. From the faces,
// A(w) = sum over faces of A_f max(0, n_f.w) is exact, where the order-2 SH rings: a face seen
// edge-on or from behind keeps up to 9 % of its area, so a building's dark walls leaked into
// the sunlit roof that a high receiver sees, and its lit roof into the walls a street sees
// (docs/design.md, "Radiance of axis-aligned content").
// Faces in the order +x, -x, +y, -y, +z, -z of one SH (area or one colour's power).
inline void AxisFacesOf(const float* c, float f[6]) {
  using namespace cluster_model_internal;
  constexpr float kInv0 = static_cast<float>(1.0 / kBand0);
  constexpr float kInv1 = static_cast<float>(1.0 / kBand1);
  constexpr float kInvZ = static_cast<float>(1.0 / kBand2Z);
  constexpr float kInvXx = static_cast<float>(1.0 / kBand2Xx);
  const float total = c[0] * kInv0;
  const float mzz = (c[6] * kInvZ + total) * (1.0f / 3.0f);
  const float diff = c[8] * kInvXx;
  const float mxx = 0.5f * (total - mzz + diff), myy = 0.5f * (total - mzz - diff);
  const float nx = c[3] * kInv1, ny = c[1] * kInv1, nz = c[2] * kInv1;
  f[0] = 0.5f * (mxx + nx), f[1] = 0.5f * (mxx - nx);
  f[2] = 0.5f * (myy + ny), f[3] = 0.5f * (myy - ny);
  f[4] = 0.5f * (mzz + nz), f[5] = 0.5f * (mzz - nz);
}

// Whether the area SH c is of axis-aligned content: M's off-diagonal entries and any negative
// face within kAxisFacesTolerance of the total area (the SH is stored quantized). Also false
// for an empty cluster.
inline constexpr float kAxisFacesTolerance = 0.02f;
inline bool IsAxisAligned(const float* c, const float f[6]) {
  using namespace cluster_model_internal;
  constexpr float kInv0 = static_cast<float>(1.0 / kBand0);
  constexpr float kInvXy = static_cast<float>(1.0 / kBand2Xy);
  const float total = c[0] * kInv0;
  if (!(total > 0.0f)) return false;
  const float tol = kAxisFacesTolerance * total;
  if ((std::fabs(c[4]) + std::fabs(c[5]) + std::fabs(c[7])) * kInvXy > tol) return false;
  for (int k = 0; k < 6; ++k) {
    if (f[k] < -tol) return false;
  }
  return true;
}

// sum over the faces f of A_f max(0, n_f.w): the front side seen from w, and the back side
// (seen from -w).
struct AxisSight {
  float front, back;
};
inline AxisSight AxisFacesSeen(const float f[6], const glm::vec3& w) {
  const float px = std::max(0.0f, w.x), mx = std::max(0.0f, -w.x);
  const float py = std::max(0.0f, w.y), my = std::max(0.0f, -w.y);
  const float pz = std::max(0.0f, w.z), mz = std::max(0.0f, -w.z);
  return {(f[0] * px + f[1] * mx) + (f[2] * py + f[3] * my) + (f[4] * pz + f[5] * mz),
          (f[0] * mx + f[1] * px) + (f[2] * my + f[3] * py) + (f[4] * mz + f[5] * pz)};
}

// The sum of the faces turned towards w (n_f.w > 0), and of those turned away (the back side's
// faces): what the axis-aligned ratio regularises with, each side's own.
inline AxisSight AxisFacesFacing(const float f[6], const glm::vec3& w) {
  const float px = w.x > 0.0f ? 1.0f : 0.0f, mx = w.x < 0.0f ? 1.0f : 0.0f;
  const float py = w.y > 0.0f ? 1.0f : 0.0f, my = w.y < 0.0f ? 1.0f : 0.0f;
  const float pz = w.z > 0.0f ? 1.0f : 0.0f, mz = w.z < 0.0f ? 1.0f : 0.0f;
  return {(f[0] * px + f[1] * mx) + (f[2] * py + f[3] * my) + (f[4] * pz + f[5] * mz),
          (f[0] * mx + f[1] * px) + (f[2] * my + f[3] * py) + (f[4] * mz + f[5] * pz)};
}

// ClusterRadiance() for axis-aligned content, from its faces: false (and *out untouched) when
// the content is not axis-aligned. The same side rule and regularisation weight as the SH
// ratio, but the radiance it blends in is the mean of the seen side's faces (those turned
// towards w for the front), not of all faces: a two-sided sheet's other side and the faces a
// building turns away from the receiver stay out of it.
inline bool AxisFacesRadiance(const Cluster& c, const glm::vec3& w, HitSides sides, glm::vec3* out);

// What the rasterizer needs of a cluster seen from w, from one evaluation of the SH basis
// (ClusterView below): the same values as MomentsFromSh + ProjectedArea and ClusterRadiance,
// to float rounding, in about a quarter of the instructions.
struct ClusterSight {
  float area;            // ProjectedArea(cluster, w, sides, model); 0 when culled
  float total;           // the cluster's total area A (band 0)
  glm::vec3 normal_sum;  // N = sum A_i n_i (band 1)
  V4 rgb1;               // {1, ClusterRadiance(cluster, w, sides)} when radiance is asked for
};

namespace cluster_model_internal {
constexpr float kY0 = static_cast<float>(sh::kY0);
constexpr float kY1 = static_cast<float>(sh::kY1);
constexpr float kY2 = static_cast<float>(sh::kY2);  // Y4, Y5, Y7
constexpr float kY6 = static_cast<float>(sh::kY6);
constexpr float kY8 = static_cast<float>(sh::kY8);
// Weight of the mean radiance in the regularised ratio P(w) / A(w) (see ClusterRadiance). It
// was 0.1: a building's cluster seen from a high wall mixed that much of the mean over all its
// faces, the shaded ones too, into the sunlit facade it shows (city irradiance 2.14 % -> 2.07 %
// of the mean, its bias +0.0008 -> +0.0002; cornell 1.92 % -> 1.89 %; 0.01 gains 0.02 % more).
constexpr float kRadianceBlend = 0.03f;
// The axis-aligned ratio blends in the seen side's faces' mean radiance where those faces hold
// more than this share of the regularisation's area (a quarter of the total); else the mean of
// all faces, as the SH ratio does (a face of no area has no radiance to speak of).
constexpr float kAxisOwnShare = 0.1f;
}  // namespace cluster_model_internal

// The moment model needs only scalars that band 2 of the SH holds directly, without the
// matrix M: by the addition theorem, sum_m Y_2m(n) Y_2m(w) = 5 / (4 pi) P2(n.w), so band 2
// evaluated at w is E2 = 5/32 (3 w^T M w - A), i.e. w^T M w = (A + 32/5 E2) / 3; and since the
// band-2 basis maps traceless symmetric matrices isometrically (up to one constant), the
// anisotropy t = 3 |M - A I / 3|_F^2 / (2 A^2) of MomentsFromSh is 16/5 sum_{i=4..8} c_i^2 /
// c_0^2 (1 for any flat cluster, 0 for an isotropic one).
// kRad: also the radiance, from the same basis: the area and the three power SH are the rows
// of a 4 x 9 matrix, evaluated together four lanes wide.
template <bool kRad>
[[gnu::always_inline]] inline ClusterSight ClusterView(const Cluster& c, const glm::vec3& w,
                                                       HitSides sides, ClusterModel model) {
  using namespace cluster_model_internal;
  const float* sa = c.sh_area.data();
  ClusterSight out;
  out.total = sa[0] * static_cast<float>(1.0 / kBand0);
  constexpr float kInv1 = static_cast<float>(1.0 / kBand1);
  out.normal_sum = glm::vec3(sa[3] * kInv1, sa[1] * kInv1, sa[2] * kInv1);
  // The basis at w; the basis at -w flips band 1 only. Band 0 is added separately (lane 0 of
  // the low vector is 0) so that band 2 alone is at hand for the moments.
  const V4 y_odd = {0.0f, kY1 * w.y, kY1 * w.z, kY1 * w.x};
  const V4 y_hi = {kY2 * w.x * w.y, kY2 * w.y * w.z, kY6 * (3.0f * w.z * w.z - 1.0f),
                   kY2 * w.x * w.z};
  const float y8 = kY8 * (w.x * w.x - w.y * w.y);
  const V4 lo0 = Load4(sa), hi0 = Load4(sa + 4);
  V4 even2, odd;  // band 2 and band 1 of each row
  if constexpr (kRad) {
    const float* p0 = c.sh_power[0].data();
    const float* p1 = c.sh_power[1].data();
    const float* p2 = c.sh_power[2].data();
    const V4 c8 = {sa[8], p0[8], p1[8], p2[8]};
    even2 = Hsum4(hi0 * y_hi, Load4(p0 + 4) * y_hi, Load4(p1 + 4) * y_hi, Load4(p2 + 4) * y_hi) +
            c8 * y8;
    odd = Hsum4(lo0 * y_odd, Load4(p0) * y_odd, Load4(p1) * y_odd, Load4(p2) * y_odd);
  } else {
    const V4 e = hi0 * y_hi, o = lo0 * y_odd;
    even2[0] = (e[0] + e[2]) + (e[1] + e[3]) + sa[8] * y8;
    odd[0] = o[2] + (o[1] + o[3]);  // the order of Hsum4 (and of the lane path, cluster_lanes.inc)
  }
  if (model == ClusterModel::kShEval) {
    out.area = ProjectedAreaShEval(c, w, sides);
  } else if (!(out.total > 0.0f)) {
    out.area = 0.0f;
  } else {
    const float a = out.total;
    const float m2 = (a + 6.4f * even2[0]) * (1.0f / 3.0f);  // w^T M w
    const V4 h2 = hi0 * hi0;
    const float q = (h2[0] + h2[2]) + (h2[1] + h2[3]) + sa[8] * sa[8];
    const float t = std::clamp(3.2f * q / (sa[0] * sa[0]), 0.0f, 1.0f);
    constexpr float kIso = 0.8660254037844386f;  // sqrt(3) / 2
    const float even_factor = kIso + (1.0f - kIso) * t;
    const float n_dot_w = odd[0] * static_cast<float>(1.0 / (kBand1 * kY1));
    const float even =
        std::max(std::sqrt(std::max(0.0f, a * m2)) * even_factor, std::fabs(n_dot_w));
    out.area = sides == HitSides::kFront  ? 0.5f * (even + n_dot_w)
               : sides == HitSides::kBack ? 0.5f * (even - n_dot_w)
                                          : 0.5f * (even + std::fabs(n_dot_w));
  }
  if constexpr (kRad) {
    const V4 zero = {0.0f, 0.0f, 0.0f, 0.0f};
    const V4 c0 = {sa[0], c.sh_power[0][0], c.sh_power[1][0], c.sh_power[2][0]};
    const V4 even = c0 * kY0 + even2;
    const V4 front = Max4(zero, even + odd), back = Max4(zero, even - odd);
    // kBoth: the side whose area is the larger (the sign of the area's band 1), for the power
    // as for the area, so that their ratio is one side's radiance.
    const V4 seen = sides == HitSides::kFront  ? front
                    : sides == HitSides::kBack ? back
                    : odd[0] >= 0.0f           ? front
                                               : back;
    // Axis-aligned content from its faces; else the SH ratio, lane 0 the plain SH area and its
    // mean (not clamped, as in ClusterRadiance).
    glm::vec3 axis;
    if (AxisFacesRadiance(c, w, sides, &axis)) {
      out.rgb1 = V4{1.0f, axis.x, axis.y, axis.z};
    } else if (const float den = seen[0] + kRadianceBlend * (kY0 * sa[0]); den > 0.0f) {
      const V4 mean = Max4(zero, c0 * kY0);
      const V4 den4 = {den, den, den, den};
      out.rgb1 = (seen + kRadianceBlend * mean) / den4;
    } else {
      out.rgb1 = zero;
    }
    out.rgb1[0] = 1.0f;
  } else {
    out.rgb1 = V4{1.0f, 0.0f, 0.0f, 0.0f};
  }
  return out;
}

inline bool AxisFacesRadiance(const Cluster& c, const glm::vec3& w, HitSides sides,
                              glm::vec3* out) {
  using namespace cluster_model_internal;
  float fa[6];
  AxisFacesOf(c.sh_area.data(), fa);
  if (!IsAxisAligned(c.sh_area.data(), fa)) return false;
  for (float& x : fa) x = std::max(0.0f, x);
  const AxisSight a = AxisFacesSeen(fa, w);
  // kBoth: the side whose area is the larger, as the SH ratio's rule.
  const bool front = sides == HitSides::kFront || (sides == HitSides::kBoth && a.front >= a.back);
  const float a_mean = kY0 * c.sh_area[0];
  const float den = (front ? a.front : a.back) + kRadianceBlend * a_mean;
  if (!(den > 0.0f)) {
    *out = glm::vec3(0.0f);
    return true;
  }
  // The regularisation's radiance: the seen side's faces' mean, where they hold some area.
  const AxisSight af = AxisFacesFacing(fa, w);
  const float facing = front ? af.front : af.back;
  const bool own = facing > kAxisOwnShare * a_mean;
  for (int ch = 0; ch < 3; ++ch) {
    float fp[6];
    AxisFacesOf(c.sh_power[ch].data(), fp);
    for (float& x : fp) x = std::max(0.0f, x);
    const AxisSight p = AxisFacesSeen(fp, w);
    const AxisSight pf = AxisFacesFacing(fp, w);
    const float reg = own ? ((front ? pf.front : pf.back) / facing) * a_mean
                          : std::max(0.0f, kY0 * c.sh_power[ch][0]);
    (*out)[ch] = ((front ? p.front : p.back) + kRadianceBlend * reg) / den;
  }
  return true;
}

// Radiance P(w)/A(w) per colour seen from w, with the same side rule (kBoth: the side with the
// larger area). Axis-aligned content (AxisFacesRadiance) from its six faces. The ratio is
// regularised towards the cluster's mean radiance where A(w) is small (exact for a uniform
// radiance, however much the SH rings); never negative.
glm::vec3 ClusterRadiance(const Cluster& cluster, const glm::vec3& w, HitSides sides);

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_CLUSTER_MODEL_H_
