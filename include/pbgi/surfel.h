// Surfels, bounds, channels, surfel streams and the gathered elements (clusters and surfels)
// that the query layer produces and the rasterizer consumes. Plain data, no dependencies on
// any module's library.
#ifndef PBGI_SURFEL_H_
#define PBGI_SURFEL_H_

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "glm/geometric.hpp"
#include "glm/vec3.hpp"

namespace pbgi {

// A surfel is a disk: position, unit normal, radius, and (with the radiance channel) the
// diffusely reflected radiance the renderer baked into it (direct light * albedo + emission).
// A two-sided surfel (a piece of a thin sheet: a leaf, a card, an open mesh part) occludes and
// shows a radiance on each side whatever RasterOptions::hitsides says (`radiance` on the side
// its normal points to, `back_radiance` on the other); a one-sided one only from the side its
// normal points to (or as hitsides selects, with `radiance` on both).
struct Surfel {
  glm::vec3 position{0.0f};
  glm::vec3 normal{0.0f, 0.0f, 1.0f};
  float radius = 0.0f;
  glm::vec3 radiance{0.0f};
  bool two_sided = false;
  // Which thin sheet a two-sided surfel lies on: 1-255, a hash of its connected piece of mesh
  // (two crossing leaves differ, the two faces of a fold agree), or 0, unknown. A receiver on
  // a sheet culls a two-sided element that looks like its own sheet folded over a convex edge
  // only when the tags do not tell them apart (docs/design.md, "Sheet tags"). One-sided
  // surfels carry 0. Stored since format version 4.
  uint8_t sheet = 0;
  // A two-sided surfel's radiance on its back, the side its normal points away from: a leaf lit
  // on one face is dark on the other (docs/design.md, "Two-sided surfels"). Unused on one-sided
  // surfels (0). A source that knows one radiance for both sides sets it to `radiance` (a PLY
  // without `back_r back_g back_b` reads so). Stored since format version 6.
  glm::vec3 back_radiance{0.0f};

  float Area() const { return 3.14159265358979f * radius * radius; }
};

// What a database stores besides geometry. kOcclusion stores no radiance anywhere.
enum class Channels : uint32_t {
  kOcclusion = 0,  // position, normal, radius: ambient occlusion only
  kRadiance = 1,   // adds RGB radiance per surfel and power SH per node
  // kRadiance, and a back radiance on two-sided surfels (Surfel::back_radiance). The builder
  // stores it in place of kRadiance when some two-sided surfel's back differs from its front
  // (as stored), so a scene without such surfels pays nothing for it. Format version 6.
  kRadianceBothSides = 2,
};

inline bool HasRadiance(Channels c) { return c != Channels::kOcclusion; }

// Axis-aligned box. An empty box has lo > hi.
struct Bounds {
  glm::vec3 lo{std::numeric_limits<float>::max()};
  glm::vec3 hi{std::numeric_limits<float>::lowest()};

  bool Empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }
  void Extend(const glm::vec3& p) {
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  void Extend(const Bounds& b) {
    lo = glm::min(lo, b.lo);
    hi = glm::max(hi, b.hi);
  }
  bool Contains(const glm::vec3& p) const {
    return p.x >= lo.x && p.y >= lo.y && p.z >= lo.z && p.x <= hi.x && p.y <= hi.y && p.z <= hi.z;
  }
  glm::vec3 Center() const { return 0.5f * (lo + hi); }
  glm::vec3 Extent() const { return hi - lo; }
};

// A stream of surfels from any source: a PLY file, a procedural scene, a renderer's own arrays.
// The builder pulls from it in batches and never holds the whole stream. Not thread-safe.
class SurfelSource {
 public:
  virtual ~SurfelSource() = default;
  // Fills up to out.size() surfels; returns how many were written, 0 at the end of the stream.
  virtual absl::StatusOr<size_t> Next(absl::Span<Surfel> out) = 0;
  // Restarts the stream from its first surfel (the builder may need a bounds pass first).
  virtual absl::Status Rewind() = 0;
  // Bounds of all positions when known in advance (e.g. from a file header), else empty.
  virtual Bounds KnownBounds() const { return Bounds{}; }
  // Number of surfels when known in advance, else -1.
  virtual int64_t KnownCount() const { return -1; }
  // Whether the surfels carry meaningful radiance.
  virtual bool HasRadiance() const { return true; }
};

// A SurfelSource over a caller-owned vector (tests, embedding renderers with points in memory).
class VectorSurfelSource final : public SurfelSource {
 public:
  explicit VectorSurfelSource(absl::Span<const Surfel> surfels, bool has_radiance = true)
      : surfels_(surfels), has_radiance_(has_radiance) {}
  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    size_t n = std::min(out.size(), surfels_.size() - pos_);
    for (size_t i = 0; i < n; ++i) out[i] = surfels_[pos_ + i];
    pos_ += n;
    return n;
  }
  absl::Status Rewind() override {
    pos_ = 0;
    return absl::OkStatus();
  }
  int64_t KnownCount() const override { return static_cast<int64_t>(surfels_.size()); }
  bool HasRadiance() const override { return has_radiance_; }

 private:
  absl::Span<const Surfel> surfels_;
  size_t pos_ = 0;
  bool has_radiance_;
};

// A shading point: position and normal (shared by the query layer, the scene tracer and shading).
struct Receiver {
  glm::vec3 position{0.0f};
  glm::vec3 normal{0.0f, 0.0f, 1.0f};
  uint8_t sheet = 0;  // the sheet tag of the surface it lies on (Surfel::sheet), 0: unknown
};

// Order-2 spherical harmonics: 9 real coefficients (see sh.h for the basis).
using Sh9 = std::array<float, 9>;

// An octree node standing in for all the surfels below it.
struct Cluster {
  Bounds bounds;
  float area = 0.0f;  // total surfel area
  // Projected area A(w) = sum A_i max(0, n_i.w) over one-sided surfels + sum A_i |n_i.w| over
  // two-sided ones (each the pair n_i, -n_i: band 1 cancels, bands 0 and 2 double, so band 0
  // holds the area of both sides; `area` counts each surfel once).
  Sh9 sh_area{};
  // Emitted power per colour P(w), the same sums weighted by L_i; zero when the database has no
  // radiance channel.
  std::array<Sh9, 3> sh_power{};
  uint32_t depth = 0;  // depth in the octree (root = 0)
  // The surfels below this node are the contiguous range [first_point, first_point+point_count)
  // of global point indices (rank in Morton order): the test harness checks cuts with it.
  uint64_t first_point = 0;
  uint64_t point_count = 0;
  // The node's octree cell (the cube of its Morton key prefix, which holds every surfel centre
  // below it): the cells of a cut tile space, so the rasterizer cuts footprints with them that
  // tile the view (docs/design.md, "Raster"). Empty when unknown (then the bounds serve).
  Bounds cell;
  // Radiance databases: how far the radiance of the node's parts strays from its own, the
  // largest |L_i - L| / L over its children (a leaf: its surfels), L the luminance of a mean
  // radiance, as stored (rounded up to a step of 1/16 octave of 1 + c); 0 otherwise
  // (Cut::radiance_contrast).
  float contrast = 0.0f;
};

// A cluster is flat when |sum A_i n_i| > kClusterFlatness * sum A_i (its surfels face within
// about 37 degrees of one way on average): the cut may refine the others further
// (Cut::curved_scale, tree/cut.h NodeIsFlat). The rasterizer draws a flat cluster by its
// plane, and also one whose normals, sides counted apart, lie within about 37 degrees of one
// axis e: e^T M e > kClusterFlatness^2 * sum A_i, M = sum A_i n_i n_i^T (a two-sided card,
// whose pairs cancel in the sum; raster/cluster_prep.cc).
inline constexpr float kClusterFlatness = 0.8f;

// What Gather() returns for one receiver: every surfel in front of the receiver is represented
// exactly once, either by itself (surfels) or by one ancestor node (clusters).
// The caller owns it and reuses it across queries: Clear() keeps the capacity.
struct Gathered {
  std::vector<Cluster> clusters;
  std::vector<Surfel> surfels;
  // Global point index (rank in Morton order) of each surfel, parallel to `surfels`.
  std::vector<uint64_t> surfel_ids;
  // The octree cell of the leaf each surfel came from: surfel_leaf[i] indexes leaf_cells.
  // Optional (empty: the rasterizer groups surfels on a grid of its own).
  std::vector<uint32_t> surfel_leaf;
  std::vector<Bounds> leaf_cells;
  // How far a surfel's stored position may lie from its surface along any direction: a
  // database's position grid step (Gather sets it), 0 for exact positions. The rasterizer takes
  // a receiver that lies behind a one-sided surface crossing its tangent plane by no more than
  // this (a receiver on a wall where the floor meets it) as in front of that surface
  // (docs/design.md, "Contacts").
  float position_tolerance = 0.0f;

  void Clear() {
    position_tolerance = 0.0f;
    clusters.clear();
    surfels.clear();
    surfel_ids.clear();
    surfel_leaf.clear();
    leaf_cells.clear();
  }
  size_t size() const { return clusters.size() + surfels.size(); }
};

}  // namespace pbgi

#endif  // PBGI_SURFEL_H_
