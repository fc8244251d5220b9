// pbgi::BuildDatabase: the out-of-core octree builder (docs/design.md, "Build"; Kontkanen,
// Tabellion, Overbeck, EGSR 2011; Salmon & Warren 1997).
//
// The builder pulls surfels from any SurfelSource, computes 63-bit Morton keys inside the cubed,
// padded bounds, sorts them externally inside a memory budget (radix-sorted runs spilled to
// temporary files, then a k-way merge), and builds the octree in one streaming pass over the
// sorted points, packing nodes into coherent pages as they close. Points are written in Morton
// order, so a node's points are one contiguous range of global point indices.
//
// Thread safety: independent builds may run concurrently. With BuildOptions::threads > 1 one
// build pipelines its passes over internal threads (parse+keys | sort+spill, then merge |
// octree+packing | LMDB writes); the database is byte-identical for any thread count.
//
// Caveats:
// - The memory budget covers the sort buffers, the merge buffers, the node packer and LMDB's
//   write batch. Budgets below a few MiB are exceeded by fixed overheads (the run size has a
//   floor), which is only useful to force spilling in tests.
// - The measurement layouts kBreadthFirst and kShuffled hold every node record in memory (216 or
//   104 bytes per node, about one node per leaf_size/2 points): they exist only to measure what
//   coherence buys, not to build huge databases. kCoherent and kPostOrder stream.
// - Temporary run files are unlinked as soon as they are created and only kept open, so they
//   disappear on success, on error, on Ctrl-C and even on a crash. Except in a resumable build
//   (BuildOptions::resumable): the sort pass's runs are then named files in a directory of
//   tmp_dir (RunDirectory), kept with a manifest once the sort pass is done, so that a build
//   interrupted later (error, Ctrl-C, crash) can resume; removed after success, and replaced by
//   the next build of the same database that does not resume.
#ifndef PBGI_BUILD_H_
#define PBGI_BUILD_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "pbgi/store.h"
#include "pbgi/surfel.h"

namespace pbgi {

// How node records are ordered in node pages. All layouts keep sibling groups contiguous in one
// page (tree/format.h); only kCoherent is meant for production.
enum class Layout {
  kCoherent,      // treelets: a sibling group and as many levels below it as fit in a page
  kPostOrder,     // sibling groups in the order their parents close, packed sequentially
  kBreadthFirst,  // sibling groups level by level (holds all nodes in memory)
  kShuffled,      // sibling groups in a random order (holds all nodes in memory)
};

// "coherent", "postorder", "breadth-first", "shuffled".
const char* LayoutName(Layout layout);
absl::StatusOr<Layout> ParseLayout(const std::string& name);

// Reported by BuildOptions::progress, at most every few hundred thousand points.
struct BuildProgress {
  const char* pass = "";      // "bounds", "sort", "merge+octree"
  uint64_t points_done = 0;   // surfels processed in this pass so far
  int64_t points_total = -1;  // when known
};

// The page size of a build unless told otherwise: 32 KiB (32752 bytes). Since format version 3
// pages are stored compressed, so the page size no longer sets the bytes on disk (15.5 vs 14.6
// bytes per surfel at 64 KiB on the city); it sets the records per decoded page, and 32 KiB
// holds about as many as 64 KiB did in version 2. Measured (docs/format.md, "Format version 3"):
// at a 5% cache a gather reads as many pages as before and is no slower, where 64 KiB compact
// pages read 45% more and took 1.7x as long.
inline constexpr uint32_t kDefaultBuildPageSize = EfficientPageSize(8);

struct BuildOptions {
  uint64_t memory_bytes = uint64_t{1} << 30;
  uint32_t leaf_size = 16;
  uint32_t page_size = kDefaultBuildPageSize;
  Channels channels = Channels::kRadiance;
  Layout layout = Layout::kCoherent;
  // Directory for the sort's temporary run files; empty: the database's parent directory (or
  // its nearest ancestor that exists, when the build creates the parent too).
  std::string tmp_dir;
  // Count and drop invalid surfels (NaN/Inf, zero normal, radius <= 0) instead of failing.
  bool skip_invalid = false;
  std::function<void(const BuildProgress&)> progress;
  // Seed of the kShuffled layout.
  uint64_t shuffle_seed = 12345;
  // When set and it becomes true (e.g. from a SIGINT handler), the build stops at the next
  // batch with a Cancelled error, removing its temporary files and the incomplete store.
  const std::atomic<bool>* cancel = nullptr;
  // Key/value pairs stored as they are in the meta record's stats (where the surfels came from:
  // the scene's fingerprint, the input file, the tool, the date; `pbgi info` shows them).
  // REQUIRES: no key is one of the builder's own statistics.
  std::map<std::string, std::string> provenance;
  // What the source lacks and the octree pass estimates from each surfel's nearest neighbours
  // in Morton order (build/neighbour_estimate.h): radii (a PLY without `radius`: its surfels
  // have radius 0) and normals (zero normals), oriented away from the centre of the bounds or
  // towards `viewpoint`. The meta record's stats say what was estimated.
  struct Estimate {
    bool radius = false;
    bool normals = false;
    int neighbours = 16;  // k, 3..64
    bool towards_viewpoint = false;
    glm::vec3 viewpoint{0.0f};
  } estimate;
  // Resumable builds (docs/format.md, "Resume"). With a non-empty input_identity, a build that
  // spills keeps its sorted runs and a manifest (what made them: this identity and the options
  // that decide the records and keys) in tmp_dir; with `resume`, the build reads no surfel from
  // the source but merges the kept runs of the same database path, after checking the manifest
  // against this build (FailedPrecondition naming what differs; NotFound when nothing is kept).
  // Options that act after the sort (leaf size, page size, layout, memory, threads) may differ.
  struct Resumable {
    std::string input_identity;  // e.g. the input file's path, size, mtime and header hash
    bool resume = false;
    // Test hook: stop with a Cancelled error right after the manifest is written (an
    // interruption after the sort pass).
    bool stop_after_sort = false;
  } resumable;
  // 1: everything on the calling thread. >= 2: a background sort/spill thread (double-buffered
  // runs inside the same budget), a merge thread running ahead of the octree pass, and (in
  // BuildDatabase) a thread for the LMDB writes. 0: 1 (measured faster on 2 cores under load;
  // docs/format.md). Under a small budget the build uses one thread whatever this says.
  int threads = 0;
};

struct BuildStats {
  uint64_t points = 0;   // surfels stored
  uint64_t skipped = 0;  // invalid surfels dropped (skip_invalid)
  uint64_t nodes = 0;
  uint64_t leaves = 0;
  uint64_t node_pages = 0;
  uint64_t point_pages = 0;
  uint32_t max_depth = 0;
  uint64_t max_leaf_points = 0;  // > leaf_size only for coincident points at the maximum depth
  uint64_t bytes_on_disk = 0;    // data file size after Finish (0 for in-memory sinks)
  double node_page_fill = 0;     // mean fraction of node page capacity used
  double seconds_bounds = 0;     // pass 1 (0 when the source knew its bounds)
  double seconds_sort = 0;       // pass 2: keys, radix-sorted runs, spills
  double seconds_merge = 0;      // merge + octree + pages (the streaming pass)
  double seconds_finish = 0;     // final commit
  double seconds_total = 0;
  uint64_t runs_spilled = 0;    // 0 when the input fit the budget
  uint64_t merge_passes = 0;    // intermediate merge passes (too many runs for one merge)
  uint64_t run_capacity = 0;    // points per in-memory run
  uint64_t spill_bytes = 0;     // bytes written to temporary files
  uint64_t peak_rss_bytes = 0;  // VmHWM of the process after the build
  int threads = 1;              // BuildOptions::threads as resolved
  // Coherent layout: node records of the upper levels (written level by level), and how many
  // upper subtrees were written before the end to stay within the memory budget.
  uint64_t upper_records = 0;
  uint64_t early_upper_writes = 0;
  bool resumed = false;  // merged the runs a previous build kept (the sort times are its)
};

// The smallest memory_bytes within which a build's peak stays: its fixed buffers, the smallest
// write batch and the smallest sorted run. Smaller budgets are accepted (tests use them to force
// spilling) but exceeded; `pbgi build` refuses them.
uint64_t MinimumBuildMemory(const BuildOptions& options);

// Builds a database at `db_path` (a directory, created or replaced) from all surfels of `source`.
// Errors name the surfel (record number) or page concerned. An empty input is an error.
absl::StatusOr<BuildStats> BuildDatabase(SurfelSource& source, const std::string& db_path,
                                         const BuildOptions& options);

// The temporary directory a build of `db_path` uses: options.tmp_dir, or the database's parent
// directory (its nearest ancestor that exists).
std::string BuildTempDir(const std::string& db_path, const BuildOptions& options);
// Where a resumable build of `db_path` keeps its runs, inside BuildTempDir.
std::string BuildRunDirectory(const std::string& db_path, const BuildOptions& options);

// Checks the tree invariants of a finished store: every point in exactly one leaf, leaves in
// depth-first order cover the points in order, node bounds contain their children and points,
// a parent's SH (area, power) is the sum of its children's and a leaf's the sum of its points'
// within float tolerance, sibling groups fit their page, and counts and depth match the meta
// record. Reads the whole store once.
absl::Status VerifyTree(const PageStore& store);

}  // namespace pbgi

#endif  // PBGI_BUILD_H_
