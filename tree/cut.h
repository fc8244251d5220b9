// The traversal math of the cut (the contract is in include/pbgi/query.h; docs/design.md, "The
// cut"): the tests that Gather applies to nodes and surfels, and that the test harness
// (pbgi/testing.h) re-evaluates by brute force. Both call exactly this code, so they agree to
// the last bit. Several tests come in a plain form and a form with the per-node terms
// precomputed (the traversal keeps them in its decoded pages, tree/decoded_page.h); each pair
// gives the same bits. Internal.
#ifndef PBGI_TREE_CUT_H_
#define PBGI_TREE_CUT_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "base/math.h"
#include "glm/geometric.hpp"
#include "glm/vec3.hpp"
#include "pbgi/query.h"
#include "pbgi/sh.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// Whether a surfel's disk lies wholly behind the receiver's tangent plane: the highest point of
// the disk above the plane, n.(c - p) + r * sqrt(1 - (n.m)^2), is <= 0. A surfel lying in the
// plane (a flat neighbour) counts as behind.
inline bool SurfelWhollyBehindUnit(const Surfel& s, const glm::vec3& p, const glm::vec3& unit_n) {
  const float h = glm::dot(unit_n, s.position - p);
  const float c = glm::dot(unit_n, s.normal);
  return h + s.radius * std::sqrt(std::max(0.0f, 1.0f - c * c)) <= 0.0f;
}

// Whether a surfel's disk lies wholly beyond max_distance: |c - p| - r > max_distance.
inline bool SurfelBeyondPoint(const Surfel& s, const glm::vec3& p, float max_distance) {
  return glm::length(s.position - p) - s.radius > max_distance;
}

// The solid angle a node subtends from the receiver, as the cut criterion measures it.
// NodeSolidAngleFrom takes the centre 0.5f * (lo + hi) precomputed (the traversal keeps it in
// its decoded pages); both forms give the same bits.
// ProjectedAreaToward(c, w) is sh::Eval<float>(c, w) written out: the same operations in the
// same order (so the same bits), kept in registers instead of a basis array in memory.
inline float ProjectedAreaToward(const float* c, const glm::vec3& w) {
  const float x = w.x, y = w.y, z = w.z;
  float v = 0.0f;
  v += c[0] * float(sh::kY0);
  v += c[1] * (float(sh::kY1) * y);
  v += c[2] * (float(sh::kY1) * z);
  v += c[3] * (float(sh::kY1) * x);
  v += c[4] * (float(sh::kY2) * x * y);
  v += c[5] * (float(sh::kY2) * y * z);
  v += c[6] * (float(sh::kY6) * (3.0f * z * z - 1.0f));
  v += c[7] * (float(sh::kY2) * x * z);
  v += c[8] * (float(sh::kY8) * (x * x - y * y));
  return v;
}
inline float NodeSolidAngleFrom(const glm::vec3& centre, const float* sh_area, const glm::vec3& p) {
  const glm::vec3 v = p - centre;
  const float d2 = glm::dot(v, v);
  if (!(d2 > 0.0f)) return std::numeric_limits<float>::infinity();
  const glm::vec3 w = v / std::sqrt(d2);
  return std::max(0.0f, ProjectedAreaToward(sh_area, w)) / d2;
}
inline float NodeSolidAngle(const glm::vec3& lo, const glm::vec3& hi, const float* sh_area,
                            const glm::vec3& p) {
  return NodeSolidAngleFrom(0.5f * (lo + hi), sh_area, p);
}

// The lobe-aware cut (Cut::lobe): its per-query constants, made once per gather by
// MakeLobeCut, and the weight of a node (LobeWeight in pbgi/query.h). LobeCutWeight is
// non-decreasing in the cosine x and lies in [min_weight, max_weight] (max_weight is its value
// at x = 1), so that the traversal's shortcuts (ClearlyBelowCut with max_sa / max_weight,
// solid_angle * max_weight < max_sa, solid_angle * min_weight >= max_sa) decide as the exact
// test would, rounding included.
struct LobeCut {
  bool active = false;
  bool phong = true;        // else GGX
  glm::vec3 axis{0, 0, 1};  // unit
  float exponent = 0.0f;    // Phong
  float k = 0.0f;           // GGX: alpha^2 - 1
  float scale = 1.0f;       // pi / integral of D over the hemisphere, D without its constant
  float min_weight = 1.0f;  // CutLobe::min_weight
  float max_weight = 1.0f;
};
inline float LobeCutRaw(const LobeCut& l, float x) {
  if (!(x > 0.0f)) return 0.0f;
  x = std::min(x, 1.0f);
  if (l.phong) return l.scale * std::pow(x, l.exponent);
  const float q = 1.0f + l.k * (x * x);
  return l.scale / (q * q);
}
inline float LobeCutWeight(const LobeCut& l, float x) {
  return std::clamp(LobeCutRaw(l, x), l.min_weight, l.max_weight);
}
// REQUIRES: ValidateCutLobe(lobe) is OK.
inline LobeCut MakeLobeCut(const CutLobe& lobe) {
  LobeCut l;
  if (lobe.kind == CutLobeKind::kNone) return l;
  l.active = true;
  l.axis = glm::normalize(lobe.direction);
  l.min_weight = lobe.min_weight;
  if (lobe.kind == CutLobeKind::kPhong) {
    l.phong = true;
    l.exponent = lobe.phong_exponent;
    // integral of x^e over the hemisphere: 2 pi / (e + 1)
    l.scale = static_cast<float>(0.5 * (double(lobe.phong_exponent) + 1.0));
  } else {
    l.phong = false;
    const double a2 = double(lobe.ggx_roughness) * double(lobe.ggx_roughness);
    l.k = static_cast<float>(a2 - 1.0);
    l.scale = static_cast<float>(1.0 / (2.0 * GgxLobeIntegral(1.0, double(lobe.ggx_roughness))));
  }
  l.max_weight = std::max(l.min_weight, LobeCutRaw(l, 1.0f));
  return l;
}

// The largest cosine between the unit `axis` and a direction from p into the sphere (centre,
// radius^2 radius2): 1 when p lies inside the sphere or the axis points into it, else
// cos(theta - alpha) (theta the centre's angle to the axis, alpha = asin(radius / distance)
// the sphere's half angle), which may be negative. NodeCutCosine's geometry, unclamped.
inline float NodeLobeCosine(const glm::vec3& centre, float radius2, const glm::vec3& p,
                            const glm::vec3& axis) {
  const glm::vec3 v = centre - p;
  const float d2 = glm::dot(v, v);
  if (!(d2 > radius2)) return 1.0f;
  const float inv_d = 1.0f / std::sqrt(d2);
  const float sin_a = std::sqrt(radius2) * inv_d;
  const float cos_a = std::sqrt(std::max(0.0f, 1.0f - sin_a * sin_a));
  const float cos_t = glm::dot(v, axis) * inv_d;
  if (cos_t >= cos_a) return 1.0f;
  const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
  return cos_t * cos_a + sin_t * sin_a;
}
// The cosine-weighted cut's weight (Cut::cosine_weighted): the largest cosine between the
// receiver's unit normal and a direction from p into the sphere (centre, radius^2 radius2) that
// does not contain p, clamped to [kMinCutCosine, 1]. With theta the angle of the centre's
// direction and alpha = asin(radius / distance) the sphere's half angle, it is 1 when
// theta <= alpha, else cos(theta - alpha). The traversal passes the node's near sphere
// (NodeNearSphere), the test harness the same sphere, so both get the same bits.
// It is NodeLobeCosine about the normal, clamped.
inline float NodeCutCosine(const glm::vec3& centre, float radius2, const glm::vec3& p,
                           const glm::vec3& unit_n) {
  return std::clamp(NodeLobeCosine(centre, radius2, p, unit_n), kMinCutCosine, 1.0f);
}
// The lobe weight of a node's near sphere (the conservative bound: the lobe's largest value
// over every direction into the sphere).
inline float NodeLobeWeight(const LobeCut& l, const glm::vec3& centre, float radius2,
                            const glm::vec3& p) {
  return LobeCutWeight(l, NodeLobeCosine(centre, radius2, p, l.axis));
}

// Whether a node with projected-area SH `sh_area` and bounds [lo, hi] is flat (see
// kClusterFlatness): band 0 holds pi Y0 A and band 1 holds (2 pi / 3) Y1 N, for A(w) = sum A_i
// max(0, n_i.w). A two-sided card, whose pairs cancel in N, is not flat by this test, so the cut
// refines it like a curved node (the rasterizer still draws it by its plane:
// raster/cluster_prep.cc AxisPlane).
// Counting a dominant axis of the second moment as flat here too (sh::AxisDominates) also kept
// thin slabs and wedges of one-sided surfels whole, and doubled cornell's error (docs/eval.md,
// Session 5 summary). Nor is a node with something standing on it (StandingShift() in
// base/math.h: the ground and a trunk in one box), whose mean plane does not represent it.
inline bool NodeIsFlat(const float* sh_area, const glm::vec3& lo, const glm::vec3& hi) {
  const sh::FirstMoments m = sh::AreaAndNormalSum(sh_area);
  if (!(glm::dot(m.normal_sum, m.normal_sum) >
        (kClusterFlatness * m.area) * (kClusterFlatness * m.area))) {
    return false;
  }
  int axis = 0;
  return !(StandingShift(m.normal_sum, hi - lo, &axis) > 0.0f);
}

// The max_solid_angle of one node: the cut's, scaled by curved_scale when the node is not flat.
// NodeCut is `cut` with it (the traversal reads the float alone: no copy of the Cut per node).
inline float NodeMaxSolidAngle(const Cut& cut, const float* sh_area, const glm::vec3& lo,
                               const glm::vec3& hi) {
  if (cut.curved_scale == 1.0f || NodeIsFlat(sh_area, lo, hi)) return cut.max_solid_angle;
  return cut.max_solid_angle * cut.curved_scale;
}
// The curved-box test (Cut::curved_box_scale): a node that is not flat is drawn as its box
// (raster/footprints.cc, BoxSilhouette), its content's projected area spread evenly over the
// box's silhouette. So besides the SH test, such a node is taken whole only when that silhouette
// is small too: BoxProjectedArea(lo, hi, w) / d^2, times the same weight as the SH test (1, the
// cosine or the lobe weight), below curved_box_scale * max_solid_angle. A wall's cell that also
// holds a piece of a block beside it is seen nearly edge-on from a receiver on the wall: a small
// projected area, but a box that covers a large part of the hemisphere, drawn translucent
// (docs/design.md, "The curved-box test").
// The area of the silhouette of the box [lo, hi] seen from unit direction w:
// |w.x| * ey * ez + |w.y| * ex * ez + |w.z| * ex * ey.
inline float BoxProjectedArea(const glm::vec3& lo, const glm::vec3& hi, const glm::vec3& w) {
  const glm::vec3 e = hi - lo;
  return std::fabs(w.x) * (e.y * e.z) + std::fabs(w.y) * (e.x * e.z) + std::fabs(w.z) * (e.x * e.y);
}
// The solid angle of that silhouette from p, the box's centre `centre` (0.5f * (lo + hi)) at
// distance d: BoxProjectedArea / d^2 (infinite when p is the centre).
inline float NodeBoxSolidAngleFrom(const glm::vec3& centre, const glm::vec3& lo,
                                   const glm::vec3& hi, const glm::vec3& p) {
  const glm::vec3 v = p - centre;
  const float d2 = glm::dot(v, v);
  if (!(d2 > 0.0f)) return std::numeric_limits<float>::infinity();
  return BoxProjectedArea(lo, hi, v / std::sqrt(d2)) / d2;
}
// Whether a node passes the curved-box test: flat nodes and curved_box_scale 0 always do;
// `weight` is the SH test's weight (called only when needed).
template <typename WeightFn>
inline bool BelowCurvedBoxCut(const Cut& cut, bool flat, const glm::vec3& centre,
                              const glm::vec3& lo, const glm::vec3& hi, const glm::vec3& p,
                              WeightFn&& weight) {
  if (flat || !(cut.curved_box_scale > 0.0f)) return true;
  return NodeBoxSolidAngleFrom(centre, lo, hi, p) * weight() <
         cut.curved_box_scale * cut.max_solid_angle;
}

// The cut that sees radiance (Cut::radiance_contrast; docs/design.md, "A cut that sees
// radiance"): a node's max_solid_angle is divided by max(1, radiance_contrast * c), c its
// stored contrast (tree/format.h, ContrastValue) times min(1, L / contrast_floor), L the
// luminance of its mean radiance (band 0 of `power` over band 0 of its projected area). 1
// without a contrast or a radiance channel. The traversal and the test harness both divide by
// exactly this.
// The luminance of a node's mean radiance: band 0 of its power over band 0 of its projected
// area, the mean of the channels (0 without area).
inline float NodeLuminance(const std::array<Sh9, 3>& power, float sh_area0) {
  return sh_area0 > 0.0f ? (power[0][0] + power[1][0] + power[2][0]) / (3.0f * sh_area0) : 0.0f;
}
inline float NodeContrastScale(const Cut& cut, float contrast, const std::array<Sh9, 3>& power,
                               float sh_area0) {
  if (!(cut.radiance_contrast > 0.0f) || !(contrast > 0.0f)) return 1.0f;
  float c = contrast;
  if (cut.contrast_floor > 0.0f) {
    c *= std::clamp(NodeLuminance(power, sh_area0) / cut.contrast_floor, 0.0f, 1.0f);
  }
  return std::max(1.0f, cut.radiance_contrast * c);
}

inline Cut NodeCut(const Cut& cut, const float* sh_area, const glm::vec3& lo, const glm::vec3& hi,
                   float contrast_scale = 1.0f) {
  Cut c = cut;
  c.max_solid_angle = NodeMaxSolidAngle(cut, sh_area, lo, hi);
  if (contrast_scale > 1.0f) c.max_solid_angle /= contrast_scale;
  return c;
}

// Whether a node whose solid angle from the receiver is `solid_angle` passes the cut's
// criterion; `cosine` is NodeCutCosine() of its near sphere, read only when cosine_weighted
// and there is no lobe; `lobe_weight` NodeLobeWeight() of it, read only with a lobe.
// BelowPlainCut is the test without a lobe, for a node's max_solid_angle `max_sa`.
template <typename CosineFn>
inline bool BelowPlainCut(float solid_angle, float max_sa, bool cosine_weighted,
                          CosineFn&& cosine) {
  if (solid_angle < max_sa) return true;
  return cosine_weighted && solid_angle * cosine() < max_sa;
}
template <typename CosineFn, typename LobeFn>
inline bool BelowCut(float solid_angle, const Cut& cut, CosineFn&& cosine, LobeFn&& lobe_weight) {
  if (cut.lobe.kind != CutLobeKind::kNone) return solid_angle * lobe_weight() < cut.max_solid_angle;
  return BelowPlainCut(solid_angle, cut.max_solid_angle, cut.cosine_weighted, cosine);
}

// A conservative bound of how far a disk of a node reaches beyond its bounds: sqrt(area / pi).
inline float NodeReach(float area) {
  return std::sqrt(std::max(0.0f, area) * float(1.0 / sh::kPi));
}

// The near-field rule: a receiver within the bounding sphere of a node's bounds, grown by its
// disk reach, always descends into the node rather than taking it as one cluster. (A flat patch
// seen edge-on from a receiver just off its plane subtends a tiny solid angle from its centre,
// yet covers half the receiver's view: testing the box alone splatted it as a speck.)
// NearSphere gives that sphere's centre and squared radius once per node; NodeNearFieldSphere
// tests it (the same bits as NodeNearField).
struct NearSphere {
  glm::vec3 centre;
  float radius2;
};
inline NearSphere NodeNearSphere(const glm::vec3& lo, const glm::vec3& hi, float reach) {
  const glm::vec3 half = 0.5f * (hi - lo);
  const float r = glm::length(half) + reach;
  return {lo + half, r * r};
}
inline bool NodeNearFieldSphere(const glm::vec3& centre, float radius2, const glm::vec3& p) {
  const glm::vec3 d = p - centre;
  return glm::dot(d, d) <= radius2;
}
inline bool NodeNearField(const glm::vec3& lo, const glm::vec3& hi, float reach,
                          const glm::vec3& p) {
  const NearSphere s = NodeNearSphere(lo, hi, reach);
  return NodeNearFieldSphere(s.centre, s.radius2, p);
}

// Whether a node (bounds of surfel centres, disk reach) lies wholly behind the tangent plane
// (unit normal) or wholly beyond max_distance: the traversal skips it. Both keep a small
// margin so that rounding never makes them drop a surfel that the exact surfel tests keep.
// The margin grows with the largest coordinate magnitude of the node and the receiver:
// NodeMarginOf(AbsMax(lo, hi), AbsMax(p)) == NodeMargin(lo, hi, p), so the traversal computes
// the node's part once per page and the receiver's once per gather.
inline float AbsMax(const glm::vec3& v) {
  return std::max(std::abs(v.x), std::max(std::abs(v.y), std::abs(v.z)));
}
inline float AbsMax(const glm::vec3& lo, const glm::vec3& hi) {
  return std::max(AbsMax(lo), AbsMax(hi));
}
inline float NodeMarginOf(float node_abs_max, float p_abs_max) {
  return 1e-5f * (1.0f + std::max(node_abs_max, p_abs_max));
}
inline float NodeMargin(const glm::vec3& lo, const glm::vec3& hi, const glm::vec3& p) {
  return NodeMarginOf(AbsMax(lo, hi), AbsMax(p));
}
// `far` is the corner of the bounds farthest along unit_n (hi where unit_n > 0, else lo).
inline bool NodeWhollyBehindFar(const glm::vec3& far, float reach, const glm::vec3& p,
                                const glm::vec3& unit_n, float margin) {
  return glm::dot(unit_n, far - p) + reach < -margin;
}
inline bool NodeWhollyBehindMargin(const glm::vec3& lo, const glm::vec3& hi, float reach,
                                   const glm::vec3& p, const glm::vec3& unit_n, float margin) {
  const glm::vec3 far{unit_n.x > 0 ? hi.x : lo.x, unit_n.y > 0 ? hi.y : lo.y,
                      unit_n.z > 0 ? hi.z : lo.z};
  return NodeWhollyBehindFar(far, reach, p, unit_n, margin);
}
inline bool NodeWhollyBehind(const glm::vec3& lo, const glm::vec3& hi, float reach,
                             const glm::vec3& p, const glm::vec3& unit_n) {
  return NodeWhollyBehindMargin(lo, hi, reach, p, unit_n, NodeMargin(lo, hi, p));
}
inline bool NodeBeyondMargin(const glm::vec3& lo, const glm::vec3& hi, float reach,
                             const glm::vec3& p, float max_distance, float margin) {
  const glm::vec3 d = glm::max(glm::max(lo - p, p - hi), glm::vec3(0.0f));
  return glm::length(d) - reach > max_distance + margin;
}
inline bool NodeBeyond(const glm::vec3& lo, const glm::vec3& hi, float reach, const glm::vec3& p,
                       float max_distance) {
  return NodeBeyondMargin(lo, hi, reach, p, max_distance, NodeMargin(lo, hi, p));
}

}  // namespace pbgi::internal

#endif  // PBGI_TREE_CUT_H_
