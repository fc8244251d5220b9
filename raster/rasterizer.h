// The rasterizer behind Shade(): prepares the gathered elements in the receiver's frame,
// splats them into the micro-buffer (cones for far elements, ray-sampled disks for near
// surfels) in depth layers, and integrates. One per Shade() call, over a caller's MicroBuffer.
#ifndef PBGI_RASTER_RASTERIZER_H_
#define PBGI_RASTER_RASTERIZER_H_

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include "absl/status/status.h"
#include "glm/geometric.hpp"
#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"
#include "raster/cluster_prep.h"
#include "raster/polygon_coverage.h"
#include "raster/simd.h"

namespace pbgi::internal {

// A polygon footprint whose opacity (PreparedSplat::alpha) is at least this is opaque: its
// fragments carry coverage masks (Rasterizer::Layer()).
inline constexpr float kMaskOpacity = 0.999f;

// Cones up to 2 * kBoxMaxHalf pixels wide are splatted as squares (SplatBox), which then span
// at most kBoxMaxSpan pixels per axis.
inline constexpr float kBoxMaxHalf = 1.0f;
inline constexpr int kBoxMaxSpan = 4;
// A fragment extends a layer's depth range only if its normal is within acos(kChainCos) = 45.6
// degrees of the layer's first fragment's (see Emit()).
inline constexpr float kChainCos = 0.7f;
// PixelState::porous of a layer whose first fragment is porous and flat: a piece of a two-sided
// sheet, whose coverage mask is where the sheet lies (Rasterizer::Close()).
inline constexpr float kPorousSheet = 2.0f;
// A cluster counts as flat (depth from its mean plane) when |sum A_i n_i| > kFlatness * A.
inline constexpr float kFlatness = kClusterFlatness;
// Rays closer than this cosine to a flat element's plane keep its bounding-sphere depth range.
inline constexpr float kMinPlaneCos = 1e-3f;

// The footprint box of content whose surfel centres have bounds `centres` and spacing
// `spacing`, inside its octree cell (raster/footprints.cc): grown to the cell's side where the
// content comes within 1.5 spacings of where it leaves the cell, else by half a spacing; along
// an axis near the plane's normal it is the cell's extent, padded to hold the centres (the
// plane, turned from that axis, runs across it to the cell's sides). `reach`: the plane's own
// extent inside the cell (PlaneReach): a plane turned from the axes leaves the cell through
// one axis's side before it reaches another's; without it, the cell's sides. *full: the plane
// with `plane_normal` fills the cell (every in-plane side reached it). *snapped: bit 2k
// (2k+1) set when the low (high) side of axis k reached the cell. Without a usable cell
// (empty, or not holding `centres`), every side grows by half a spacing.
Bounds FootprintBox(const Bounds& centres, const Bounds& cell, float spacing,
                    const glm::vec3& plane_normal, bool* full, int* snapped = nullptr,
                    const Bounds* reach = nullptr);
// A box's lo and hi as four lanes each, the fourth repeating the third: Bounds is six floats,
// read as two overlapping four-float loads within it.
inline void LoadBounds(const Bounds& b, V4* lo, V4* hi) {
  static_assert(sizeof(Bounds) == 6 * sizeof(float));
  const char* p = reinterpret_cast<const char*>(&b);
  V4 l, h;
  std::memcpy(&l, p, sizeof l);
  std::memcpy(&h, p + 2 * sizeof(float), sizeof h);
  *lo = __builtin_shufflevector(l, l, 0, 1, 2, 2);
  *hi = __builtin_shufflevector(h, h, 1, 2, 3, 3);
}
// Whether the boxes a and b (not empty), grown by ga and gb on every side, overlap or touch:
// a.lo - ga <= b.hi + gb and b.lo - gb <= a.hi + ga along every axis, the three axes in lanes.
inline bool GrownBoxesOverlap(const Bounds& a, float ga, const Bounds& b, float gb) {
  V4 alo, ahi, blo, bhi;
  LoadBounds(a, &alo, &ahi);
  LoadBounds(b, &blo, &bhi);
  return Movemask4((alo - ga <= bhi + gb) & (blo - gb <= ahi + ga)) == 0xf;
}
// The bounds of the plane {dot(normal, x) = offset} (x relative to `origin`) inside `cell`,
// padded by kPlanePad spacings along the axes nearly along the normal, in world coordinates;
// false when it misses the cell or lies along the axes (then the cell's sides serve).
bool PlaneReach(const glm::vec3& normal, float offset, const Bounds& cell, float spacing,
                const glm::vec3& origin, Bounds* reach);
// FootprintBox of a flat element on the plane {dot(normal, x) = offset} (x relative to
// `origin`), with the plane's reach where a side did not snap to the cell's.
Bounds FlatBox(const Bounds& centres, const Bounds& cell, float spacing, const glm::vec3& normal,
               float offset, const glm::vec3& origin, bool* full, int* snapped);

// The flat footprint of content of area `area` on the plane {dot(normal, x) = offset} (x
// relative to `origin`): the plane inside the footprint box, its free in-plane sides moved out
// until the polygon holds the content's area (a surface that ends inside its cell ends where
// its area says, not where the outermost centres say, so that sampling that puts more centres
// in one cell than its area does not lose the excess). Returns the coverage inside the
// polygon (1 when the plane fills the cell), or 0 with p->n = 0 when there is no polygon.
// `backs`: the receiver sees the content's backs (ShowsBacks); the plane never fills the cell.
// `sheet` (optional): set when the plane fills its cell, with at least 70 % of its area, and
// the cell is more than 36 surfels' areas wide: a piece of one sheet, not of foliage
// (docs/design.md, "Porous layers").
float FlatFootprint(const Bounds& centres, const Bounds& cell, float spacing,
                    const glm::vec3& normal, float offset, const glm::vec3& origin, double area,
                    bool backs, Polygon* p, bool* sheet = nullptr);

// A two-sided pair's footprint on the same plane: a rhombus along the pair of centres c1, c2
// holding `area` (docs/design.md, "A leaf's pieces"). Returns its coverage, or -1 when the
// centres coincide.
float PairFootprint(const glm::vec3& c1, const glm::vec3& c2, const glm::vec3& normal, float offset,
                    const glm::vec3& origin, float spacing, double area, Polygon* p);

// A two-sided group's footprint on the same plane: the rectangle of its members' centres
// (surfels[members[0 .. count)]) along their principal axes in the plane, grown to hold `area`
// (docs/design.md, "A leaf's pieces"). Returns its coverage, or -1 when it has no extent.
float InPlaneFootprint(const Surfel* surfels, const uint32_t* members, int count,
                       const glm::vec3& normal, float offset, const glm::vec3& origin,
                       float spacing, double area, Polygon* p);

// Shades one receiver into a MicroBuffer that it borrows. Not thread-safe (neither is the
// buffer); cheap to construct: everything it keeps lives in the MicroBuffer.
class Rasterizer {
 public:
  Rasterizer(MicroBuffer* mb, const RasterOptions& o)
      : mb_(*mb),
        o_(o),
        res_(mb->res_),
        radiance_(o.compute_radiance),
        clamp_(o.clamp),
        px_(mb->pixels_.data()),
        shut_(mb->shut_.data()),
        dirs_(mb->dirs_.data()),
        omega_(mb->omega_f_.data()),
        inv_omega_(mb->inv_omega_f_.data()),
        dir_x_(mb->dir_x_.data()),
        dir_y_(mb->dir_y_.data()),
        dir_z_(mb->dir_z_.data()),
        half_width_(mb->half_width_.data()),
        max_width_(mb->max_width_),
        avx2_(UseAvx2()),
        polygons_(o.footprint == Footprint::kPolygons),
        free_layer_(!polygons_),
        bound_(polygons_ && o.clamp && o.bound_by_footprints) {
    mb->free_layer_ = free_layer_;
  }

  absl::Status Run(const Gathered& g, const ShadeReceiver& r, ShadeResult* out);
  // A diagnostic: the elements of the last Shade() into `mb` that draw on `pixel`, nearest
  // first, with their footprints as the whole gather shaped them (a footprint can depend on its
  // neighbours: SheetCell, the junction clips): polygons with their exact share of the pixel,
  // and exact disks and far clusters' cones whose disk or cone the pixel's central ray crosses.
  // A cluster found hidden behind closed pixels before its footprint was built is not listed.
  struct FootprintOver {
    enum Kind : uint8_t { kPolygon, kDisk, kCone };
    float depth;     // the element's depth (PreparedSplat::depth)
    float alpha;     // coverage inside a polygon (1 for a disk or a cone)
    float coverage;  // a polygon's share of the pixel, before alpha; -1 for the others
    uint8_t flags;   // kSplatPorous, kSplatBack
    Kind kind;
    int32_t cluster;   // its index in Gathered::clusters, or -1 for surfels and their groups
    glm::vec3 normal;  // a polygon's unit normal; a disk's or a cone's element normal (local)
  };
  static void FootprintsOver(const MicroBuffer& mb, int pixel, std::vector<FootprintOver>* out);
  // The next Run() composites `far` behind its elements (ShadeWithFar() in pbgi/raster.h).
  void set_far(const FarBuffer* far) { far_ = far; }
  // What the last Run() left in the hemisphere's pixels, as a far buffer (ShadeFar()).
  void ExportFar(const ShadeReceiver& r, FarBuffer* out) const;

  // The pixel's coverage is at most the share of its samples that its fragments' footprints
  // touched (PixelState::touched, RasterOptions::bound_by_footprints), after its last layer
  // closed: translucent footprints (a
  // cluster's box, a partly filled plane) count as spread evenly over the pixel, so layers of
  // them behind each other add up in samples that none of them touches. The far edge of the
  // city against the void, seen just below a high wall's horizon: every cluster there covers
  // the lower third of the pixel, rays 0.4, the layers 1.0 (bug: translucent_layers_fill_void).
  // Only where a translucent polygon contributed: opaque ones compose by their masks already,
  // and their exact areas need not match their samples' count.
  template <bool kRad>
  [[gnu::always_inline]] static void CapByTouched(PixelState& px) {
    if (px.translucent == 0 || px.touched == ~uint64_t{0}) return;
    const float cap = static_cast<float>(std::popcount(px.touched)) * (1.0f / 64.0f);
    if (!(px.closed > cap)) return;
    if constexpr (kRad) {
      const float scale = cap / px.closed;
      for (float& c : px.closed_rgb) c *= scale;
    }
    px.closed = cap;
  }

  // The pixel's cosine weight where its coverage lies, over its mean weight: the coverage of a
  // pixel is weighted by the samples it covers, not by the pixel's centre. Up to an upward
  // receiver's horizon the weight grows from 0 across a pixel (cos ~ elevation), and a wall's
  // top edge in the pixel covers its lower part: weighted by the whole pixel it counted up to
  // twice its share, and the city's streets and roofs, which see buildings standing up to that
  // edge, came out +0.003 too dark at res 12 (docs/eval.md, "Session 17"). The samples are the
  // closed layers' coverage masks where only opaque polygons drew (and their count matches the
  // coverage), else the samples the fragments' footprints touched, spread evenly; unknown
  // (a disk, a splat: every sample touched) or a pixel wholly covered, 1. `gx`, `gy`: the
  // weight's slope per sample column and row (MicroBuffer::hemi_slope_x_).
  [[gnu::always_inline]] static float SampleWeight(const PixelState& px, float gx, float gy) {
    if (!(px.closed > 0.0f) || !(px.closed < 1.0f) || px.touched == ~uint64_t{0}) return 1.0f;
    uint64_t s = px.touched;
    if (px.translucent == 0 && px.closed_mask != 0 &&
        std::fabs(px.closed - static_cast<float>(std::popcount(px.closed_mask)) * (1.0f / 64.0f)) <=
            2.0f / 64.0f) {
      s = px.closed_mask;
    }
    const int n = std::popcount(s);
    if (n == 0) return 1.0f;
    const int sx = std::popcount(s & 0xAAAAAAAAAAAAAAAAull) +
                   2 * std::popcount(s & 0xCCCCCCCCCCCCCCCCull) +
                   4 * std::popcount(s & 0xF0F0F0F0F0F0F0F0ull);
    const int sy = std::popcount(s & 0xFF00FF00FF00FF00ull) +
                   2 * std::popcount(s & 0xFFFF0000FFFF0000ull) +
                   4 * std::popcount(s & 0xFFFFFFFF00000000ull);
    const float fn = static_cast<float>(n);
    return 1.0f +
           (gx * (static_cast<float>(sx) - 3.5f * fn) + gy * (static_cast<float>(sy) - 3.5f * fn)) /
               fn;
  }

  // `behind`: a fragment wholly behind the layer closes it. The first layer keeps its free sum
  // only when nothing lies behind it (a lone surface whose splats' overlaps and gaps cancel);
  // with a surface behind, the gaps are filled by that surface, so the overlaps must not count
  // twice: the layer is clamped at 1 like the later ones (bug: hidden_surface_overcount).
  //
  // Coverage masks: a layer of polygon fragments fills only what its samples leave uncovered by
  // the nearer layers' samples, not whatever coverage is left: a wall behind the lower half of a
  // pixel's roof edge adds nothing there when it too covers only that lower half (bug:
  // hidden_layer_fills_visible_gap; the scalar rule counted the pixel full). Porous layers
  // stay independent ones.
  template <bool kRad>
  static void Close(PixelState& px, bool behind, bool free_layer) {
    if (!(px.open > 0.0f)) return;
    float open = px.open;
    // A two-sided sheet's porous layer whose pieces carry masks, behind closed masks
    // (PorousMaskedShare). A porous cluster's mask is its box's silhouette, not where its
    // content lies: such layers keep the independent rule (the city's view: MAE 0.00487 with
    // sheets' layers alone, 0.00494 with every porous layer; docs/eval.md, "Session 30").
    const float porous_e = px.porous == kPorousSheet && px.open_mask != 0 && px.closed_mask != 0
                               ? PorousMaskedShare(px)
                               : -1.0f;
    if (px.porous == 0.0f) {
      if (const uint64_t hidden = px.open_mask & px.closed_mask; hidden != 0) {
        // Only the masked share: coverage that came without a mask (a translucent cluster's
        // box silhouette) is not known to lie on those samples (bug:
        // unmasked_coverage_scaled_by_hidden_samples).
        const float masked = std::min(px.open_masked, open);
        open -= masked * (1.0f - static_cast<float>(std::popcount(px.open_mask & ~hidden)) /
                                     static_cast<float>(std::popcount(px.open_mask)));
      }
    }
    // A sheet's porous layer's masks are where its pieces lie, as much as a solid one's: the
    // layers behind find them hidden too (bug: porous_layers_forget_their_masks).
    if (px.porous == 0.0f || px.porous == kPorousSheet) px.closed_mask |= px.open_mask;
    px.open_mask = 0;
    px.open_masked = 0.0f;
    const float e = free_layer && px.closed == 0.0f && !behind ? open
                    : porous_e >= 0.0f                         ? porous_e
                    : px.porous != 0.0f ? std::min(open, 1.0f) * std::max(0.0f, 1.0f - px.closed)
                                        : std::min(open, std::max(0.0f, 1.0f - px.closed));
    const float closed = px.closed + e;
    if constexpr (kRad) {
      const V4 open = Load4(&px.open);
      Store4(&px.closed, Load4(&px.closed) + (e / px.open) * open);
      Store4(&px.open, V4{0.0f, 0.0f, 0.0f, 0.0f});
    } else {
      px.open = 0.0f;
    }
    px.closed = closed;  // exactly closed + e, not closed + (e / open) * open
    px.far = 0.0f;
  }

  // What a closing porous layer whose pieces carry coverage masks adds behind closed layers
  // that have masks too. Its masked coverage lies on its samples: those the closed masks cover
  // are hidden, and the rest are free but for the closed coverage that came without masks
  // (FreeOfUnmasked). Its unmasked coverage (a leaf's disk, a translucent cluster's box) is a
  // leaf's, at no known place, and fills (1 - closed) of itself. With no closed masks this is
  // Close()'s independent layer, min(open, 1) (1 - closed). Composed that way, a fold of
  // spider.obj's body behind another filled what the nearer fold's coverage left, over samples
  // that the nearer fold's masks covered (docs/design.md, "Porous layers").
  [[gnu::always_inline]] static float PorousMaskedShare(const PixelState& px) {
    const float masked = std::min(px.open_masked, px.open);
    const float seen = static_cast<float>(std::popcount(px.open_mask & ~px.closed_mask)) /
                       static_cast<float>(std::popcount(px.open_mask));
    const float left = std::max(0.0f, 1.0f - px.closed);
    return std::min(left, masked * seen * FreeOfUnmasked(px.closed, px.closed_mask) +
                              std::min(px.open - masked, 1.0f) * left);
  }
  // The share of each sample outside `mask` that coverage `coverage` leaves free, where
  // `mask`'s samples hold `mask`'s share of it and the rest came without masks, spread evenly
  // over the samples outside the mask.
  [[gnu::always_inline]] static float FreeOfUnmasked(float coverage, uint64_t mask) {
    const int m = std::popcount(mask);
    if (m >= 64) return 0.0f;
    const float fm = static_cast<float>(m) * (1.0f / 64.0f);
    return std::max(0.0f, 1.0f - std::max(0.0f, coverage - fm) / (1.0f - fm));
  }
  // What a leaf (a porous fragment without a mask, coverage `cov`, its footprint touching the
  // samples `touched`) adds beside an open layer: its coverage spread over the samples it
  // touches, less those that the open and closed layers' masks cover, and the rest free but for
  // their coverage without masks. With no masks, or touching every sample, it is
  // min(cov, 1) (1 - closed - open). Counted at no known place, a crumpled curved cell of a
  // cab's wall beside the wall's flat cells filled only what the wall left of its pixels,
  // though it lies in none of the wall's samples (docs/design.md, "Porous layers").
  [[gnu::always_inline]] static float LeafShare(const PixelState& px, float cov, uint64_t touched) {
    const float plain = std::min(cov, 1.0f) * std::max(0.0f, 1.0f - px.closed - px.open);
    const uint64_t known = px.open_mask | px.closed_mask;
    const int nt = std::popcount(touched);
    if (known == 0 || nt == 0 || touched == ~uint64_t{0} || !(plain > 0.0f)) return plain;
    return std::min(cov, 1.0f) *
           (static_cast<float>(std::popcount(touched & ~known)) / static_cast<float>(nt)) *
           FreeOfUnmasked(px.closed + px.open, known);
  }

  // A flat fragment's depth range along pixel direction u: where the pixel's central ray meets
  // the slab of half thickness `thick` around its plane, widened by t * half the pixel's width /
  // cos(incidence), a bound on the depth change across half the pixel (t * half width *
  // tan(incidence)) that needs no square root (same MAE on cornell and sphere-in-box, 3% fewer
  // instructions). Co-planar fragments then get the same range in a pixel however far apart their
  // centres lie, so a surface seen at a grazing angle stays one layer without chaining. The range
  // is clamped to the element's own [lo0, hi0] (its centre's depth -+ its extent): every hit of
  // the element lies there. Unclamped, a plane seen nearly edge-on reached hundreds of extents
  // past the element, and the fragments behind it joined its open layer (bug:
  // grazing_plane_range_merges_layers; docs/eval.md, Session 12). A ray (nearly) parallel to the
  // plane keeps [lo, hi] as given.
  [[gnu::always_inline]] static void PlaneDepthRange(const PixelDir& u, const glm::vec3& normal,
                                                     float plane, float thick, float lo0, float hi0,
                                                     float* lo, float* hi) {
    const float mu = normal.x * u.x + normal.y * u.y + normal.z * u.z;
    if (!(mu < -kMinPlaneCos)) return;
    const float inv = -1.0f / mu;  // 1 / cos(incidence)
    const float t = -plane * inv;
    const float half = (thick + t * u.half_width) * inv;
    *lo = std::clamp(t - half, lo0, hi0);
    *hi = std::clamp(t + half, lo0, hi0);
  }

 private:
  void Reset();
  void SortByDepth();
  void SetFrame(const ShadeReceiver& r);
  glm::vec3 ToLocal(const glm::vec3& v) const {
    return glm::vec3(glm::dot(t_, v), glm::dot(b_, v), glm::dot(n_, v));
  }
  // ToLocal() in lanes 0-2, the same values.
  V4 ToLocal4(const glm::vec3& v) const {
    return MulColumns4(col_x_, col_y_, col_z_, v.x, v.y, v.z);
  }
  template <bool kRad>
  void PrepareClusters(const std::vector<Cluster>& clusters);
  void PrepareSurfel(const Surfel& s, ShadeResult* out);
  // Surfels grouped by leaf and normal into co-planar polygons (raster/footprints.cc).
  void PrepareSurfelGroups(const Gathered& g, ShadeResult* out);
  // The footprint polygons of prepared cluster splat s (raster/footprints.cc), built as it is
  // drawn, so that a hidden cluster costs none. False: the cluster shows nothing (the
  // receiver's own surface seen from behind).
  bool BuildClusterFootprint(const Cluster& c, PreparedSplat& s);
  // With clamp, whether drawing cluster splat s (not yet built), whose BilinearConeClosed()
  // holds, would change nothing: every pixel that its footprint, or the cone splat it may fall
  // back to, could reach is closed and already as near (raster/footprints.cc). False when that
  // is not certain.
  bool ClusterHidden(const Cluster& c, const PreparedSplat& s) const;
  // Whether every pixel that a polygon inside the box [lo, hi] (world axes) could cover is
  // closed, with depth <= `depth`; false when the box is not on one face's pyramid.
  bool BoxClosed(const glm::vec3& lo, const glm::vec3& hi, float depth) const;
  // Whether s's cone splat is a bilinear one (SplatCone) whose four pixels are closed, with
  // depth <= s.depth.
  bool BilinearConeClosed(const PreparedSplat& s) const;
  // Whether every pixel first + row * res + col, col0 <= col <= col1, row0 <= row <= row1, is
  // closed (closed >= 1, where Emit() only lowers depth) with depth <= `depth`. Asked of the
  // pixels' shut_ (NaN compares false): a pixel's state is 96 bytes, and these reads of two
  // floats in it were the rasterizer's most sampled line.
  bool RectClosed(uint32_t first, int col0, int col1, int row0, int row1, float depth) const {
    for (int row = row0; row <= row1; ++row) {
      const float* shut = shut_ + first + static_cast<uint32_t>(row * res_);
      for (int col = col0; col <= col1; ++col) {
        if (!(shut[col] <= depth)) return false;
      }
    }
    return true;
  }
  // Appends a polygon given relative to the receiver in world axes, in the receiver's frame and
  // clipped to its hemisphere, to s's polygons.
  void AddPolygon(const Polygon& world_rel, PreparedSplat* s);
  void Integrate(const ShadeReceiver& r, ShadeResult* out);
  // The far buffer behind what Draw() left (set_far()).
  template <bool kClamp, bool kRad>
  void CompositeFar();
  // Whether a surfel or co-planar group (unit `normal`, centre at `rel` from the receiver) is
  // the receiver's own surface seen from behind, its plane passing within `reach` (a radius, a
  // spacing) of the receiver: a receiver never sees that, so it is culled.
  // - One-sided, with hitsides both: the receiver lies behind its plane (with front it is
  //   culled as a back face anyway).
  // - Two-sided, in every mode: its centre lies behind the receiver's tangent plane (so it
  //   and the receiver's surface are one sheet bent convexly, or folded over a convex edge)
  //   and its plane passes within `reach` of the receiver on either side. Its disk, tilted by
  //   the bend, passes just above the receiver, and drawn from its back (a two-sided surfel
  //   shows both) it covered up to the whole hemisphere (bug:
  //   convex_thin_sheet_covers_its_receiver). A separate sheet over the receiver (a decal over
  //   a panel, a leaf over the ground) has its centre in front and still occludes.
  // - Either way, not when `sheet` and the receiver's sheet tag (Surfel::sheet) are both known
  //   and differ: then it is another sheet crossing the receiver's (a leaf through a leaf),
  //   whatever its place (docs/design.md, "Sheet tags").
  bool OwnSurfaceFromBehind(bool two_sided, uint8_t sheet, const glm::vec3& normal,
                            const glm::vec3& rel, float reach) const {
    const float side = -glm::dot(normal, rel);  // > 0: the receiver is in front
    if (!two_sided) return o_.hitsides == HitSides::kBoth && side < 0.0f && -side < reach;
    if (OtherSheet(sheet)) return false;
    return std::fabs(side) < reach && glm::dot(n_, rel) < 0.0f;
  }
  // Whether a two-sided element's sheet tag says it is not the receiver's sheet.
  bool OtherSheet(uint8_t sheet) const { return sheet != 0 && sheet_ != 0 && sheet != sheet_; }
  // Whether a two-sided co-planar group (unit `normal`, centre at `rel`, its surfel centres
  // within `thickness` of its plane) is the receiver's own sheet bent concavely: the receiver
  // lies behind the sheet turned its way (normal towards the receiver's normal), no farther
  // than the group's own thickness. The group's mean plane then passes just above the
  // receiver, the sheet curving up on both sides of it, and drawn it covered most of the
  // hemisphere (bug: concave_thin_sheet_covers_its_receiver: 1.0 inside a two-sided half-pipe
  // that rays give 0.29). The centre is in front, so OwnSurfaceFromBehind() keeps it. A
  // separate sheet above the receiver is flat within its own group, so lies farther than its
  // thickness (at least kOwnSheetReach of a spacing) and still occludes.
  static constexpr float kOwnSheetReach = 0.075f;
  // The caller skips it for a group whose sheet tag and the receiver's are both known and
  // differ (OtherSheet): a leaf crossing the receiver's leaf at the receiver was culled here
  // (bug: crossing_leaf_culled_as_the_receivers_concave_sheet; docs/design.md, "Sheet tags").
  bool InsideOwnSheet(const glm::vec3& normal, const glm::vec3& rel, float thickness,
                      float spacing) const {
    const float side = -glm::dot(normal, rel);
    const float s = glm::dot(normal, n_) >= 0.0f ? side : -side;
    return s < 0.0f && -s < std::max(thickness, kOwnSheetReach * spacing);
  }
  // A receiver on a crease (on a wall, where the floor meets it) lies in the other surface's
  // plane, and the stored positions place that plane up to a grid step either side of it: on
  // cornell's floor half a step up, so that a wall receiver a rounding above the floor was
  // behind it, the floor culled, and the pixel along each of the room's edges lost half its
  // occlusion (0.47 for rays' 0.97: docs/eval.md, "Session 16"). So a one-sided element whose
  // plane crosses the receiver's tangent plane (the cosine between their normals below
  // kCreaseCos) and that the receiver lies behind by at most crease_tol_ (the gather's position
  // tolerance, or a few float steps of the receiver's coordinates) counts as in front: moved
  // back along its normal by the returned distance, so that the receiver lies crease_tol_ in
  // front. The receiver's own surface (the cosine at least kCreaseCos) keeps its side.
  static constexpr float kCreaseCos = 0.9f;
  float CreaseShift(bool two_sided, const glm::vec3& normal, float side) const {
    if (two_sided || !(std::fabs(glm::dot(normal, n_)) < kCreaseCos)) return 0.0f;
    if (o_.hitsides == HitSides::kBack) {
      return side >= 0.0f && side < crease_tol_ ? -crease_tol_ - side : 0.0f;
    }
    return side <= 0.0f && side > -crease_tol_ ? crease_tol_ - side : 0.0f;
  }
  // PreparedSplat::flags of a surfel or co-planar group: a two-sided one is a piece of a leaf
  // (porous); with hitsides both, a one-sided one seen from behind is kSplatBack. See Layer().
  uint8_t SurfelFlags(bool two_sided, float side) const {
    if (!polygons_) return 0;
    if (two_sided) return kSplatPorous;
    return o_.hitsides == HitSides::kBoth && side < 0.0f ? kSplatBack : 0;
  }

  // What Emit() needs of the element being drawn, by value: through a pointer into the
  // splats the compiler would reload it after every store to a pixel.
  struct Frag {
    V4 rgb1;              // {1, radiance}
    float depth, lo, hi;  // centre distance and depth range [lo, hi]
    glm::vec3 normal;     // unit, facing the receiver; 0 when unknown
    float plane, thick;   // flat: see PreparedSplat
    bool flat;
    bool porous, back;  // PreparedSplat::flags
  };
  static Frag FragOf(const PreparedSplat& s) {
    return Frag{Load4(s.rgb1),
                s.depth,
                s.depth - s.extent,
                s.depth + s.extent,
                s.normal,
                s.plane,
                s.thick,
                s.flat != 0,
                (s.flags & kSplatPorous) != 0,
                (s.flags & kSplatBack) != 0};
  }
  // What a fragment covers of its pixel's samples, as Layer() asks for it. A cone splat or a
  // near disk: no coverage mask, every sample touched.
  struct AllSamples {
    static constexpr bool kAll = true, kTranslucent = false;
    uint64_t mask() const { return 0; }
    uint64_t touched() const { return ~uint64_t{0}; }
  };
  // A polygon's fragment: an opaque one's coverage mask and the samples whose cells it overlaps;
  // a translucent one's (SplatPolygons()) cells alone, computed when asked.
  template <bool kOpaque>
  struct PolygonSamples {
    static constexpr bool kAll = false, kTranslucent = !kOpaque;
    const polygon_coverage::PixelSamples& s;
    uint64_t mask() const {
      if constexpr (kOpaque) {
        return s.mask();
      } else {
        return 0;
      }
    }
    uint64_t touched() const { return s.touched(); }
  };

  template <bool kClamp, bool kRad, bool kLanes>
  void Draw(const Gathered& g, uint32_t count);
  // Everything after cluster preparation: Reset(), the surfels, Draw(), Integrate(); on the
  // AVX2 build when avx2_ is set. kLanes: polygon footprints are rasterized in eight lanes
  // (RasterizePolygonIn), which only the AVX2 build takes: on the baseline ISA an eight-lane
  // vector is two SSE2 ones and its shuffles cost more than the vertex-at-a-time code.
  template <bool kClamp, bool kRad, bool kLanes>
  void Finish(const Gathered& g, const ShadeReceiver& r, ShadeResult* out);
  template <bool kClamp, bool kRad>
  void FinishOn(const Gathered& g, const ShadeReceiver& r, ShadeResult* out);
#if PBGI_RASTER_HAS_AVX2
  // The same code compiled for AVX2 with every call below it inlined (flatten: nothing compiled
  // for AVX2 escapes into code that the baseline path could link to). VEX encoding's
  // three-operand instructions need fewer register copies: ~10% fewer instructions. Same
  // results bit for bit: no FMA, and ISO C++ neither contracts nor reassociates.
  template <bool kClamp, bool kRad>
  __attribute__((target("avx2"), flatten)) void FinishAvx2(const Gathered& g,
                                                           const ShadeReceiver& r,
                                                           ShadeResult* out) {
    Finish<kClamp, kRad, /*kLanes=*/true>(g, r, out);
  }
#endif

  template <bool kClamp, bool kRad>
  void SplatCone(const PreparedSplat& s);
  // A square footprint of half side h pixels centred at (u, v) (pixel-edge coordinates) on
  // the face whose first pixel is `base`; q is the pixel that holds the centre.
  template <bool kClamp, bool kRad>
  void SplatBox(const PreparedSplat& s, int base, float u, float v, float h, uint32_t q);
  template <bool kClamp, bool kRad>
  void SplatDisk(const PreparedSplat& s);
  template <bool kClamp, bool kRad, bool kLanes>
  void SplatPolygons(const PreparedSplat& s);

  // Polygon footprints only: a splat spreads its element's coverage over pixels past the
  // element's extent (its filter), and one surface's splats must keep sharing a range there.
  [[gnu::always_inline]] void PlaneRange(uint32_t p, const Frag& f, float* lo, float* hi) const {
    constexpr float kInf = std::numeric_limits<float>::infinity();
    PlaneDepthRange(dirs_[p], f.normal, f.plane, f.thick, polygons_ ? f.lo : -kInf,
                    polygons_ ? f.hi : kInf, lo, hi);
  }

  // Adds a fragment of coverage `cov` to pixel p. With clamp, fragments arrive front to back:
  // one whose depth range overlaps the open layer's joins it (the splats of one surface tile it,
  // and their round footprints overlap and leave gaps that cancel only if they add up freely);
  // one wholly behind closes the layer first. The layer's range is its first fragment's,
  // extended by a joining fragment only if that faces the same way (normals within
  // kChainCos): a curved surface's splats chain along it, but a chain of fragments of
  // different surfaces (a block's top, its edge, the floor, the next block, each overlapping the
  // previous in depth) must not merge them into one layer that adds up (bug:
  // chained_surfaces_overcount). The first layer counts in full only if nothing lies behind
  // it; otherwise it, like every later one, only fills what is left below 1: nearer surfaces
  // hide farther ones (the depth test), see Close(). An open layer's `far` is 0 when it is
  // empty (every depth range ends beyond 0).
  //
  // `samples`: what the fragment's footprint covers of the pixel's samples (see Layer()).
  template <bool kClamp, bool kRad, class Samples = AllSamples>
  [[gnu::always_inline]] void Emit(uint32_t p, float cov, const Frag& f,
                                   const Samples& samples = Samples{}) {
    PixelState& px = px_[p];
    px.depth = std::min(px.depth, f.depth);
    if constexpr (!kClamp) {
      if constexpr (kRad) {
        Store4(&px.closed, Load4(&px.closed) + cov * f.rgb1);  // lane 0: closed + cov
      } else {
        px.closed += cov;
      }
    } else {
      // shut_[p] follows the pixel once it is closed (RectClosed()).
      if (px.closed >= 1.0f) {
        shut_[p] = px.depth;
        return;
      }
      float lo = f.lo, hi = f.hi;
      if (f.flat) PlaneRange(p, f, &lo, &hi);
      Layer<kRad>(px, cov, f, lo, hi, samples);
      if (px.closed >= 1.0f) shut_[p] = px.depth;
    }
  }

  // Emit() with clamp once the fragment's depth range in the pixel is known. Porous fragments
  // (f.porous: leaves) are independent of each other: a layer they start adds what it covers
  // of what the layers in front leave free, cov * (1 - closed) (Close()), and one that overlaps
  // the open layer in depth without facing its way (another leaf) adds cov * (1 - closed -
  // open) at once, so leaves at many depths multiply their transmittances where adding and
  // clamping at 1 over-occluded the forest (bug: porous_layers_overcount). A porous fragment
  // facing the layer's way (the next piece of the same leaf or card) joins it, so the
  // overlapping disks of one sheet still add up to cover it. One that carries a mask, into a
  // layer that has masks, is not a leaf of unknown place: it adds the share of its samples
  // that the layer does not cover yet, as a solid fragment does (two-sided walls meeting at a
  // corner tile the seam's pixels; composed as leaves they gave a + b - ab, 0.78 for 1, and
  // 2CylinderEngine's casing leaked: bug masked_porous_pieces_composed_as_leaves).
  //
  // `samples.mask()`: the fragment's coverage mask (a polygon's; 0 when unknown). A fragment of
  // another surface (another facing) inside the open layer's depth range adds only the share of
  // its samples that the layer does not cover yet: a roof and its wall that tile a pixel at a
  // convex edge add up to the pixel, two surfaces that overlap in it count their union, not
  // their sum (bug: overlapping_surfaces_add; the city's walls were +0.01 too dark).
  //
  // `samples.touched()`: the samples the fragment's footprint touches (the cells a polygon
  // overlaps; all when unknown), gathered in PixelState::touched, and Samples::kTranslucent,
  // whether it is a translucent polygon's: see CapByTouched().
  //
  // Both are asked only where the pixel's state needs them (a polygon's spans are found on
  // first use, polygon_coverage::FaceSamples): not for a pixel a back face cannot reach or that
  // closes, not for touched samples once all are touched, not for a porous fragment's mask
  // beside a layer without masks. The state is the same bit for bit as with both computed
  // first.
  // `f` opens the pixel's layer, whose depth range ends at `hi`: the layer takes its facing,
  // and is porous (a two-sided sheet's, kPorousSheet, when `f` is flat) when `f` is.
  [[gnu::always_inline]] static void OpenLayer(PixelState& px, const Frag& f, float hi) {
    px.far = hi;
    px.normal[0] = f.normal.x, px.normal[1] = f.normal.y, px.normal[2] = f.normal.z;
    px.porous = f.porous ? (f.flat ? kPorousSheet : 1.0f) : 0.0f;
  }

  template <bool kRad, class Samples = AllSamples>
  [[gnu::always_inline]] void Layer(PixelState& px, float cov, const Frag& f, float lo, float hi,
                                    const Samples& samples = Samples{}) {
    // A one-sided fragment seen from behind (hitsides both) behind one seen from the front is
    // the far inside of a closed object showing through its near side's footprints: with them
    // it filled what their opacity left, +0.05 to +0.10 on closed meshes (bug:
    // back_faces_fill_front_gaps).
    if (f.back) {
      if (px.front != 0.0f) return;
    } else {
      px.front = 1.0f;
    }
    if constexpr (Samples::kAll) {
      px.touched = ~uint64_t{0};
    } else if (px.touched != ~uint64_t{0}) {
      px.touched |= samples.touched();
    }
    if constexpr (Samples::kTranslucent) px.translucent |= 1u;
    if (lo > px.far && px.open > 0.0f) {
      Close<kRad>(px, /*behind=*/true, free_layer_);
      ++closes_;
      if (px.closed >= 1.0f) return;
    }
    uint64_t mask = 0;
    if (!(px.open > 0.0f)) {
      OpenLayer(px, f, hi);
      mask = samples.mask();
    } else if (f.normal.x * px.normal[0] + f.normal.y * px.normal[1] + f.normal.z * px.normal[2] >
               kChainCos) {
      px.far = std::max(px.far, hi);
      mask = samples.mask();
    } else {
      // A porous fragment without a mask is a leaf. One with a mask beside a layer without
      // masks (a translucent cluster's box or a leaf's disk came first) takes the layer over:
      // that layer closes as it would behind the fragment, and the fragment opens the next
      // one, so that the other pieces of its sheet tile with it. Composed as leaves against
      // such a layer, a sheet's pieces filled 1 - (1 - a)(1 - b)... of pixels they cover
      // wholly (bug: a_translucent_bit_makes_a_sheet_a_leaf; docs/design.md, "Porous layers").
      mask = samples.mask();
      if (f.porous && mask != 0 && px.open_mask == 0) {
        Close<kRad>(px, /*behind=*/true, free_layer_);
        ++closes_;
        if (px.closed >= 1.0f) return;
        OpenLayer(px, f, hi);
      } else if (f.porous && mask == 0) {
        // Every sample touched (a splat, a disk): min(cov, 1) (1 - closed - open).
        const float e = LeafShare(px, cov, samples.touched());
        if constexpr (kRad) {
          Store4(&px.closed, Load4(&px.closed) + e * f.rgb1);
        } else {
          px.closed += e;
        }
        return;
      } else if (const int seen = std::popcount(mask & ~px.closed_mask); mask != 0 && seen != 0) {
        cov *= static_cast<float>(std::popcount(mask & ~px.closed_mask & ~px.open_mask)) /
               static_cast<float>(seen);
      }
    }
    if (mask != 0 && px.closed_mask != 0) {
      // Samples that the closed layers in front cover are hidden: a masked fragment adds the
      // share of its samples they leave free, and its radiance only there. Scaled at Close()
      // by the layer's shares together, a far layer kept the mean radiance of all its
      // fragments in the samples left free: a light beside the ceiling, seen past a block's
      // face that hid the ceiling, came out at their mean (a floor receiver at res 12: 0.024
      // of irradiance where res 48 gives 0.056 in one pixel; bug:
      // hidden_samples_keep_the_layers_mean_radiance; docs/design.md, "Coverage masks").
      const uint64_t free = mask & ~px.closed_mask;
      cov *= static_cast<float>(std::popcount(free)) / static_cast<float>(std::popcount(mask));
      mask = free;
    }
    if (mask != 0) px.open_masked += cov;
    px.open_mask |= mask;
    if constexpr (kRad) {
      Store4(&px.open, Load4(&px.open) + cov * f.rgb1);
    } else {
      px.open += cov;
    }
  }

  // Emit() into the 2 x 2 block of pixels p0, p0 + 1, p0 + res, p0 + res + 1 with coverages
  // cov[0..3]: the same, with the four plane ranges computed in four lanes.
  template <bool kClamp, bool kRad>
  [[gnu::always_inline]] void Emit2x2(uint32_t p0, const float* cov, const Frag& f) {
    if constexpr (!kClamp) {
      const uint32_t p[4] = {p0, p0 + 1, p0 + res_, p0 + res_ + 1};
      for (int i = 0; i < 4; ++i) Emit<kClamp, kRad>(p[i], cov[i], f);
    } else {
      V4 lo = Splat4(f.lo), hi = Splat4(f.hi);
      if (f.flat) {
        // PlaneRange() four lanes wide (the same expressions, so the same values).
        const V4 ux = Load2x2(dir_x_ + p0), uy = Load2x2(dir_y_ + p0), uz = Load2x2(dir_z_ + p0);
        const V4 mu = f.normal.x * ux + f.normal.y * uy + f.normal.z * uz;
        const V4i ok = mu < -kMinPlaneCos;
        const V4 inv = -1.0f / mu;
        const V4 t = -f.plane * inv;
        const V4 half = (f.thick + t * Load2x2(half_width_ + p0)) * inv;
        constexpr float kInf = std::numeric_limits<float>::infinity();
        const V4 flo = Splat4(polygons_ ? f.lo : -kInf), fhi = Splat4(polygons_ ? f.hi : kInf);
        lo = ok ? Min4(Max4(t - half, flo), fhi) : lo;
        hi = ok ? Min4(Max4(t + half, flo), fhi) : hi;
      }
      // Unrolled by hand: the loop stayed a loop, with the lanes going through memory.
      auto one = [&](uint32_t q, float c, float l, float h) [[gnu::always_inline]] {
        PixelState& px = px_[q];
        px.depth = std::min(px.depth, f.depth);
        if (px.closed < 1.0f) Layer<kRad>(px, c, f, l, h);
        if (px.closed >= 1.0f) shut_[q] = px.depth;  // as Emit() keeps it
      };
      one(p0, cov[0], lo[0], hi[0]);
      one(p0 + 1, cov[1], lo[1], hi[1]);
      one(p0 + res_, cov[2], lo[2], hi[2]);
      one(p0 + res_ + 1, cov[3], lo[3], hi[3]);
    }
  }
  // {a[0], a[1], a[res], a[res + 1]}.
  V4 Load2x2(const float* a) const {
    V2 top, bottom;
    std::memcpy(&top, a, sizeof top);
    std::memcpy(&bottom, a + res_, sizeof bottom);
    return __builtin_shufflevector(top, bottom, 0, 1, 2, 3);
  }

  MicroBuffer& mb_;
  const RasterOptions& o_;
  const int res_;
  const bool radiance_, clamp_;
  PixelState* px_;
  // MicroBuffer::shut_: with clamp, px_[p].depth where px_[p].closed >= 1, else NaN (Emit()).
  float* shut_;
  const PixelDir* dirs_;
  const float* omega_;
  const float* inv_omega_;
  const float *dir_x_, *dir_y_, *dir_z_, *half_width_;
  const float max_width_;  // the largest pixel's angular width
  const bool avx2_;        // run the AVX2 builds (UseAvx2())
  glm::vec3 origin_, t_, b_, n_;
  uint8_t sheet_ = 0;                      // the receiver's sheet tag (ShadeReceiver::sheet)
  float crease_tol_ = 0.0f;                // see CreaseShift()
  glm::vec3 world_x_, world_y_, world_z_;  // the world axes x, y, z in the receiver's frame
  // ToLocal()'s matrix by columns, {t_[k], b_[k], n_[k], 0} for k = x, y, z (ToLocal4()).
  V4 col_x_, col_y_, col_z_;
  uint32_t count_ = 0;          // prepared splats in mb_.splats_
  uint32_t poly_count_ = 0;     // polygons in mb_.polygons_
  uint32_t cluster_count_ = 0;  // mb_.splats_[0, cluster_count_) are clusters'
  // Layers closed by a fragment behind them so far (Layer()): until there are a few, no pixel
  // is closed and Draw() does not look for hidden clusters.
  uint32_t closes_ = 0;
  const bool polygons_;    // Footprint::kPolygons
  const bool free_layer_;  // !polygons_: the first layer sums freely
  const bool bound_;       // RasterOptions::bound_by_footprints, with polygons and clamp
  const FarBuffer* far_ = nullptr;
};

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_RASTERIZER_H_
