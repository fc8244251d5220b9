// The micro-buffer rasterizer: turns the elements that Gather() returns for one receiver
// (clusters and surfels, see surfel.h) into ambient occlusion, irradiance and glossy radiance.
// It depends on nothing but the gathered elements, so it is tested and benchmarked without a
// database (docs/design.md, "Raster"; Christensen 2008; Ritschel et al. 2009).
//
// The micro-buffer is a cube of six res x res faces around the receiver, in the receiver's local
// frame (+z = the receiver's normal), with a coverage, a depth and a radiance per pixel.
//  - Far elements are splatted as cones ("disks on the sphere") of the element's exact solid
//    angle, centred on the direction of the element's centre (a cluster: its bounds' centre):
//      surfel:  solid angle = A max(0, n.w) / d^2,       radiance = the surfel's radiance;
//      cluster: solid angle = max(0, A(w)) / d^2,        radiance = P(w) / A(w) per colour,
//    where w is the unit direction from the element towards the receiver. A splat smaller than
//    half a pixel is spread bilinearly over the four nearest pixel centres (weight * its solid
//    angle / the pixel's); a larger one gets a per-pixel coverage that ramps from 1 to 0 over
//    one pixel width across the cone's edge, rescaled so that the sum over pixels of coverage *
//    pixel solid angle is the element's solid angle exactly. Either way the footprint spreads
//    but the total does not drift.
//  - A surfel closer than `near_field_factor * radius` is drawn as an exact disk: every pixel
//    that the disk's bounding cone touches is sampled with near_field_samples^2 rays, each
//    intersected with the disk; coverage is the solid-angle-weighted fraction of rays that hit.
//  - With `clamp` (the default), elements are composited front to back by distance, in depth
//    layers per pixel: an element whose depth range in the pixel overlaps the open layer's joins
//    it, and a layer's coverage adds up freely (the splats of one surface tile it; their round
//    footprints overlap and leave gaps that cancel only if they add up); an element wholly
//    behind closes the layer. A flat element's depth range in a pixel is where the pixel's ray
//    meets its plane (a surfel's disk, a flat cluster's mean plane); a curved cluster's is
//    [d - extent, d + extent]. A joining element extends the layer's range only if it faces
//    the same way as the layer's first one (one surface, curving), so that a chain of elements
//    of different surfaces cannot merge them into one layer. The first layer counts in full only
//    while nothing lies behind it in that pixel; once a fragment behind it arrives it is clamped at
//    1, and each later layer only fills what the nearer ones left below 1 (the depth test).
//    Surfaces closer in depth than a pixel's footprint spans (about depth * slope * pixel angle)
//    merge into one layer and add up.
//  - With footprint = kPolygons (see Footprint), elements are polygons that tile instead:
//    clusters and groups of co-planar leaf surfels become the part of their plane inside their
//    octree cell (or, not flat, their cell's faces that face the receiver), rasterized with
//    exact area coverage; every layer is clamped at 1, the first one too, since footprints that
//    tile need no free sum to fill their gaps.
//  - Pixel solid angles are exact for their place on the face (closed form for a rectangle on a
//    cube face), and each pixel's cosine weight is the exact projected solid angle of the part
//    of the pixel above the horizon (Lambert's polygon formula), so the weights sum to pi.
//
// Outputs (ShadeResult):
//  - occlusion = sum_p coverage_p * W_p / pi, W_p = integral of cos over pixel p above the
//    horizon: cosine-weighted, a fully covered hemisphere gives 1.
//  - irradiance = sum_p L_p * W_p, NOT divided by pi: E = integral of L cos dw, so a uniform
//    hemisphere of radiance L gives pi * L (multiply by albedo / pi for outgoing radiance).
//  - glossy = sum_p L_p D(w_p) dw_p / sum_p D(w_p) dw_p over the hemisphere above the receiver,
//    D the lobe around the receiver's reflection direction: the lobe-weighted mean radiance, so
//    a uniform environment of radiance L gives L.
//  - coverage = covered fraction of the hemisphere's solid angle (not cosine-weighted).
//
// Cluster model: the order-2 SH of the projected area holds exactly the total area A (band 0),
// the area-weighted normal sum N (band 1) and the second moment M = sum A_i n_i n_i^T (bands 0
// and 2). A(w) = (sum A_i |n_i.w| + N.w) / 2, and the even part is estimated from M, exactly for
// a flat cluster and for an isotropic one. A two-sided surfel enters the SH as the pair
// (n_i, -n_i), so it adds A_i |n_i.w| to the front (and to the back) area. Plain SH evaluation
// (kShEval) overestimates a facing flat cluster by 6.25% and leaks 9.4% of its area at grazing
// angles.
#ifndef PBGI_RASTER_H_
#define PBGI_RASTER_H_

#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "glm/vec3.hpp"
#include "pbgi/surfel.h"

namespace pbgi {

// Which sides of a one-sided surfel occlude and emit (RenderMan's `hitsides`). A surfel's front
// is the side its normal points to. With kBack or kBoth, a surfel seen from behind shows the
// same radiance as its front. A two-sided surfel (Surfel::two_sided) shows both sides in every
// mode, its back with Surfel::back_radiance. A cluster with kBoth shows the larger of its two
// sides' projected areas, not their sum, so that a closed object's silhouette counts once (see
// "Cluster model" above).
enum class HitSides : uint8_t { kFront, kBack, kBoth };

// The glossy lobe D around the reflection direction r, with a = angle(w, r):
//   kPhong: D = cos(a)^phong_exponent for cos(a) > 0;
//   kGgx:   D = alpha^2 / (pi ((alpha^2 - 1) cos^2(a) + 1)^2), alpha = ggx_roughness.
enum class GlossyLobe : uint8_t { kNone, kPhong, kGgx };

// What an element covers on the micro-buffer.
//   kSplats: round splats (cones of the element's solid angle; exact disks near the receiver)
//     whose overlaps and gaps cancel in a freely summed first layer (see the top).
//   kPolygons: footprints that tile (raster/polygon.h, docs/design.md "Raster"): a flat
//     cluster or a leaf's group of co-planar surfels is its plane inside its octree cell, a
//     curved cluster its cell's receiver-facing faces, each with exact area coverage and an
//     opacity of its projected area over the footprint's; every layer clamps at 1. Continuous
//     in the receiver's position and free of the splats' blocks and streaks; costs more.
enum class Footprint : uint8_t { kSplats, kPolygons };

// How a cluster's projected area A(w) is reconstructed from its SH (see the header comment).
enum class ClusterModel : uint8_t { kMoments, kShEval };

struct RasterOptions {
  int resolution = 12;  // pixels per face edge, 4..64
  // Offset of the receiver along its normal before rasterizing (world units: scale it with the
  // scene). Keeps a receiver's own surface out of its buffer.
  float bias = 0.0f;
  // Composite front to back in depth layers (nearer surfaces hide farther ones; see the top of
  // this file), and clamp occlusion to [0, 1] and radiance to >= 0 (SH may ring negative).
  // Without it, coverage adds up unsorted (faster, over-occludes where surfaces overlap) and
  // results are not clamped.
  bool clamp = true;
  // Elements whose centre lies farther than this from the receiver are ignored.
  float max_distance = std::numeric_limits<float>::infinity();
  HitSides hitsides = HitSides::kFront;
  // A surfel whose centre is closer than near_field_factor * radius is drawn as an exact disk
  // with near_field_samples^2 rays per pixel (0 disables the exact path).
  float near_field_factor = 4.0f;
  int near_field_samples = 4;  // 1..16
  // Accumulate radiance (irradiance, glossy); false computes occlusion only, faster.
  bool compute_radiance = true;
  ClusterModel cluster_model = ClusterModel::kMoments;
  Footprint footprint = Footprint::kSplats;
  // With polygon footprints and clamp: a pixel's coverage is at most the share of its 8 x 8
  // samples that its fragments' footprints touch (PixelState::touched), so that translucent
  // footprints behind each other cannot fill the part of the pixel that none of them reaches.
  // Every other fragment (a splat, a near disk) touches all samples.
  bool bound_by_footprints = true;
  GlossyLobe lobe = GlossyLobe::kNone;
  float phong_exponent = 32.0f;  // >= 0
  float ggx_roughness = 0.2f;    // (0, 1]
};

// OK, or InvalidArgument naming the field and its value.
absl::Status ValidateRasterOptions(const RasterOptions& options);

struct ShadeReceiver {
  glm::vec3 position{0.0f};
  glm::vec3 normal{0.0f, 0.0f, 1.0f};      // need not be unit length, must not be zero
  glm::vec3 reflection{0.0f, 0.0f, 1.0f};  // centre of the glossy lobe (world space)
  // The sheet tag of a receiver on a thin sheet (Surfel::sheet), 0: unknown. A two-sided
  // element with another non-zero tag is never taken for the receiver's own sheet.
  uint8_t sheet = 0;
};

struct ShadeResult {
  float occlusion = 0.0f;
  glm::vec3 irradiance{0.0f};
  glm::vec3 glossy{0.0f};
  float coverage = 0.0f;
  // What was drawn: far clusters, far surfels, exact near-field disks, elements culled (behind
  // the tangent plane, beyond max_distance, wrong side, zero size).
  uint32_t clusters_drawn = 0;
  uint32_t surfels_drawn = 0;
  uint32_t near_disks_drawn = 0;
  uint32_t culled = 0;
};

namespace internal {
// A convex polygon in the micro-buffer's frame (raster/polygon.h): a plane cut by a box has at
// most 6 vertices, and each of the 5 clips of rasterizing (the horizon, a face's 4 sides) adds
// at most one.
inline constexpr int kMaxPolygonVertices = 12;
struct Polygon {
  int n = 0;
  glm::vec3 v[kMaxPolygonVertices];
};
// One pixel's share of a polygon: the fraction of the pixel's area that it covers.
struct PixelCoverage {
  uint32_t pixel;
  float coverage;
};
// PreparedSplat::flags. Porous: a cluster of pieces facing every way with gaps between them
// (leaves, grass), or a two-sided surfel (a piece of a leaf); its layer's coverage is
// composited as an independent one's. Back: with hitsides both, a one-sided element seen from
// behind; it counts only where no element seen from the front came before it in the pixel
// (behind its near side, the inside of a closed object must not fill the gaps that side's
// footprints leave). See Rasterizer::Layer().
inline constexpr uint8_t kSplatPorous = 1;
inline constexpr uint8_t kSplatBack = 2;
// One element ready to splat (local frame), kept in the MicroBuffer to avoid allocation.
// 64 bytes, the radiance first and 16-byte aligned so that Emit() adds it four lanes wide.
struct alignas(16) PreparedSplat {
  float rgb1[4];     // {1, radiance}: lane 0 carries the coverage (see PixelState)
  glm::vec3 dir;     // far: unit direction; near disk: centre
  float omega;       // far: solid angle; near disk: radius
  glm::vec3 normal;  // near disk: its normal; far: unit mean normal facing the receiver, or 0
  float depth;       // distance from the receiver to the element's centre
  float extent;      // half the element's size along any direction (depth overlap test)
  // Far and flat: the element lies within `thick` of its plane {x : normal.x = plane} (x
  // relative to the receiver; plane < 0), which gives its depth along each pixel's ray.
  float plane, thick;
  uint8_t near;  // 1 for an exact disk, 2 for polygons (poly_first, poly_count)
  uint8_t flat;  // far: 1 when plane and thick are set (a surfel, or a nearly flat cluster)
  uint8_t poly_count;
  uint8_t flags;        // kSplatPorous, kSplatBack (polygon footprints only; 0 otherwise)
  uint32_t source;      // the cluster's index in Gathered::clusters (clusters only)
  uint32_t poly_first;  // polygons: the first in the MicroBuffer's polygon list
  float alpha;          // polygons: the coverage of the element inside them
};
// A pixel's state: layers of fragments that overlap in depth (one surface) add up freely in
// `open`; when a fragment lies wholly behind the open layer, the layer closes into `closed`.
// Each coverage is followed by its coverage-weighted radiance, four floats that the hot loops
// update as one vector.
struct alignas(16) PixelState {
  float closed;  // coverage of the closed layers
  float closed_rgb[3];
  float open;  // coverage of the open layer
  float open_rgb[3];
  float far;          // far end of the open layer's depth range
  float depth;        // nearest fragment's depth
  float normal[3];    // the open layer's first fragment's normal (0: none)
  float porous;       // 1 when the open layer's first fragment is porous (kSplatPorous), 2
                      // when it is also flat (a two-sided sheet's piece)
  float front;        // 1 once a fragment not flagged kSplatBack reached the pixel
  float open_masked;  // the share of `open` that came with coverage masks (open_mask)
  // Coverage masks (polygon footprints with clamp): which of the pixel's 8 x 8 sample points
  // the open layer's polygon fragments cover, and those of the closed layers (see
  // Rasterizer::Layer()).
  uint64_t open_mask;
  uint64_t closed_mask;
  // The samples that the fragments' footprints touched (a polygon, opaque or translucent: the
  // samples whose cells it overlaps; every other fragment: all), and
  // whether a translucent polygon contributed: then the pixel's coverage is at most their
  // share (RasterOptions::bound_by_footprints, Rasterizer::CapByTouched()).
  uint64_t touched;
  uint32_t translucent;
};
static_assert(sizeof(PixelState) == 96);  // translucent fills what was padding
struct PixelDir {
  float x, y, z;
  float inv_width;   // 1 / (angular width of the pixel)
  float half_width;  // half the angular width of the pixel
};
class Rasterizer;
}  // namespace internal

// The per-receiver scratch of the rasterizer: the cube's pixel tables (built once per
// resolution) and per-pixel state. After the first receiver at a given resolution and element
// count, Shade() allocates nothing. A MicroBuffer belongs to one thread; use one per thread.
// Pixels are numbered face * res * res + row * res + col; faces are +x, -x, +y, -y, +z, -z of
// the receiver's local frame (+z = normal); a face's columns run along the first of its other
// two axes, its rows along the second.
class MicroBuffer {
 public:
  MicroBuffer() = default;
  MicroBuffer(const MicroBuffer&) = delete;
  MicroBuffer& operator=(const MicroBuffer&) = delete;
  MicroBuffer(MicroBuffer&&) = default;
  MicroBuffer& operator=(MicroBuffer&&) = default;

  // Builds the pixel tables for `resolution` (a no-op when it is already the current one).
  absl::Status Prepare(int resolution);

  int resolution() const { return res_; }
  int pixel_count() const { return 6 * res_ * res_; }

  // Pixel tables (local frame), valid after Prepare().
  glm::vec3 PixelDirection(int p) const;  // unit direction of the pixel's centre
  double PixelSolidAngle(int p) const { return omega_[p]; }
  // Solid angle of the part of the pixel above the horizon (z >= 0).
  double PixelSolidAngleAbove(int p) const { return omega_above_[p]; }
  // Integral of cos(theta) over the part of the pixel above the horizon.
  double PixelCosineWeight(int p) const { return cos_weight_[p]; }

  // What the last Shade() left in the pixel.
  float PixelCoverage(int p) const;                           // may exceed 1 (see top)
  float PixelDepth(int p) const { return pixels_[p].depth; }  // +inf where nothing drew
  glm::vec3 PixelRadiance(int p) const;                       // coverage-weighted

 private:
  friend class internal::Rasterizer;

  int res_ = 0;
  std::vector<internal::PixelDir> dirs_;
  std::vector<double> omega_, omega_above_, cos_weight_;
  std::vector<float> omega_f_, inv_omega_f_;  // omega_ and 1 / omega_ for the hot loops
  // dirs_ by component, for four pixels at a time (the bilinear splat's 2 x 2 block)
  std::vector<float> dir_x_, dir_y_, dir_z_, half_width_;
  float max_width_ = 0.0f;            // largest pixel's angular width, sqrt(solid angle)
  std::vector<uint32_t> hemisphere_;  // pixels with omega_above_ > 0
  std::vector<float> hemi_weight_;    // cos_weight_ of hemisphere_ pixels
  std::vector<float> hemi_omega_;     // omega_above_ of hemisphere_ pixels
  // The cosine weight's slope across each hemisphere pixel's coverage samples, per sample
  // column and row (Rasterizer::SampleWeight(); 0 for a pixel the horizon cuts).
  std::vector<float> hemi_slope_x_, hemi_slope_y_;
  std::vector<internal::PixelState> pixels_;
  // Per pixel, its depth once it is closed (coverage >= 1), else NaN: what
  // Rasterizer::RectClosed() asks of a pixel, in one float (kept by Emit() with clamp).
  std::vector<float> shut_;
  std::vector<internal::PreparedSplat> splats_;
  std::vector<uint64_t> order_, order_tmp_;            // (depth key << 32) | splat index
  std::vector<std::pair<uint32_t, float>> fragments_;  // one splat's pixels and coverages
  std::vector<internal::Polygon> polygons_;            // the splats' footprints
  std::vector<float> accumulation_;                    // scratch of RasterizePolygon
  std::vector<internal::PixelCoverage> coverage_;      // one polygon's pixels
  std::vector<uint32_t> groups_;                       // scratch of the surfel groups
  std::vector<uint64_t> group_keys_;                   // their grid cells
  std::vector<uint32_t> leaf_runs_;  // where each run of one leaf's surfels starts (SheetCell)
  bool free_layer_ = true;           // the last Shade()'s first layer summed freely (kSplats)
  // The last Shade()'s prepared elements: splats_[0, prepared_), the clusters' first
  // (internal::Rasterizer::FootprintsOver, a diagnostic).
  uint32_t prepared_ = 0, prepared_clusters_ = 0;
};

// The far field of a group of receivers that share it (pbgi/query.h, FarCut; docs/shade.md,
// "Session 13"), rasterized once from the group's centre in the frame of the group's normal:
// per pixel of the cube, the coverage, the coverage-weighted radiance and the nearest depth that
// the far clusters left. ShadeWithFar() composites it behind each member's near field. Like a
// MicroBuffer, it belongs to one thread.
class FarBuffer {
 public:
  int resolution() const { return res_; }
  const glm::vec3& normal() const { return normal_; }  // unit
  float PixelCoverage(int p) const { return state_[4 * size_t(p)]; }
  glm::vec3 PixelRadiance(int p) const {  // coverage-weighted
    const float* s = &state_[4 * size_t(p)];
    return glm::vec3(s[1], s[2], s[3]);
  }
  float PixelDepth(int p) const { return depth_[size_t(p)]; }  // +inf where nothing drew

 private:
  friend class internal::Rasterizer;
  int res_ = 0;
  glm::vec3 normal_{0.0f, 0.0f, 1.0f};
  std::vector<float> state_;  // per pixel: coverage, then radiance
  std::vector<float> depth_;
  std::vector<uint64_t> mask_;  // per pixel: the samples that the far field's layers covered
};

// Rasterizes a group's far clusters (FarCut::far) from `centre` (the group's centre and normal)
// into `out`, with the options that its members will be shaded with. `scratch` is used and left
// holding the far field alone.
absl::Status ShadeFar(const Gathered& far, const ShadeReceiver& centre,
                      const RasterOptions& options, MicroBuffer* scratch, FarBuffer* out);

// Shades one member of a group: its near field (Reader::GatherNear) is rasterized as Shade()
// does, at the receiver's position but in the frame of the far buffer's normal (the receiver's
// own normal is not used), then the far buffer is composited behind it, pixel by pixel, as a
// layer behind the near ones: it fills what they leave below 1, and where both came with
// coverage masks (polygon footprints) only with the share of its samples that they leave
// uncovered, so that a surface that crosses from the near field into the far one tiles the
// pixel as it does in one buffer (without clamp, both add). The far buffer was drawn from the
// group's centre: a far element's direction is off by at most the angle the group's radius
// subtends at its distance (1 / distance_factor radians). REQUIRES: far comes from ShadeFar
// with the same options.
absl::Status ShadeWithFar(const Gathered& near, const ShadeReceiver& receiver, const FarBuffer& far,
                          const RasterOptions& options, MicroBuffer* scratch, ShadeResult* out);

// Shades one receiver from the gathered elements. `scratch` is reused across receivers.
// Returns InvalidArgument for invalid options or a zero / non-finite receiver normal; never
// produces NaN or Inf from finite inputs.
absl::Status Shade(const Gathered& gathered, const ShadeReceiver& receiver,
                   const RasterOptions& options, MicroBuffer* scratch, ShadeResult* out);

}  // namespace pbgi

#endif  // PBGI_RASTER_H_
