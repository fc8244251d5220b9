// Database, Reader and the gather traversal (docs/design.md, "Query"; the cut is documented in
// include/pbgi/query.h).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "pbgi/query.h"
#include "pbgi/status.h"
#include "query/database_internal.h"
#include "query/front_cache.h"
#include "query/page_cache.h"
#include "store/page_io.h"
#include "tree/cut.h"
#include "tree/decoded_page.h"
#include "tree/format.h"
#include "tree/morton.h"
#include "tree/verify.h"

namespace pbgi {

using internal::AbsMax;
using internal::BelowCurvedBoxCut;
using internal::BelowPlainCut;
using internal::CachedPage;
using internal::ContrastValue;
using internal::DecodedPage;
using internal::NodeBeyondMargin;
using internal::NodeContrastScale;
using internal::NodeCutCosine;
using internal::NodeHot;
using internal::NodeMarginOf;
using internal::NodeNearFieldSphere;
using internal::NodeRef;
using internal::NodeSolidAngleFrom;
using internal::NodeWhollyBehindFar;
using internal::PageCache;
using internal::PageKey;
using internal::SurfelWhollyBehindUnit;

void QueryStats::Add(const QueryStats& o) {
  queries += o.queries;
  nodes_visited += o.nodes_visited;
  nodes_culled += o.nodes_culled;
  clusters += o.clusters;
  surfels += o.surfels;
  points_tested += o.points_tested;
  for (int i = 0; i < kStatLevels; ++i) {
    nodes[i] += o.nodes[i];
    pages_touched[i] += o.pages_touched[i];
    reader_hits[i] += o.reader_hits[i];
    reader_misses[i] += o.reader_misses[i];
    shared_hits[i] += o.shared_hits[i];
    shared_misses[i] += o.shared_misses[i];
  }
  pages_read += o.pages_read;
  bytes_read += o.bytes_read;
}

namespace {
uint64_t Sum(const std::array<uint64_t, kStatLevels>& a) {
  uint64_t s = 0;
  for (uint64_t v : a) s += v;
  return s;
}
}  // namespace

uint64_t QueryStats::TotalPagesTouched() const { return Sum(pages_touched); }
uint64_t QueryStats::TotalReaderHits() const { return Sum(reader_hits); }
uint64_t QueryStats::TotalSharedHits() const { return Sum(shared_hits); }
uint64_t QueryStats::TotalSharedMisses() const { return Sum(shared_misses); }

// ---------------------------------------------------------------------------------------------
// Database

// Counters of all Readers, exact whenever asked: each live Reader publishes its own on a cache
// line of its own (single writer, relaxed stores, nothing shared on the gather path), and a
// Reader adds its final counters to `retired` when it goes.
namespace {
// The counters of CacheStats in one fixed order: the one list that a Reader's published copy
// and Database::TotalStats share. f(counter) for each, `s` a CacheStats or a const one.
constexpr int kCacheCounters = 10;
template <typename Stats, typename F>
void ForEachCounter(Stats& s, F&& f) {
  for (auto* level : {&s.reader, &s.shared}) {
    f(level->hits), f(level->misses), f(level->pages_read), f(level->bytes_read);
    f(level->evictions);
  }
}
}  // namespace

struct Database::Totals {
  std::mutex mu;
  CacheStats retired ABSL_GUARDED_BY(mu);
  std::vector<const std::atomic<uint64_t>*> live ABSL_GUARDED_BY(mu);
};

Database::Database(std::unique_ptr<internal::PageSource> source, const DatabaseOptions& options)
    : source_(std::move(source)), options_(options), totals_(new Totals) {
  const StoreMeta& m = source_->meta();
  // A decoded page costs about its stored size (see CachedPage::Charge).
  const uint64_t page_charge = std::max<uint64_t>(m.page_size, 4096);
  page_charge_ = page_charge;
  const int bits = options_.cache_shard_bits >= 0
                       ? options_.cache_shard_bits
                       : PageCache::DefaultShardBits(options_.cache_bytes, page_charge);
  cache_ = std::make_unique<PageCache>(options_.cache_bytes, bits);
  // Keys are (page << 1) | section (PageKey): 2 max(pages) + 2 bits, 16 KiB per million pages.
  loaded_words_ = (2 * std::max(m.node_pages, m.point_pages) + 2 + 63) / 64;
  loaded_ = std::make_unique<std::atomic<uint64_t>[]>(loaded_words_);
}

Database::~Database() = default;

absl::StatusOr<std::unique_ptr<Database>> Database::Open(const std::string& path,
                                                         const DatabaseOptions& options) {
  absl::StatusOr<std::unique_ptr<internal::PageSource>> source =
      internal::OpenStorePageSource(path, options.verify_checksums, options.copy_pages);
  if (!source.ok()) return source.status();
  return internal::OpenDatabase(std::move(*source), options);
}

absl::StatusOr<std::unique_ptr<Database>> internal::OpenDatabase(
    std::unique_ptr<internal::PageSource> source, const DatabaseOptions& options) {
  if (source == nullptr) return absl::InvalidArgumentError("OpenDatabase: no source");
  const StoreMeta& m = source->meta();
  if (m.page_size <= sizeof(PageHeader) + internal::NodeRecordSize(m.channels)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s: page size %d is too small", source->name(), m.page_size));
  }
  // A record crafted with a valid checksum (no points, bounds that are NaN or inverted, ...)
  // must not be shaded as zeros.
  PBGI_RETURN_IF_ERROR(internal::CheckDatabaseMeta(m, source->name()));
  if (m.point_count > 0 && internal::RefSlot(m.root) >= 0xffffu) {
    return absl::DataLossError(absl::StrFormat("%s: meta: bad root reference", source->name()));
  }
  return std::unique_ptr<Database>(new Database(std::move(source), options));
}

const StoreMeta& Database::meta() const { return source_->meta(); }
const std::string& Database::path() const { return source_->name(); }
uint64_t Database::FileBytes() const { return source_->FileBytes(); }
uint64_t Database::CacheUsageBytes() const { return cache_->usage(); }
uint64_t Database::SharedCacheCalls() const { return cache_->counters().calls(); }
uint64_t Database::DistinctPagesRead() const {
  return distinct_loaded_.load(std::memory_order_relaxed);
}
void Database::NoteLoaded(uint64_t key) {
  // A key past the meta's page counts (a source that does not fill them in) is not counted.
  if (key / 64 >= loaded_words_) return;
  const uint64_t bit = uint64_t{1} << (key % 64);
  if ((loaded_[key / 64].fetch_or(bit, std::memory_order_relaxed) & bit) == 0) {
    distinct_loaded_.fetch_add(1, std::memory_order_relaxed);
  }
}
absl::StatusOr<uint64_t> Database::MapResidentBytes() const { return source_->MapResidentBytes(); }
void Database::DropCache() { cache_->Prune(); }

void Database::AddTotals(const CacheStats& s) {
  std::lock_guard<std::mutex> l(totals_->mu);
  totals_->retired.Add(s);
}

CacheStats Database::TotalStats() const {
  CacheStats s;
  {
    std::lock_guard<std::mutex> l(totals_->mu);
    s = totals_->retired;
    for (const std::atomic<uint64_t>* c : totals_->live) {
      int i = 0;
      ForEachCounter(s, [&](uint64_t& v) { v += c[i++].load(std::memory_order_relaxed); });
    }
  }
  s.shared.evictions = cache_->counters().evictions;
  return s;
}

// ---------------------------------------------------------------------------------------------
// Reader

namespace {
// DFS stack: a node pushes at most 8 children and pops one, so depth * 7 + 1 entries suffice.
constexpr int kStackSize = kMaxTreeDepth * 8;
}  // namespace

// Whether NodeSolidAngleFrom(node.centre, node.sh_area, p) < max_sa holds whatever the
// direction, from the node's bound of its projected area (ProjectedAreaBound): E <= bound, so
// E / d2 <= bound / d2 < max_sa * (1 - 1e-4), far enough below max_sa that the float division
// of the exact test rounds below it too. False says nothing (the exact test decides): the cut
// is the same, bit for bit, only cheaper for clusters that are small from every side.
inline bool ClearlyBelowCut(const NodeHot& node, const glm::vec3& p, float max_sa) {
  const glm::vec3 v = p - node.centre;
  const float d2 = glm::dot(v, v);
  return node.area_bound < (max_sa * d2) * (1.0f - 1e-4f);
}

// BelowCut() with a lobe (Cut::lobe): solid_angle * NodeLobeWeight() < max_sa, with the weight
// (a pow and three square roots) computed only for the nodes that the lobe's bounds do not
// decide: the weight lies in [min_weight, max_weight] (LobeCut), and float rounding is
// monotone, so each shortcut gives the exact test's answer, bit for bit.
inline bool BelowLobeCut(const NodeHot& node, const glm::vec3& p, float max_sa,
                         const internal::LobeCut& lobe) {
  if (ClearlyBelowCut(node, p, max_sa / lobe.max_weight)) return true;
  const float sa = NodeSolidAngleFrom(node.centre, node.sh_area.data(), p);
  if (sa * lobe.max_weight < max_sa) return true;
  if (sa * lobe.min_weight >= max_sa) return false;
  return sa * internal::NodeLobeWeight(lobe, node.near_centre, node.near_radius2, p) < max_sa;
}

namespace {

// An upper bound of a node's projected area (ProjectedAreaToward) over the directions within
// `angle` radians of the unit direction w: its value at w plus the largest gradient of its SH
// on the sphere times the angle, per band |c_l| sqrt(l (l + 1) (2l + 1) / (4 pi)) (Cauchy-Schwarz
// with the sum over m of |grad Y_lm|^2, the derivative of the addition theorem), and never
// above the node's bound over all directions.
float FarAreaBound(const NodeHot& node, const glm::vec3& w, float angle) {
  const float* c = node.sh_area.data();
  const float band1 = std::sqrt(c[1] * c[1] + c[2] * c[2] + c[3] * c[3]);
  const float band2 =
      std::sqrt(c[4] * c[4] + c[5] * c[5] + c[6] * c[6] + c[7] * c[7] + c[8] * c[8]);
  const float lipschitz = 0.6910f * band1 + 1.5451f * band2;
  float sum_abs = 0.0f;
  for (int i = 0; i < 9; ++i) sum_abs += std::fabs(c[i]);
  // 1e-5 of the coefficients' magnitude covers the float evaluation at w, as ProjectedAreaBound
  // covers its own.
  const float at_w = std::max(0.0f, internal::ProjectedAreaToward(c, w)) + 1e-5f * sum_abs;
  return std::min(node.area_bound, (at_w + lipschitz * angle) * 1.0001f);
}

// The box whose cube the builder made the Morton keys in: build statistic "key_bounds" (six
// hexadecimal floats). A database built from a source that declared bounds larger than its
// points has it; the points' box stood for it before, and then every cluster's and leaf's cell
// was off the octree's grid, so footprints did not snap to the cells' sides (bug:
// cells_off_the_key_cube). Every build writes it; missing or unusable (a store written
// without it): the points' box, which is the key box of every build that measured its bounds.
// Format 3's position grid (StoreMeta::grid_origin, grid_step) holds the same cube in float,
// while the builder's cells (MortonCube) are in double.
Bounds KeyBounds(const StoreMeta& meta) {
  const auto it = meta.stats.find("key_bounds");
  if (it == meta.stats.end()) return meta.bounds;
  std::vector<std::string> parts = absl::StrSplit(it->second, ' ', absl::SkipEmpty());
  if (parts.size() != 6) return meta.bounds;
  float v[6];
  for (int k = 0; k < 6; ++k) {
    char* end = nullptr;
    v[k] = std::strtof(parts[k].c_str(), &end);
    if (end == parts[k].c_str() || *end != '\0' || !std::isfinite(v[k])) return meta.bounds;
  }
  Bounds b;
  b.lo = glm::vec3(v[0], v[1], v[2]);
  b.hi = glm::vec3(v[3], v[4], v[5]);
  // The points may stick out of a declared key box by rounding (KeyBoundsTolerance): the
  // builder kept such a box, and so must the reader. Refusing it for a point 6e-6 past a
  // scene's bounds put the forest's cells half a cell off the octree's (bug:
  // key_box_refused_for_rounding).
  const Bounds tolerated = internal::KeyBoundsTolerance(b);
  for (int k = 0; k < 3; ++k) {
    if (!(tolerated.lo[k] <= meta.bounds.lo[k] && meta.bounds.hi[k] <= tolerated.hi[k])) {
      return meta.bounds;
    }
  }
  return b;
}

}  // namespace

struct Reader::Impl {
  struct StackEntry {
    NodeRef ref;
    uint32_t depth;
  };

  Impl(Database* d, std::unique_ptr<internal::PageReader> r, uint64_t budget, uint32_t max_entries)
      : db(d),
        meta(d->meta()),
        source(std::move(r)),
        front(budget, max_entries),
        points_per_page(internal::PointsPerPage(meta.page_size, meta.channels)),
        cube(KeyBounds(meta)) {}

  // A page through both cache levels, counted at `level`.
  inline absl::Status Fetch(Section section, uint64_t page_no, int level, const DecodedPage** out) {
    const uint64_t key = PageKey(section, page_no);
    ++q.pages_touched[level];
    Memo& m = memo[MemoSlot(key)];
    if (m.key == key) {
      ++q.reader_hits[level];
      *out = m.page;
      return absl::OkStatus();
    }
    if (const DecodedPage* p = front.Find(key)) {
      ++q.reader_hits[level];
      m = {key, p};
      *out = p;
      return absl::OkStatus();
    }
    ++q.reader_misses[level];
    return FetchSlow(section, page_no, key, level, out);
  }

  absl::Status FetchSlow(Section section, uint64_t page_no, uint64_t key, int level,
                         const DecodedPage** out);
  absl::Status Gather(const Receiver& receiver, const Cut& cut, Gathered* out);
  // Gather's traversal from the root, with (kLobe) or without a lobe.
  template <bool kLobe>
  [[gnu::noinline]] absl::Status Traverse(const glm::vec3& p, const glm::vec3& n, const Cut& cut,
                                          const internal::LobeCut& lobe,
                                          absl::Span<const FarCut::Root> roots, Gathered* out);
  // Checks a receiver and a cut as Gather does ("Gather: ..." errors, `what` names the call).
  absl::Status CheckQuery(absl::string_view what, const glm::vec3& p, const glm::vec3& normal,
                          const Cut& cut);
  absl::Status GatherFar(const ReceiverGroup& group, const Cut& cut, float distance_factor,
                         FarCut* out);
  absl::Status GatherNear(const glm::vec3& p, const Cut& cut, const FarCut& far, Gathered* out);
  // The node of stack entry e, through the page cache (cur_page, page: the traversal's current
  // page, updated), with the corruption checks of a traversal.
  absl::Status VisitNode(const StackEntry& e, uint64_t* cur_page, const DecodedPage** page,
                         uint64_t* front_evictions, const NodeHot** node, uint32_t* slot);
  // Appends node `slot` of `page` to out->clusters.
  void EmitCluster(const DecodedPage& page, uint32_t slot, const NodeHot& node, Gathered* out);
  absl::Status EmitLeafPoints(uint64_t first, uint64_t count, const Bounds& cell,
                              const glm::vec3& p, const glm::vec3& n, float max_distance,
                              bool check_distance, Gathered* out);

  // A few pages this gather already found in the front cache, so that going back and forth
  // between a parent's page and its children's pages skips the hash lookup and the LRU relink.
  // Pointers in it are valid while the front cache evicts nothing (FetchSlow clears it when it
  // does); Gather clears it first so that every page it uses is still made most recent in the
  // front cache once per gather.
  struct Memo {
    uint64_t key = ~uint64_t{0};
    const DecodedPage* page = nullptr;
  };
  static constexpr int kMemoBits = 4;
  static int MemoSlot(uint64_t key) {
    return static_cast<int>((key * 0x9e3779b97f4a7c15ull) >> (64 - kMemoBits));
  }
  void ClearMemo() {
    for (Memo& m : memo) m = Memo{};
  }

  Database* db;
  const StoreMeta& meta;
  std::unique_ptr<internal::PageReader> source;
  internal::FrontCache front;
  const uint64_t points_per_page;
  const internal::MortonCube cube;  // the root cell: a node's depth and corner give its cell
  // This Reader's CacheStats as Database::TotalStats() reads them (ForEachCounter order), on
  // cache lines of their own: the other thread never shares a line that a gather writes.
  alignas(64) std::atomic<uint64_t> published[kCacheCounters] = {};
  void Publish(const CacheStats& s) {
    int i = 0;
    ForEachCounter(s, [&](uint64_t v) { published[i++].store(v, std::memory_order_relaxed); });
  }
  alignas(64) QueryStats q;  // counters of the current query
  Memo memo[1 << kMemoBits];
  StackEntry stack[kStackSize];
};

absl::Status Reader::Impl::FetchSlow(Section section, uint64_t page_no, uint64_t key, int level,
                                     const DecodedPage** out) {
  uint64_t bytes = 0;
  auto load = [&]() -> absl::StatusOr<PageCache::Loaded> {
    absl::StatusOr<PageView> view = source->Read(section, page_no);
    if (!view.ok()) return view.status();
    bytes = meta.page_size;  // pages are stored at their fixed size
    auto page = std::make_unique<CachedPage>();
    PBGI_RETURN_IF_ERROR(
        internal::DecodePage(*view, section, page_no, meta, db->path(), &page->page));
    PageCache::Loaded loaded;
    loaded.charge = page->Charge();
    loaded.value = std::move(page);
    return loaded;
  };
  PageCache::Outcome outcome;
  absl::StatusOr<PageCache::Handle> handle = db->cache_->Lookup(key, load, &outcome);
  // The share may have shrunk since another Reader was made: the next Insert honours it.
  front.set_budget_bytes(db->ReaderCacheBytes());
  if (!handle.ok()) return handle.status();
  if (outcome == PageCache::Outcome::kLoaded) {
    db->NoteLoaded(key);
    ++q.shared_misses[level];
    ++q.pages_read;
    q.bytes_read += bytes;
  } else {
    ++q.shared_hits[level];
  }
  const uint64_t evictions_before = front.evictions();
  *out = front.Insert(key, std::move(*handle));
  if (front.evictions() != evictions_before) ClearMemo();
  memo[MemoSlot(key)] = {key, *out};
  return absl::OkStatus();
}

absl::Status Reader::Impl::EmitLeafPoints(uint64_t first, uint64_t count, const Bounds& cell,
                                          const glm::vec3& p, const glm::vec3& n,
                                          float max_distance, bool check_distance, Gathered* out) {
  uint64_t i = first;
  const uint64_t end = first + count;
  const uint32_t leaf = static_cast<uint32_t>(out->leaf_cells.size());
  out->leaf_cells.push_back(cell);
  while (i < end) {
    const uint64_t page_no = i / points_per_page;
    const uint64_t slot0 = i % points_per_page;
    const uint64_t run = std::min(end - i, points_per_page - slot0);
    const DecodedPage* page;
    if (absl::Status s = Fetch(Section::kPoints, page_no, kPointLevel, &page); !s.ok()) return s;
    const Surfel* pts = page->points.get() + slot0;
    for (uint64_t k = 0; k < run; ++k) {
      const Surfel& s = pts[k];
      if (SurfelWhollyBehindUnit(s, p, n)) continue;
      if (check_distance && internal::SurfelBeyondPoint(s, p, max_distance)) continue;
      out->surfels.push_back(s);
      out->surfel_ids.push_back(i + k);
      out->surfel_leaf.push_back(leaf);
    }
    q.points_tested += run;
    i += run;
  }
  return absl::OkStatus();
}

absl::Status Reader::Impl::CheckQuery(absl::string_view what, const glm::vec3& p,
                                      const glm::vec3& normal, const Cut& cut) {
  const float nlen = glm::length(normal);
  if (!(nlen > 0.0f) || !std::isfinite(nlen) || !std::isfinite(p.x) || !std::isfinite(p.y) ||
      !std::isfinite(p.z)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: receiver at (%g, %g, %g) with normal (%g, %g, %g): the position must be finite "
        "and the normal finite and not zero",
        what, p.x, p.y, p.z, normal.x, normal.y, normal.z));
  }
  if (!(cut.curved_scale > 0.0f && cut.curved_scale <= 1.0f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: Cut.curved_scale = %g: must be in (0, 1]", what, cut.curved_scale));
  }
  if (!(cut.radiance_contrast >= 0.0f && std::isfinite(cut.radiance_contrast))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: Cut.radiance_contrast = %g: must be finite and >= 0", what, cut.radiance_contrast));
  }
  if (!(cut.contrast_floor >= 0.0f && std::isfinite(cut.contrast_floor))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: Cut.contrast_floor = %g: must be finite and >= 0", what, cut.contrast_floor));
  }
  if (!(cut.curved_box_scale >= 0.0f && std::isfinite(cut.curved_box_scale))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: Cut.curved_box_scale = %g: must be finite and >= 0", what, cut.curved_box_scale));
  }
  if (absl::Status s = ValidateCutLobe(cut.lobe); !s.ok()) {
    return absl::InvalidArgumentError(absl::StrCat(what, ": ", s.message()));
  }
  return absl::OkStatus();
}

absl::Status Reader::Impl::Gather(const Receiver& receiver, const Cut& cut, Gathered* out) {
  out->Clear();
  out->position_tolerance = meta.grid_step;
  ++q.queries;
  ClearMemo();
  if (meta.point_count == 0 || meta.root == internal::kNoNodeRef) return absl::OkStatus();
  const glm::vec3 p = receiver.position;
  PBGI_RETURN_IF_ERROR(CheckQuery("Gather", p, receiver.normal, cut));
  // The lobe-aware cut's per-query constants (inactive without a lobe), and a traversal of its
  // own for each kind of cut, so that a gather without a lobe runs the loop it ran before.
  const internal::LobeCut lobe = internal::MakeLobeCut(cut.lobe);
  const FarCut::Root root[1] = {{meta.root, 0}};
  return lobe.active ? Traverse<true>(p, glm::normalize(receiver.normal), cut, lobe, root, out)
                     : Traverse<false>(p, glm::normalize(receiver.normal), cut, lobe, root, out);
}

inline absl::Status Reader::Impl::VisitNode(const StackEntry& e, uint64_t* cur_page,
                                            const DecodedPage** page, uint64_t* front_evictions,
                                            const NodeHot** node, uint32_t* slot_out) {
  const uint64_t page_no = internal::RefPage(e.ref);
  const uint32_t slot = internal::RefSlot(e.ref);
  const int level = static_cast<int>(e.depth);
  if (page_no != *cur_page || front.evictions() != *front_evictions) {
    if (absl::Status s = Fetch(Section::kNodes, page_no, level, page); !s.ok()) return s;
    *cur_page = page_no;
    *front_evictions = front.evictions();
  }
  if (slot >= (*page)->count) {
    return absl::DataLossError(
        absl::StrFormat("%s: nodes page %d is corrupt: a link points at slot %d of %d", db->path(),
                        page_no, slot, (*page)->count));
  }
  const NodeHot& n = (*page)->nodes[slot];
  if (n.depth != e.depth) {
    return absl::DataLossError(
        absl::StrFormat("%s: nodes page %d is corrupt: node %d has depth %d, its parent says %d",
                        db->path(), page_no, slot, static_cast<int>(n.depth), e.depth));
  }
  ++q.nodes_visited;
  ++q.nodes[level];
  *node = &n;
  *slot_out = slot;
  return absl::OkStatus();
}

inline void Reader::Impl::EmitCluster(const DecodedPage& page, uint32_t slot, const NodeHot& node,
                                      Gathered* out) {
  // Built in place (C++20 aggregate initialization): no zeroing of ~200 bytes first.
  const float area = page.areas[slot];
#if defined(__cpp_aggregate_paren_init)
  if (page.power) {
    out->clusters.emplace_back(Bounds{node.lo, node.hi}, area, node.sh_area, page.power[slot],
                               uint32_t{node.depth}, node.first_point, node.point_count,
                               cube.CellOf(node.lo, node.depth), ContrastValue(node.contrast));
  } else {
    out->clusters.emplace_back(Bounds{node.lo, node.hi}, area, node.sh_area, std::array<Sh9, 3>{},
                               uint32_t{node.depth}, node.first_point, node.point_count,
                               cube.CellOf(node.lo, node.depth));
  }
#else  // clang 14: no parenthesized aggregate initialization, the same Cluster by braces
  out->clusters.push_back(Cluster{Bounds{node.lo, node.hi}, area, node.sh_area,
                                  page.power ? page.power[slot] : std::array<Sh9, 3>{},
                                  uint32_t{node.depth}, node.first_point, node.point_count,
                                  cube.CellOf(node.lo, node.depth),
                                  page.power ? ContrastValue(node.contrast) : 0.0f});
#endif
  ++q.clusters;
}

template <bool kLobe>
absl::Status Reader::Impl::Traverse(const glm::vec3& p, const glm::vec3& n, const Cut& cut,
                                    const internal::LobeCut& lobe,
                                    absl::Span<const FarCut::Root> roots, Gathered* out) {
  const bool cosine_weighted = cut.cosine_weighted;
  const float max_d = cut.max_distance;
  const bool check_distance = std::isfinite(max_d);
  const float p_abs_max = AbsMax(p);
  // Whether a node's flatness matters (Cut::curved_scale, Cut::curved_box_scale).
  const bool need_flat = cut.curved_scale != 1.0f || cut.curved_box_scale > 0.0f;
  const float curved_max_sa = cut.max_solid_angle * cut.curved_scale;
  // Cut::radiance_contrast, in a radiance database (NodeContrastScale).
  const bool contrast_cut = cut.radiance_contrast > 0.0f && HasRadiance(meta.channels);
  // The corner of every node farthest along n (NodeWhollyBehindMargin's choice, as indices).
  const uint32_t far_word[3] = {n.x > 0 ? 4u : 0u, n.y > 0 ? 5u : 1u, n.z > 0 ? 6u : 2u};

  uint64_t cur_page = ~uint64_t{0};
  const DecodedPage* page = nullptr;
  uint64_t front_evictions = front.evictions();

  // One root at a time (a far field's near roots may outnumber the stack), each depth-first.
  for (const FarCut::Root& root : roots) {
    int sp = 0;
    stack[sp++] = {root.node, root.depth};
    while (sp > 0) {
      const StackEntry e = stack[--sp];
      const uint64_t page_no = internal::RefPage(e.ref);
      const uint32_t slot = internal::RefSlot(e.ref);
      const int level = static_cast<int>(e.depth);
      if (page_no != cur_page || front.evictions() != front_evictions) {
        if (absl::Status s = Fetch(Section::kNodes, page_no, level, &page); !s.ok()) return s;
        cur_page = page_no;
        front_evictions = front.evictions();
      }
      if (slot >= page->count) {
        return absl::DataLossError(
            absl::StrFormat("%s: nodes page %d is corrupt: a link points at slot %d of %d",
                            db->path(), page_no, slot, page->count));
      }
      const NodeHot& node = page->nodes[slot];
      if (node.depth != e.depth) {
        return absl::DataLossError(absl::StrFormat(
            "%s: nodes page %d is corrupt: node %d has depth %d, its parent says %d", db->path(),
            page_no, slot, static_cast<int>(node.depth), e.depth));
      }
      ++q.nodes_visited;
      ++q.nodes[level];

      // The tests of tree/cut.h with the node's terms precomputed in its decoded page.
      const float margin = NodeMarginOf(node.abs_max, p_abs_max);
      if (NodeWhollyBehindFar(internal::NodeCorner(node, far_word), node.reach, p, n, margin) ||
          (check_distance && NodeBeyondMargin(node.lo, node.hi, node.reach, p, max_d, margin))) {
        ++q.nodes_culled;
        continue;
      }
      // NodeMaxSolidAngle, with the flatness that the curved-box test needs too.
      const bool flat = !need_flat || node.flat != 0;
      float max_sa = flat ? cut.max_solid_angle : curved_max_sa;
      if (contrast_cut && node.contrast != 0) {
        const float scale = NodeContrastScale(cut, ContrastValue(node.contrast), page->power[slot],
                                              node.sh_area[0]);
        if (scale > 1.0f) max_sa /= scale;
      }
      const auto cosine = [&] { return NodeCutCosine(node.near_centre, node.near_radius2, p, n); };
      if (!NodeNearFieldSphere(node.near_centre, node.near_radius2, p) &&
          (kLobe ? BelowLobeCut(node, p, max_sa, lobe)
                 : ClearlyBelowCut(node, p, max_sa) ||
                       BelowPlainCut(NodeSolidAngleFrom(node.centre, node.sh_area.data(), p),
                                     max_sa, cosine_weighted, cosine)) &&
          BelowCurvedBoxCut(cut, flat, node.centre, node.lo, node.hi, p, [&] {
            if constexpr (kLobe) {
              return internal::NodeLobeWeight(lobe, node.near_centre, node.near_radius2, p);
            } else {
              return cosine_weighted ? cosine() : 1.0f;
            }
          })) {
        EmitCluster(*page, slot, node, out);
        continue;
      }
      if (node.child_count == 0) {
        // The point pages may evict this node page from the front cache (a small budget): the
        // eviction counter makes the next node look its page up again.
        const uint64_t first = node.first_point, count = node.point_count;
        if (absl::Status s = EmitLeafPoints(first, count, cube.CellOf(node.lo, node.depth), p, n,
                                            max_d, check_distance, out);
            !s.ok()) {
          return s;
        }
        continue;
      }
      if (e.depth + 1 >= static_cast<uint32_t>(kMaxTreeDepth) ||
          sp + static_cast<int>(node.child_count) > kStackSize) {
        return absl::DataLossError(
            absl::StrFormat("%s: nodes page %d is corrupt: node %d is deeper than %d levels",
                            db->path(), page_no, slot, kMaxTreeDepth));
      }
      // Push in reverse so that children are visited in stored (depth-first) order.
      for (uint32_t k = node.child_count; k-- > 0;) stack[sp++] = {node.children + k, e.depth + 1};
    }
  }
  q.surfels += out->surfels.size();
  return absl::OkStatus();
}

absl::Status Reader::Impl::GatherFar(const ReceiverGroup& group, const Cut& cut, float k,
                                     FarCut* out) {
  out->Clear();
  ++q.queries;
  ClearMemo();
  const glm::vec3 c = group.centre;
  const float r = group.radius;
  PBGI_RETURN_IF_ERROR(CheckQuery("GatherFar", c, group.normal, cut));
  if (!(r >= 0.0f) || !std::isfinite(r)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("GatherFar: ReceiverGroup.radius = %g: must be finite and >= 0", r));
  }
  const float th = group.thickness;
  if (!(th >= 0.0f && th <= r)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "GatherFar: ReceiverGroup.thickness = %g: must be in [0, radius = %g]", th, r));
  }
  if (!(k >= 1.0f) || !std::isfinite(k)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("GatherFar: distance_factor = %g: must be finite and >= 1", k));
  }
  if (cut.lobe.kind != CutLobeKind::kNone) {
    return absl::InvalidArgumentError(
        "GatherFar: a cut with a lobe (Cut::lobe) belongs to one receiver; far sharing needs a "
        "cut without one");
  }
  if (std::isfinite(cut.max_distance)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "GatherFar: Cut.max_distance = %g: far sharing needs an infinite one", cut.max_distance));
  }
  const glm::vec3 n = glm::normalize(group.normal);
  out->group = ReceiverGroup{c, r, n, th};
  out->distance_factor = k;
  if (meta.point_count == 0 || meta.root == internal::kNoNodeRef) return absl::OkStatus();
  // Every member's tangent plane (the group's normal) lies between the ones through `low` and
  // `high`: a node wholly behind the low plane is behind every member's, and only a node with
  // something in front of the high one is in front of every member's (margin 0: a member's own
  // test has a margin >= 0).
  const glm::vec3 low = c - th * n, high = c + th * n;
  const float low_abs_max = AbsMax(low);
  // Whether a node's flatness matters (Cut::curved_scale, Cut::curved_box_scale).
  const bool need_flat = cut.curved_scale != 1.0f || cut.curved_box_scale > 0.0f;
  const float curved_max_sa = cut.max_solid_angle * cut.curved_scale;
  const uint32_t far_word[3] = {n.x > 0 ? 4u : 0u, n.y > 0 ? 5u : 1u, n.z > 0 ? 6u : 2u};
  const float near_reach = r + k * r;  // a node wholly within this of c is near for everyone
  const bool contrast_cut = cut.radiance_contrast > 0.0f && HasRadiance(meta.channels);

  int sp = 0;
  stack[sp++] = {meta.root, 0};
  uint64_t cur_page = ~uint64_t{0};
  const DecodedPage* page = nullptr;
  uint64_t front_evictions = front.evictions();
  while (sp > 0) {
    const StackEntry e = stack[--sp];
    const NodeHot* np = nullptr;
    uint32_t slot = 0;
    PBGI_RETURN_IF_ERROR(VisitNode(e, &cur_page, &page, &front_evictions, &np, &slot));
    const NodeHot& node = *np;
    const float margin = NodeMarginOf(node.abs_max, low_abs_max);
    if (NodeWhollyBehindFar(internal::NodeCorner(node, far_word), node.reach, low, n, margin)) {
      ++q.nodes_culled;
      continue;
    }
    const float near_r = std::sqrt(node.near_radius2);
    const float to_near = glm::length(node.near_centre - c);
    const float gap = to_near - near_r - r;  // from the group's sphere to the near sphere
    const glm::vec3 corner = internal::NodeCorner(node, far_word);
    if (gap > 0.0f && gap >= k * r && !(glm::dot(n, corner - high) + node.reach < 0.0f)) {
      // Every member p lies within r of c, so |p - centre| >= |c - centre| - r, and the
      // direction from the node to p lies within asin(r / |c - centre|) of the one to c, over
      // which the projected area changes by at most the SH's Lipschitz bound times that angle
      // (FarAreaBound); the node's solid angle from p is at most that area over
      // (|c - centre| - r)^2. With the cosine weight, the directions from p into the near
      // sphere lie among those from c into the sphere grown by r, so their largest cosine bounds
      // p's. 1e-3 covers the rounding of the members' own tests (checked against them by brute
      // force in tests/shade/far_sharing_test.cc).
      // NodeMaxSolidAngle, with the flatness that the curved-box test below needs too.
      const bool flat = !need_flat || node.flat != 0;
      float max_sa = flat ? cut.max_solid_angle : curved_max_sa;
      if (contrast_cut && node.contrast != 0) {
        const float scale = NodeContrastScale(cut, ContrastValue(node.contrast), page->power[slot],
                                              node.sh_area[0]);
        if (scale > 1.0f) max_sa /= scale;
      }
      const glm::vec3 to_c = c - node.centre;
      const float dc = glm::length(to_c);
      const float dmin = dc - r;
      float weight = 1.0f;
      if (cut.cosine_weighted) {
        const float grown = near_r + r;
        weight = NodeCutCosine(node.near_centre, grown * grown, c, n);
      }
      // The curved-box test (Cut::curved_box_scale) from every member: the box's silhouette
      // from any direction is at most the length of its three faces' area vector.
      bool box_ok = true;
      if (cut.curved_box_scale > 0.0f && !flat) {
        const glm::vec3 e = node.hi - node.lo;
        const float box = glm::length(glm::vec3(e.y * e.z, e.x * e.z, e.x * e.y));
        box_ok = box * weight <
                 (cut.curved_box_scale * cut.max_solid_angle * (dmin * dmin)) * (1.0f - 1e-3f);
      }
      if (dmin > 0.0f && box_ok &&
          FarAreaBound(node, to_c / dc, std::asin(std::min(1.0f, r / dc))) * weight <
              (max_sa * (dmin * dmin)) * (1.0f - 1e-3f)) {
        EmitCluster(*page, slot, node, &out->far);
        continue;
      }
    }
    if (node.child_count == 0 || to_near + near_r <= near_reach) {
      out->near_roots.push_back({e.ref, e.depth});
      continue;
    }
    if (e.depth + 1 >= static_cast<uint32_t>(kMaxTreeDepth) ||
        sp + static_cast<int>(node.child_count) > kStackSize) {
      return absl::DataLossError(
          absl::StrFormat("%s: nodes page %d is corrupt: node %d is deeper than %d levels",
                          db->path(), internal::RefPage(e.ref), slot, kMaxTreeDepth));
    }
    for (uint32_t j = node.child_count; j-- > 0;) stack[sp++] = {node.children + j, e.depth + 1};
  }
  return absl::OkStatus();
}

absl::Status Reader::Impl::GatherNear(const glm::vec3& p, const Cut& cut, const FarCut& far,
                                      Gathered* out) {
  out->Clear();
  out->position_tolerance = meta.grid_step;
  ++q.queries;
  ClearMemo();
  const ReceiverGroup& g = far.group;
  PBGI_RETURN_IF_ERROR(CheckQuery("GatherNear", p, g.normal, cut));
  if (cut.lobe.kind != CutLobeKind::kNone || std::isfinite(cut.max_distance)) {
    return absl::InvalidArgumentError(
        "GatherNear: far sharing needs a cut without a lobe and with an infinite max_distance");
  }
  const float d = glm::length(p - g.centre);
  if (!(d <= g.radius * (1.0f + 1e-5f) + 1e-6f * (1.0f + AbsMax(g.centre)))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "GatherNear: receiver at (%g, %g, %g) lies %g from the group's centre, outside its "
        "radius %g",
        p.x, p.y, p.z, d, g.radius));
  }
  if (far.near_roots.empty()) return absl::OkStatus();
  const internal::LobeCut lobe;  // inactive
  return Traverse<false>(p, g.normal, cut, lobe, far.near_roots, out);
}

Reader::Reader(Database* db, std::unique_ptr<Impl> impl) : db_(db), impl_(std::move(impl)) {}

Reader::~Reader() {
  {
    std::lock_guard<std::mutex> l(db_->totals_->mu);
    auto& live = db_->totals_->live;
    live.erase(std::find(live.begin(), live.end(), impl_->published));
  }
  db_->AddTotals(stats_);
  impl_.reset();  // unpins before the Database can go
  db_->live_readers_.fetch_sub(1, std::memory_order_relaxed);
}

uint64_t Database::ReaderCacheBytes() const {
  if (options_.reader_cache_bytes != 0) return options_.reader_cache_bytes;
  const uint64_t live = std::max<uint32_t>(1, live_readers_.load(std::memory_order_relaxed));
  return options_.cache_bytes / (2 * live);
}

absl::StatusOr<std::unique_ptr<Reader>> Database::NewReader() {
  absl::StatusOr<std::unique_ptr<internal::PageReader>> r = source_->NewReader();
  if (!r.ok()) return r.status();
  live_readers_.fetch_add(1, std::memory_order_relaxed);
  // Slots for the largest share a Reader can get (alone: half the budget), at most 16384.
  const uint64_t most =
      options_.reader_cache_bytes != 0 ? options_.reader_cache_bytes : options_.cache_bytes / 2;
  const uint64_t entries = std::clamp<uint64_t>(most / (page_charge_ / 2) + 2, 2, 1u << 14);
  auto impl = std::make_unique<Reader::Impl>(this, std::move(*r), ReaderCacheBytes(),
                                             static_cast<uint32_t>(entries));
  {
    std::lock_guard<std::mutex> l(totals_->mu);
    totals_->live.push_back(impl->published);
  }
  return std::unique_ptr<Reader>(new Reader(this, std::move(impl)));
}

absl::Status Reader::Gather(const Receiver& receiver, const Cut& cut, Gathered* out,
                            QueryStats* stats) {
  return Account([&] { return impl_->Gather(receiver, cut, out); }, stats);
}

absl::Status Reader::GatherFar(const ReceiverGroup& group, const Cut& cut, float distance_factor,
                               FarCut* out, QueryStats* stats) {
  return Account([&] { return impl_->GatherFar(group, cut, distance_factor, out); }, stats);
}

absl::Status Reader::GatherNear(const glm::vec3& position, const Cut& cut, const FarCut& far,
                                Gathered* out, QueryStats* stats) {
  return Account([&] { return impl_->GatherNear(position, cut, far, out); }, stats);
}

absl::Status Reader::Account(absl::FunctionRef<absl::Status()> query, QueryStats* stats) {
  Impl& im = *impl_;
  const uint64_t evictions_before = im.front.evictions();
  im.q.Clear();
  absl::Status status = query();
  const QueryStats& q = im.q;
  const uint64_t rh = q.TotalReaderHits();
  const uint64_t rm = q.TotalPagesTouched() - rh;
  stats_.reader.hits += rh;
  stats_.reader.misses += rm;
  stats_.reader.pages_read += rm;  // every miss of this level is filled from the next one
  stats_.reader.evictions += im.front.evictions() - evictions_before;
  const uint64_t sh = q.TotalSharedHits();
  stats_.shared.hits += sh;
  stats_.shared.misses += q.TotalSharedMisses();
  stats_.shared.pages_read += q.pages_read;
  stats_.shared.bytes_read += q.bytes_read;
  if (stats != nullptr) stats->Add(q);
  im.Publish(stats_);
  return status;
}

absl::Status Reader::GatherBatch(absl::Span<const Receiver> receivers, const Cut& cut,
                                 absl::Span<const uint32_t> order,
                                 absl::FunctionRef<absl::Status(size_t, const Gathered&)> fn,
                                 QueryStats* stats) {
  Gathered g;
  const size_t n = order.empty() ? receivers.size() : order.size();
  for (size_t j = 0; j < n; ++j) {
    const size_t i = order.empty() ? j : order[j];
    if (i >= receivers.size()) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "GatherBatch: order[%d] = %d, but only %d receivers", j, i, receivers.size()));
    }
    if (absl::Status s = Gather(receivers[i], cut, &g, stats); !s.ok()) return s;
    if (absl::Status s = fn(i, g); !s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::StatusOr<float> Reader::MeanRadiance() {
  const StoreMeta& m = impl_->meta;
  if (!HasRadiance(m.channels) || m.point_count == 0 || m.root == internal::kNoNodeRef) {
    return 0.0f;
  }
  const DecodedPage* page;
  PBGI_RETURN_IF_ERROR(
      impl_->Fetch(Section::kNodes, internal::RefPage(m.root), /*level=*/0, &page));
  const uint32_t slot = internal::RefSlot(m.root);
  if (slot >= page->count || !page->power) {
    return absl::DataLossError(absl::StrFormat("%s: the root's node page %d is corrupt",
                                               db_->path(), internal::RefPage(m.root)));
  }
  return internal::NodeLuminance(page->power[slot], page->nodes[slot].sh_area[0]);
}

absl::Status Reader::ReadPoints(uint64_t first, uint64_t count, std::vector<Surfel>* out) {
  const StoreMeta& m = impl_->meta;
  if (count > m.point_count || first > m.point_count - count) {
    return absl::OutOfRangeError(absl::StrFormat("%s: points [%d, +%d) outside the %d points",
                                                 db_->path(), first, count, m.point_count));
  }
  impl_->q.Clear();
  impl_->ClearMemo();
  uint64_t i = first;
  const uint64_t end = first + count;
  const uint64_t ppp = impl_->points_per_page;
  while (i < end) {
    const DecodedPage* page;
    PBGI_RETURN_IF_ERROR(impl_->Fetch(Section::kPoints, i / ppp, kPointLevel, &page));
    const uint64_t slot0 = i % ppp;
    const uint64_t run = std::min(end - i, ppp - slot0);
    out->insert(out->end(), page->points.get() + slot0, page->points.get() + slot0 + run);
    i += run;
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// Z-order of receivers

// Receivers are sorted by the same Morton key as the points on disk (tree/morton.h), inside
// their own bounds, so consecutive receivers walk neighbouring subtrees.
std::vector<uint32_t> ZOrder(absl::Span<const Receiver> receivers) {
  return internal::MortonOrder(receivers.size(), [&](size_t i) { return receivers[i].position; });
}

}  // namespace pbgi
