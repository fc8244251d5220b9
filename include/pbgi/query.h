// pbgi::Database and pbgi::Reader: gather the octree cut for a receiver from many threads at
// once, inside one memory cap, touching only the pages the answer needs (docs/design.md, "Query").
//
//   auto db = pbgi::Database::Open("scene.pbgi", {.cache_bytes = 512 << 20});
//   auto reader = (*db)->NewReader();          // one per thread
//   pbgi::Gathered g;                          // reused across queries: no allocation when warm
//   absl::Status s = (*reader)->Gather({p, n}, pbgi::Cut{}, &g, &stats);
//
// Thread safety: a Database is safe to share between threads; a Reader belongs to one thread
// at a time (make one per thread with Database::NewReader()).
//
// What a gather returns (the cut; the test harness in pbgi/testing.h checks it by brute force):
// every surfel that is in front of the receiver (not SurfelWhollyBehind) and within
// max_distance (not SurfelBeyond) is represented exactly once, either by itself (surfels,
// surfel_ids = its global point index) or by one cluster (an octree node whose point range
// covers it). Nothing wholly behind the receiver's tangent plane is emitted on its own, and no
// cluster lies wholly behind it or wholly beyond max_distance (with a node's disk reach, below).
//
// Traversal, for each node from the root, depth first (the tests named here are in tree/cut.h):
// 1. Skip it if its bounds, grown by its disk reach sqrt(area / pi), lie wholly behind the
//    tangent plane, or wholly farther than max_distance. Node bounds hold surfel centres; a
//    surfel's disk can reach its radius further, and any surfel radius below a node is at most
//    sqrt(area / pi) (pi r_i^2 <= sum_j pi r_j^2), so the test never drops a surfel in front.
// 2. Accept it as a cluster if the receiver is outside its near field (NodeNearField: the
//    bounding sphere of its bounds, grown by its disk reach; a box alone fails for a flat
//    patch, whose zero-thickness box a receiver just off the patch is "outside") and
//    ClusterSolidAngle() < max_solid_angle: the projected-area SH evaluated toward the
//    receiver from the bounds centre, clamped at 0, over the squared distance to the centre
//    (RenderMan's `maxsolidangle`, default 0.03). With Cut::cosine_weighted, also if that
//    solid angle times NodeCutCosine() of the near sphere is below max_solid_angle (BelowCut).
//    With Cut::lobe (the lobe-aware cut), instead if that solid angle times the lobe's weight
//    LobeWeight() at the largest cosine to the lobe's axis over the near sphere
//    (NodeLobeCosine) is below max_solid_angle: a node that reaches into the lobe's core gets
//    the core's weight, whatever its centre's direction.
// 3. Otherwise descend; at a leaf emit its surfels that are neither wholly behind nor beyond.
//
// Memory (one budget, DatabaseOptions::cache_bytes): decoded pages live only in the shared
// cache, which keeps its usage within cache_bytes by evicting unpinned pages. A Reader's own
// LRU (the first level, lock-free hits) holds pins into the shared cache, not copies, within
// reader_cache_bytes each; pinned pages cannot be evicted, so the cap holds while
// (number of Readers) * reader_cache_bytes <= cache_bytes. By default each Reader may pin
// cache_bytes / (2 * live Readers), re-read on every miss of its LRU, so the rule holds for
// any number of Readers and one or two Readers get a large lock-free level (a Reader keeps at
// least two pages, so a budget below 2 * Readers pages is exceeded by those pins).
//
// Caveats:
// - Each Reader holds one LMDB read transaction for its lifetime. The store is immutable after
//   its build, so a long-lived reader costs nothing but one slot in LMDB's reader table
//   (126 by default): do not make more Readers than threads.
// - A pinned page costs its decoded size (about the page size) and cannot be evicted. When a
//   Reader is made, the others shrink to their new share at their next miss, not at once.
//   A budget smaller than a few pages still answers correctly, but thrashes.
// - Besides the budget, each Reader owns fixed tables for its LRU (up to 16384 slots, about
//   1.2 MB) and a 256-entry traversal stack.
// - A corrupt page is reported as an error naming the store, the section and the page number;
//   the gather stops there and `out` holds a partial result that must not be used.
#ifndef PBGI_QUERY_H_
#define PBGI_QUERY_H_

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/functional/function_ref.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "glm/geometric.hpp"
#include "glm/vec3.hpp"
#include "pbgi/sh.h"
#include "pbgi/store.h"
#include "pbgi/surfel.h"

namespace pbgi {

class Database;
class Reader;
struct DatabaseOptions;

namespace internal {
class PageSource;
class PageCache;
// Opens a Database over any page source (query/database_internal.h).
absl::StatusOr<std::unique_ptr<Database>> OpenDatabase(std::unique_ptr<PageSource> source,
                                                       const DatabaseOptions& options);
}  // namespace internal

// Receiver (a shading point) is defined in pbgi/surfel.h; Gather normalizes its normal.

// The smallest cosine weight of the cosine-weighted cut: nodes at the horizon are at most
// 1 / kMinCutCosine times the plain cut's solid angle.
inline constexpr float kMinCutCosine = 0.05f;

// The glossy lobe that a lobe-aware cut refines for (Cut::lobe): D(angle a to `direction`)
// with the rasterizer's lobes (pbgi/raster.h GlossyLobe): Phong D = cos(a)^phong_exponent,
// GGX D = alpha^2 / (pi ((alpha^2 - 1) cos^2(a) + 1)^2), alpha = ggx_roughness.
enum class CutLobeKind : uint8_t { kNone, kPhong, kGgx };
struct CutLobe {
  CutLobeKind kind = CutLobeKind::kNone;  // kNone: no lobe, the plain or cosine-weighted cut
  // The lobe's axis, the receiver's reflection direction (world space; need not be unit length,
  // must not be zero). It belongs to one receiver: set it per Gather (GatherBatch uses one for
  // all).
  glm::vec3 direction{0.0f, 0.0f, 1.0f};
  float phong_exponent = 32.0f;  // kPhong: >= 0
  float ggx_roughness = 0.2f;    // kGgx: (0, 1]
  // The smallest weight (LobeWeight), > 0: a node outside the lobe's core is taken whole up to
  // max_solid_angle / min_weight. 1 (the default) never makes a node coarser than the plain cut
  // does: the lobe cut only refines where the lobe looks. Smaller values also coarsen outside
  // the core, which costs fewer clusters but measured worse where a lobe's tail still weighs
  // (cornell, GGX 0.3: 4.1% relative MAE at 1, 4.6% at 0.5, 5.3% at kMinCutCosine; Phong 32
  // unchanged; docs/eval.md Session 9).
  float min_weight = 1.0f;
};
// OK, or InvalidArgument naming the field and its value.
absl::Status ValidateCutLobe(const CutLobe& lobe);

// The cut criterion.
struct Cut {
  // Accept a node as a cluster when the solid angle it subtends is below this (steradians).
  // 0 gathers every surfel in front on its own.
  float max_solid_angle = 0.03f;
  // Ignore what is farther than this.
  float max_distance = std::numeric_limits<float>::infinity();
  // Weigh the solid angle by where the node lies above the horizon: also accept a node whose
  // solid angle times NodeCutCosine() (the largest cos(angle to the receiver's normal) over
  // its near sphere, at least kMinCutCosine) is below max_solid_angle. Occlusion and
  // irradiance integrate against that cosine, so a node near the horizon contributes little
  // and can be coarser for the same error; a node that reaches up toward the normal keeps the
  // plain criterion. Not for glossy light, whose lobe is not the cosine.
  bool cosine_weighted = false;
  // A node that is not flat (|sum A_i n_i| <= kClusterFlatness * sum A_i: an edge, a corner,
  // a crease, foliage) is taken whole only below curved_scale * max_solid_angle, in (0, 1].
  // A flat cluster is drawn exactly (its plane); a curved one only approximately (its box), so
  // refining just the curved nodes buys accuracy where it is lost (docs/eval.md).
  float curved_scale = 1.0f;
  // A node that is not flat is drawn as its box, its projected area spread evenly over the
  // box's silhouette; so it is taken whole only when that silhouette, too, subtends (times the
  // same cosine or lobe weight) below curved_box_scale * max_solid_angle. 0 turns the test off
  // (the default here; the tools use 1, with polygon footprints). >= 0. A wall's cell that also
  // holds a piece of a block beside it, seen nearly edge-on from a receiver on the wall, has a
  // small projected area but a box over much of the hemisphere (docs/design.md).
  float curved_box_scale = 0.0f;
  // The lobe-aware cut for glossy light (CutLobe): refine a node by how much of the receiver's
  // glossy lobe it covers. With a lobe, a node is accepted when its solid angle times
  // LobeWeight() over its near sphere is below max_solid_angle, instead of the plain (or the
  // cosine-weighted) test: finer than the plain cut in the lobe's core (and, with a
  // CutLobe::min_weight below 1, coarser outside it).
  CutLobe lobe{};
  // A cut that sees radiance (docs/design.md, "A cut that sees radiance"): a node whose parts'
  // radiance strays from its mean (Cluster::contrast, c) is taken whole only below
  // max_solid_angle / max(1, radiance_contrast * c * min(1, L / contrast_floor)), L the
  // luminance of its mean radiance: drawn whole, a node's footprint has its mean radiance
  // everywhere, and a light panel's node that holds some of the ceiling round it, or a street's
  // that crosses a shadow's edge, spreads the light over the dark part. 0 (the default here)
  // turns it off; it needs a radiance database (format version 5). contrast_floor, a radiance
  // >= 0, keeps the contrast of dark nodes from refining them (0: none); ShadeBatch sets it from
  // the database (ShadeOptions::radiance_contrast).
  float radiance_contrast = 0.0f;
  float contrast_floor = 0.0f;
};

// The lobe's weight in the lobe-aware cut, for a node whose directions from the receiver come
// at best within an angle a of the lobe's axis (x = cos a, the largest over the node's near
// sphere): w = pi * D(x) / integral of D over the axis's hemisphere, clamped to
// [lobe.min_weight, max(lobe.min_weight, w(1))] (1 without a lobe). pi times the normalized
// lobe: the cosine lobe D = cos gives w = cos, the plain cut's weight at the normal, so a
// cluster's share of the glossy integral is bounded as the plain cut bounds its share of
// irradiance, and the integral of w over the hemisphere is pi for every lobe, so that a sharp
// lobe's clusters concentrate in its core. Phong e: w = (e + 1) / 2 * x^e (16.5 at the axis for
// e = 32); GGX alpha: w = (1 / (1 + k x^2)^2) / (2 I), k = alpha^2 - 1,
// I = 1 / (2 alpha^2) + atanh(m) / (2 m), m = sqrt(-k) (9.45 at the axis for alpha = 0.3).
// Not clamped by the receiver's horizon: a lobe cut off by it is normalized over the whole
// hemisphere, which underestimates the weight of a grazing lobe's visible part by up to 2x.
float LobeWeight(const CutLobe& lobe, float cos_to_axis);

// The tests of the cut contract above, for one element and one receiver, exactly as Gather and
// the test harness evaluate them (the traversal's variants of these, with per-node terms
// precomputed, give the same bits: tree/cut.h).
// Whether a surfel's disk lies wholly behind the receiver's tangent plane: the highest point of
// the disk above the plane, n.(c - p) + r * sqrt(1 - (n.m)^2), is <= 0 (n the unit normal). A
// surfel lying in the plane (a flat neighbour) counts as behind.
bool SurfelWhollyBehind(const Surfel& s, const Receiver& r);
// Whether a surfel's disk lies wholly beyond max_distance: |c - p| - r > max_distance.
bool SurfelBeyond(const Surfel& s, const Receiver& r, float max_distance);
// The solid angle a cluster subtends from the receiver, as the cut criterion measures it: its
// projected-area SH evaluated toward the receiver from the bounds centre, clamped at 0, over
// the squared distance to the centre.
float ClusterSolidAngle(const Cluster& c, const Receiver& r);

// Far-field sharing (Wang et al., "Factorized Point Based Global Illumination", EGSR 2013;
// docs/shade.md, "Session 13"): a group of nearby receivers with one normal gathers its far
// field once (Reader::GatherFar) and each member gathers only its near field
// (Reader::GatherNear). Every member lies within `radius` of `centre` and is gathered with the
// group's `normal` (its own normal is not used: members are chosen with normals close to it).
struct ReceiverGroup {
  glm::vec3 centre{0.0f};
  float radius = 0.0f;                 // >= 0
  glm::vec3 normal{0.0f, 0.0f, 1.0f};  // need not be unit length, must not be zero
  // in [0, radius]: every member lies within this of the plane through centre with this normal
  // (0 for members on one plane).
  float thickness = 0.0f;
};

// What GatherFar gives a group, for its members' GatherNear. The octree is split three ways:
// - `far.clusters`: nodes that every member may take whole: each lies at least
//   distance_factor * radius from the group's sphere (beyond its near-field sphere for every
//   member), is not wholly behind any member's tangent plane, and passes the cut's test (Cut:
//   plain, or cosine-weighted with the largest cosine any member sees) from every point of the
//   sphere. Each is a valid element of every member's cut (pbgi/testing.h CheckValidCut), though
//   a member's own Gather may take one of its ancestors instead. Only clusters: no surfels.
// - `near_roots`: subtrees that each member gathers on its own (GatherNear), with the usual cut
//   from its position: the nodes that lie wholly within that distance of the sphere, and leaves
//   that are neither far nor wholly near.
// - the nodes wholly behind every member's tangent plane (culled).
// Every surfel in front of a member is represented exactly once by the far clusters and the
// member's near gather together, as by one Gather.
struct FarCut {
  ReceiverGroup group;  // the group it was gathered for (unit normal)
  float distance_factor = 0.0f;
  Gathered far;
  // Where each member's near gather starts: an octree node and its depth (opaque to callers).
  struct Root {
    uint64_t node;
    uint32_t depth;
  };
  std::vector<Root> near_roots;
  void Clear() {
    far.Clear();
    near_roots.clear();
  }
};

// Counters of one cache level.
struct LevelCounters {
  uint64_t hits = 0;
  uint64_t misses = 0;
  uint64_t pages_read = 0;  // pages loaded from the store into this level
  uint64_t bytes_read = 0;  // bytes of those pages as stored
  uint64_t evictions = 0;
  double HitRate() const {
    return hits + misses == 0 ? 1.0 : static_cast<double>(hits) / double(hits + misses);
  }
  void Add(const LevelCounters& o) {
    hits += o.hits, misses += o.misses, pages_read += o.pages_read, bytes_read += o.bytes_read,
        evictions += o.evictions;
  }
};

// Counters of both levels: the Reader's own LRU, then the shared cache (asked on a Reader miss).
struct CacheStats {
  LevelCounters reader;
  LevelCounters shared;
  void Add(const CacheStats& o) {
    reader.Add(o.reader);
    shared.Add(o.shared);
  }
};

// Index of the per-level arrays of QueryStats: node depth 0..kMaxTreeDepth-1, and
// kPointLevel for the point pages that leaves read.
inline constexpr int kMaxTreeDepth = 32;
inline constexpr int kPointLevel = kMaxTreeDepth;
inline constexpr int kStatLevels = kMaxTreeDepth + 1;

// What one or more gathers cost. Gather() adds to it (Clear() it to start over).
struct QueryStats {
  uint64_t queries = 0;
  uint64_t nodes_visited = 0;
  uint64_t nodes_culled = 0;  // skipped: behind the plane or beyond max_distance
  uint64_t clusters = 0;
  uint64_t surfels = 0;
  uint64_t points_tested = 0;
  // Per level (see kStatLevels): nodes visited; page lookups (a node or point in another page
  // than the previous one); how the Reader's LRU and then the shared cache answered them.
  std::array<uint64_t, kStatLevels> nodes{};
  std::array<uint64_t, kStatLevels> pages_touched{};
  std::array<uint64_t, kStatLevels> reader_hits{};
  std::array<uint64_t, kStatLevels> reader_misses{};
  std::array<uint64_t, kStatLevels> shared_hits{};
  std::array<uint64_t, kStatLevels> shared_misses{};
  uint64_t pages_read = 0;  // loaded from the store by this reader
  uint64_t bytes_read = 0;

  void Clear() { *this = QueryStats{}; }
  void Add(const QueryStats& o);
  uint64_t TotalPagesTouched() const;
  uint64_t TotalReaderHits() const;
  uint64_t TotalSharedHits() const;
  uint64_t TotalSharedMisses() const;
};

struct DatabaseOptions {
  uint64_t cache_bytes = uint64_t{256} << 20;  // both cache levels together
  // Each Reader's own LRU (pins into the shared cache). 0: cache_bytes / (2 * live Readers),
  // adjusted as Readers come and go.
  uint64_t reader_cache_bytes = 0;
  int cache_shard_bits = -1;  // -1: chosen from cache_bytes and page size
  bool verify_checksums = true;
  // Read pages from the file into the cache (pread) rather than through LMDB's memory map, so
  // that the map's pages never count in this process's resident memory: peak RSS stays within
  // cache_bytes plus a fixed overhead, whatever the database's size (StoreOptions::copy_pages).
  // false: zero-copy reads through the map, whose touched pages stay resident (file-backed,
  // reclaimable, but counted) until the Database is closed.
  bool copy_pages = true;
};

class Reader;

// An opened database. Safe to share between threads.
class Database {
 public:
  // Opens the database at `path` read-only; refuses what PageStore::Open refuses.
  static absl::StatusOr<std::unique_ptr<Database>> Open(const std::string& path,
                                                        const DatabaseOptions& options = {});
  ~Database();
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  const StoreMeta& meta() const;
  const std::string& path() const;
  uint64_t FileBytes() const;
  const DatabaseOptions& options() const { return options_; }

  // A new Reader for one thread. REQUIRES: the Database outlives it.
  absl::StatusOr<std::unique_ptr<Reader>> NewReader();

  // Counters of all Readers, live and destroyed, up to their last finished gather, and the
  // shared cache's evictions. (Each Reader publishes its counters on a cache line of its own;
  // this sums them under a lock, so calling it costs the gathers nothing.)
  CacheStats TotalStats() const;
  // Calls into the shared cache so far, by all Readers: lookups (found, waited for or loaded)
  // and unpins, each of which takes a shard's lock. A gather whose pages are all in its
  // Reader's own LRU makes none: its hits touch no state shared with other threads.
  uint64_t SharedCacheCalls() const;
  // Bytes of decoded pages in the shared cache now (pinned ones included).
  uint64_t CacheUsageBytes() const;
  // Pages loaded from the store at least once since the database was opened, each counted once
  // however often the cache evicted and reloaded it: the compulsory reads of the work so far,
  // which no cache size or receiver order lowers (CacheStats::shared.pages_read less this is
  // what a larger cache would have saved).
  uint64_t DistinctPagesRead() const;
  // Bytes of the store's memory map resident in this process now (PageStore::MapResidentBytes;
  // 0 for a source without a map). With copy_pages, only LMDB's B-tree pages.
  absl::StatusOr<uint64_t> MapResidentBytes() const;
  // Empties the shared cache of unpinned pages (to measure cold runs).
  void DropCache();

 private:
  friend class Reader;
  friend absl::StatusOr<std::unique_ptr<Database>> internal::OpenDatabase(
      std::unique_ptr<internal::PageSource> source, const DatabaseOptions& options);
  Database(std::unique_ptr<internal::PageSource> source, const DatabaseOptions& options);
  void AddTotals(const CacheStats& s);

  // What each Reader's own LRU may pin now (see DatabaseOptions::reader_cache_bytes).
  uint64_t ReaderCacheBytes() const;
  // Records that the page of cache key `key` (PageKey) was loaded from the store.
  void NoteLoaded(uint64_t key);

  std::unique_ptr<internal::PageSource> source_;
  DatabaseOptions options_;
  uint64_t page_charge_ = 0;
  std::atomic<uint32_t> live_readers_{0};
  std::unique_ptr<internal::PageCache> cache_;
  // One bit per page key ever loaded (DistinctPagesRead), and their count.
  std::unique_ptr<std::atomic<uint64_t>[]> loaded_;
  uint64_t loaded_words_ = 0;
  std::atomic<uint64_t> distinct_loaded_{0};
  struct Totals;
  std::unique_ptr<Totals> totals_;
};

// One thread's access to a Database. Not thread-safe; cheap to keep for a thread's lifetime.
class Reader {
 public:
  ~Reader();
  Reader(const Reader&) = delete;
  Reader& operator=(const Reader&) = delete;

  // Gathers the cut for one receiver into `out` (cleared first; its capacity is reused).
  // Adds its costs to `stats` when not null. InvalidArgument for a non-finite position or a
  // zero or non-finite normal, and for a lobe that ValidateCutLobe() refuses.
  absl::Status Gather(const Receiver& receiver, const Cut& cut, Gathered* out,
                      QueryStats* stats = nullptr);

  // Far-field sharing (FarCut): gathers the far field of `group` into `out` (cleared first),
  // with the cut `cut`; distance_factor (>= 1) sets how far a shared node lies from the group's
  // sphere, relative to its radius. InvalidArgument for a bad group or factor, for a cut with a
  // lobe (a lobe belongs to one receiver) or a finite max_distance (not supported).
  absl::Status GatherFar(const ReceiverGroup& group, const Cut& cut, float distance_factor,
                         FarCut* out, QueryStats* stats = nullptr);
  // The near field of one member of far.group at `position`, with the group's normal: what
  // Gather() gives minus the far clusters. REQUIRES: `far` came from GatherFar on this
  // Database, with the same `cut`. InvalidArgument when `position` lies outside the group's
  // sphere (the far set was not chosen for it).
  absl::Status GatherNear(const glm::vec3& position, const Cut& cut, const FarCut& far,
                          Gathered* out, QueryStats* stats = nullptr);

  // Gathers for receivers[order[0]], receivers[order[1]], ... (every receiver in index order
  // when `order` is empty), reusing one Gathered, and calls fn(index, gathered) after each.
  // Stops at the first error, from the gather or from fn.
  absl::Status GatherBatch(absl::Span<const Receiver> receivers, const Cut& cut,
                           absl::Span<const uint32_t> order,
                           absl::FunctionRef<absl::Status(size_t, const Gathered&)> fn,
                           QueryStats* stats = nullptr);

  // Reads the surfels with global point indices [first, first + count) into `out` (appended).
  absl::Status ReadPoints(uint64_t first, uint64_t count, std::vector<Surfel>* out);

  // The luminance (the mean of the channels) of the database's mean radiance: the root's band
  // 0 of power over band 0 of projected area, as the cut computes a node's
  // (Cut::contrast_floor). 0 for an occlusion database or an empty one.
  absl::StatusOr<float> MeanRadiance();

  // This Reader's counters since it was made.
  const CacheStats& stats() const { return stats_; }

 private:
  friend class Database;
  struct Impl;
  Reader(Database* db, std::unique_ptr<Impl> impl);
  // Runs one query and adds its counters to this Reader's and to `stats`.
  absl::Status Account(absl::FunctionRef<absl::Status()> query, QueryStats* stats);

  Database* db_;
  std::unique_ptr<Impl> impl_;
  // Written at the end of every gather: on cache lines of its own (which also aligns the
  // Reader), so that no other thread's data can share them, whatever the heap puts next to it.
  alignas(64) CacheStats stats_;
};

// The order in which to visit receivers for coherence: sorted by the Morton (Z-order) key of
// their positions, quantized to 21 bits per axis inside the receivers' bounds.
std::vector<uint32_t> ZOrder(absl::Span<const Receiver> receivers);

}  // namespace pbgi

#endif  // PBGI_QUERY_H_
