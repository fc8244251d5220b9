#include "build/builder.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "base/stopwatch.h"
#include "build/external_sort.h"
#include "build/input_range.h"
#include "build/neighbour_estimate.h"
#include "build/node_packer.h"
#include "build/octree_builder.h"
#include "build/run_manifest.h"
#include "build/sort_record.h"
#include "pbgi/status.h"
#include "tree/format.h"
#include "tree/morton.h"

namespace pbgi {

const char* LayoutName(Layout layout) {
  switch (layout) {
    case Layout::kCoherent:
      return "coherent";
    case Layout::kPostOrder:
      return "postorder";
    case Layout::kBreadthFirst:
      return "breadth-first";
    case Layout::kShuffled:
      return "shuffled";
  }
  return "unknown";
}

absl::StatusOr<Layout> ParseLayout(const std::string& name) {
  for (Layout l :
       {Layout::kCoherent, Layout::kPostOrder, Layout::kBreadthFirst, Layout::kShuffled}) {
    if (name == LayoutName(l)) return l;
  }
  return absl::InvalidArgumentError(
      absl::StrFormat("unknown layout '%s' (coherent, postorder, breadth-first, shuffled)", name));
}

namespace internal {
namespace {

constexpr size_t kBatch = 8192;
constexpr size_t kUnpackChunk = 256;  // decoded records at a time in the octree pass (12 KiB)
constexpr size_t kPackChunk = 256;    // records packed at a time in the input pass (12 KiB)
constexpr uint64_t kProgressEvery = uint64_t{1} << 18;
constexpr uint64_t kMinRunRecords = 256;
constexpr uint64_t kMiB = uint64_t{1} << 20;

absl::Status CheckCancel(const BuildOptions& o) {
  if (o.cancel != nullptr && o.cancel->load(std::memory_order_relaxed)) {
    return absl::CancelledError("the build was interrupted");
  }
  return absl::OkStatus();
}

void Report(const BuildOptions& o, const char* pass, uint64_t done, int64_t total) {
  if (o.progress) o.progress(BuildProgress{pass, done, total});
}

absl::Status CheckOptions(const BuildOptions& o, uint32_t page_size) {
  if (o.leaf_size == 0) return absl::InvalidArgumentError("leaf size must be at least 1");
  if (page_size < sizeof(PageHeader) + 8 * NodeRecordSize(o.channels)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "page size %d is too small: a page must hold a sibling group of 8 node records (%d "
        "bytes)",
        page_size, sizeof(PageHeader) + 8 * NodeRecordSize(o.channels)));
  }
  if (NodesPerPage(page_size, o.channels) > 0xffff) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "page size %d is too large: node refs address at most 65535 records per page", page_size));
  }
  return absl::OkStatus();
}

}  // namespace

int ThreadCount(const BuildOptions& o) {
  // 0 means one here; `pbgi build` resolves its default 0 to the cores, since the pipelined build
  // pays on 2 idle cores (docs/format.md, "Session 11: build throughput from a PLY").
  return o.threads > 0 ? o.threads : 1;
}

namespace {

constexpr uint64_t kMinUpperBytes = 256 << 10;
constexpr uint64_t kMinMergeBytes = 64 << 10;

uint64_t BatchBytes(uint64_t m) { return std::clamp<uint64_t>(m / 16, kMiB, 64 * kMiB); }

// PlanFor's fixed part on one thread.
uint64_t FixedBytes(const BuildOptions& o) {
  return 24 * kMiB + 4 * uint64_t{o.page_size} +
         (o.estimate.radius || o.estimate.normals ? NeighbourEstimator::kMemoryBytes : 0);
}

// The smallest sort share a plan runs with: the smallest run, or the merge's smallest buffers.
constexpr uint64_t kMinSortBytes =
    std::max<uint64_t>(kMinRunRecords * kSortBytesPerRecord, kMinMergeBytes);

MemoryPlan PlanFor(const BuildOptions& o, int64_t known_count, int threads) {
  MemoryPlan p;
  const uint64_t m = o.memory_bytes;
  p.threads = threads;
  p.batch_bytes = BatchBytes(m);
  // Node packer pending sets, page buffers, the look-ahead window, the PLY reader, LMDB's own
  // allocations and the process's baseline (code, libraries). Threads add the merge's block
  // pipe and the LMDB writer's page slots, and LMDB's dirty pages then come from the writer
  // thread's malloc arena, which keeps about one more batch of freed pages resident
  // (docs/design.md, "Memory plan"). In the input pass, before the pipe exists, the same share
  // holds the caller's writer of a shared spill (about 1.3 MiB: ExternalSorter::HelpSpill).
  const uint64_t fixed = FixedBytes(o) + (threads > 1 ? 4 * kMiB + p.batch_bytes : 0);
  p.fixed_bytes = fixed;
  uint64_t sort_bytes = m > p.batch_bytes + fixed ? m - p.batch_bytes - fixed : 0;
  // The coherent layout's upper node groups grow during the octree pass, while the merge buffers
  // (or, without spill, the sorted run) are in use: they get their own share.
  p.upper_bytes =
      std::clamp<uint64_t>(sort_bytes / 4, kMinUpperBytes, NodePacker::kDefaultUpperLimitBytes);
  sort_bytes = sort_bytes > p.upper_bytes ? sort_bytes - p.upper_bytes : 0;
  p.sort_bytes = sort_bytes;
  p.fits =
      sort_bytes >= (threads > 1 ? kMinRunRecords * kSortBytesPerRecordThreaded : kMinSortBytes);
  p.run_capacity = std::max<uint64_t>(kMinRunRecords, sort_bytes / kSortBytesPerRecord);
  if (known_count >= 0 && uint64_t(known_count) <= p.run_capacity) {
    // Fits one run: never spilled, so no second buffer either.
    p.run_capacity = std::max<uint64_t>(1, uint64_t(known_count));
    p.spills = false;
  } else if (threads > 1) {
    // A second run buffer fills while the first one is sorted and spilled.
    p.run_capacity = std::max<uint64_t>(kMinRunRecords, sort_bytes / kSortBytesPerRecordThreaded);
  }
  // The merge reuses the sort's memory once the runs are spilled (at most 8 MiB a run: a larger
  // read buffer gains nothing and would stay resident through the whole merge).
  p.merge_bytes = std::max<uint64_t>(kMinMergeBytes, sort_bytes);
  return p;
}

}  // namespace

}  // namespace internal

uint64_t MinimumBuildMemory(const BuildOptions& o) {
  // PlanFor's fixed part, the smallest upper share and the smallest sort share, on one thread
  // (the plan drops to one under a small budget), and the write batch, a sixteenth of the
  // budget: the smallest M with M - M/16 >= the rest.
  const uint64_t rest =
      internal::FixedBytes(o) + internal::kMinUpperBytes + internal::kMinSortBytes;
  const uint64_t m = (rest * 16 + 14) / 15;
  return std::max(m, rest + internal::BatchBytes(m));
}

namespace internal {

MemoryPlan PlanMemory(const BuildOptions& o, int64_t known_count) {
  const int threads = ThreadCount(o);
  const MemoryPlan one = PlanFor(o, known_count, 1);
  if (threads <= 1) return one;
  const MemoryPlan many = PlanFor(o, known_count, threads);
  // Under a small budget the threads' own memory would cut the sort's share so much that the
  // runs shrink (and the merge fans out) more than the overlap gains: 1 M points at 32 MiB made
  // 4,096 runs and took 20x longer. Threads only when they leave at least half the sort memory.
  // And when the threads' own memory does not fit where one thread's does (a budget below
  // MinimumBuildMemory fits neither: the library takes those to force spills in tests).
  if ((!many.fits && one.fits) || (many.spills && 2 * many.sort_bytes < one.sort_bytes)) {
    return one;
  }
  return many;
}

namespace {

// Removes a resumable build's run directory when the build ends before its runs were kept
// (declared before the sorter, so that the sorter has closed and unlinked its runs first).
struct RunDirGuard {
  std::string dir;
  bool keep = false;
  ~RunDirGuard() {
    std::error_code ec;
    if (!dir.empty() && !keep) std::filesystem::remove_all(dir, ec);
  }
};

}  // namespace

absl::StatusOr<BuildStats> BuildToSink(SurfelSource& source, PageSink& sink,
                                       const BuildOptions& options, const std::string& tmp_dir,
                                       StoreMeta* meta, const std::string& run_dir) {
  const Stopwatch total;
  PBGI_RETURN_IF_ERROR(CheckOptions(options, sink.page_size()));
  const bool radiance = HasRadiance(options.channels);
  const int64_t known = source.KnownCount();
  BuildStats stats;
  std::vector<Surfel> batch(kBatch);

  // Reads the whole source once, calling f(surfel, index) for every valid surfel.
  auto for_each_valid = [&](const char* pass, auto&& f) -> absl::Status {
    PBGI_RETURN_IF_ERROR(source.Rewind());
    uint64_t index = 0, skipped = 0, next_report = kProgressEvery;
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(size_t n, source.Next(absl::MakeSpan(batch)));
      if (n == 0) break;
      PBGI_RETURN_IF_ERROR(CheckCancel(options));
      for (size_t i = 0; i < n; ++i, ++index) {
        const Surfel& s = batch[i];
        if (const char* why = InvalidSurfelReason(s, radiance, options.estimate.radius,
                                                  options.estimate.normals)) {
          if (!options.skip_invalid) {
            return absl::InvalidArgumentError(absl::StrFormat(
                "input surfel %d (counting from 0): %s (use skip_invalid / --skip-invalid to "
                "drop such surfels)",
                index, why));
          }
          ++skipped;
          continue;
        }
        PBGI_RETURN_IF_ERROR(f(s, index));
      }
      if (index >= next_report) {
        Report(options, pass, index, known);
        next_report = index + kProgressEvery;
      }
    }
    stats.skipped = skipped;
    return absl::OkStatus();
  };

  const bool resume = !run_dir.empty() && options.resumable.resume;
  RunDirGuard run_guard;
  std::error_code ec;
  if (!run_dir.empty() && !resume) {
    // A fresh resumable build replaces what an earlier one kept.
    std::filesystem::remove_all(run_dir, ec);
    std::filesystem::create_directories(run_dir, ec);
    if (ec) {
      return absl::InternalError(
          absl::StrFormat("cannot create the run directory %s: %s", run_dir, ec.message()));
    }
    run_guard.dir = run_dir;
  }

  // Pass 1: bounds, unless the source knows them.
  Bounds bounds = source.KnownBounds();
  const bool declared = !bounds.Empty();
  Stopwatch t;
  RunManifest kept;
  if (resume) {
    absl::StatusOr<RunManifest> m = ReadManifest(run_dir);
    if (absl::IsNotFound(m.status())) {
      return absl::NotFoundError(absl::StrFormat(
          "nothing to resume: no sort runs are kept in %s (the interrupted build did not finish "
          "its sort pass, did not spill, or used another --tmp); build without --resume",
          run_dir));
    }
    PBGI_RETURN_IF_ERROR(m.status());
    kept = *std::move(m);
    PBGI_RETURN_IF_ERROR(CheckResumable(kept, ManifestFor(options, bounds, declared), run_dir));
    bounds = kept.key_bounds;
    stats.skipped = kept.skipped;
    stats.seconds_bounds = kept.seconds_bounds;
    stats.seconds_sort = kept.seconds_sort;
    stats.resumed = true;
  } else if (!declared) {
    PBGI_RETURN_IF_ERROR(for_each_valid("bounds", [&](const Surfel& s, uint64_t) {
      bounds.Extend(s.position);
      return absl::OkStatus();
    }));
    stats.seconds_bounds = t.Seconds();
  }

  // Pass 2: keys and sorted runs.
  t.Restart();
  const MemoryPlan plan = PlanMemory(options, resume ? kept.known_count : known);
  stats.run_capacity = resume ? kept.run_capacity : plan.run_capacity;
  stats.threads = plan.threads;
  ExternalSorter::Options sort_options;
  sort_options.tmp_dir = tmp_dir;
  sort_options.run_capacity = plan.run_capacity;
  sort_options.merge_bytes = plan.merge_bytes;
  sort_options.threads = plan.threads;
  if (CompactSpill(options)) {
    sort_options.compact = SpillCodec{SpillChannels(options), GridOfCube(MortonCube(bounds))};
    sort_options.packed_input = true;
    sort_options.packed_output = true;
  }
  // Whether some two-sided surfel's back radiance differs from its front, as stored: the
  // database then stores Channels::kRadianceBothSides.
  bool back_radiance = resume && kept.back_radiance;
  ExternalSorter::RunsWritten runs_written;
  if (!run_dir.empty() && !resume) {
    runs_written = [&](const std::vector<KeptRun>& runs) -> absl::Status {
      RunManifest m = ManifestFor(options, bounds, declared);
      for (const KeptRun& r : runs) m.records += r.records;
      m.skipped = stats.skipped;
      m.back_radiance = back_radiance;
      m.known_count = known;
      m.run_capacity = plan.run_capacity;
      m.seconds_bounds = stats.seconds_bounds;
      m.seconds_sort = t.Seconds();
      m.runs = runs;
      PBGI_RETURN_IF_ERROR(WriteManifest(run_dir, m));
      run_guard.keep = true;
      return absl::OkStatus();
    };
  }
  ExternalSorter sorter(sort_options);
  if (!run_dir.empty()) sorter.SetRunDirectory(run_dir, std::move(runs_written));
  InputRangeCheck range;
  if (resume) {
    PBGI_RETURN_IF_ERROR(sorter.ResumeFrom(kept.runs));
  } else {
    const MortonQuantizer quant(bounds);
    const Bounds inside = KeyBoundsTolerance(bounds);
    // Records are made in place in the sorter's run buffer, and packed there a chunk at a time
    // (SpillCodec::PackBlock; docs/format.md, "Session 17").
    absl::Span<SortRecord> slots;
    size_t used = 0, packed = 0;
    auto pack = [&] {
      if (sort_options.packed_input && used > packed) {
        sort_options.compact->PackBlock(&slots[packed], used - packed, &slots[packed]);
      }
      packed = used;
    };
    PBGI_RETURN_IF_ERROR(
        for_each_valid("sort", [&](const Surfel& in, uint64_t index) -> absl::Status {
          PBGI_RETURN_IF_ERROR(options.estimate.radius ? range.AddPosition(in, index)
                                                       : range.Add(in, index, radiance));
          if (declared && !inside.Contains(in.position)) {
            return absl::InvalidArgumentError(absl::StrFormat(
                "input surfel %d (counting from 0) at (%g, %g, %g) lies outside the bounds the "
                "source declared, (%g, %g, %g) to (%g, %g, %g) (a PLY's `comment pbgi bounds` "
                "line or --bounds): give bounds that hold every point, or none",
                index, in.position.x, in.position.y, in.position.z, bounds.lo.x, bounds.lo.y,
                bounds.lo.z, bounds.hi.x, bounds.hi.y, bounds.hi.z));
          }
          if (used == slots.size()) {
            pack();
            sorter.Commit(used);
            used = packed = 0;
            PBGI_ASSIGN_OR_RETURN(slots, sorter.Reserve(kBatch));
          }
          Surfel s = in;
          if (options.estimate.normals) {
            s.normal = glm::vec3(0.0f);
          } else {
            s.normal = glm::vec3(glm::normalize(glm::dvec3(s.normal)));
          }
          if (options.estimate.radius) s.radius = 0.0f;
          if (!radiance) s.radiance = glm::vec3(0.0f);
          slots[used] = MakeSortRecord(quant.Key(s.position), s);
          if (radiance && s.two_sided && !back_radiance) {
            back_radiance = RecordBackDiffers(slots[used]);
          }
          ++used;
          if (used - packed == kPackChunk) pack();
          return absl::OkStatus();
        }));
    pack();
    sorter.Commit(used);
    PBGI_RETURN_IF_ERROR(sorter.FinishInput());
    stats.seconds_sort = t.Seconds();
    if (run_guard.keep && options.resumable.stop_after_sort) {
      return absl::CancelledError(
          "stopped after the sort pass (BuildOptions::resumable.stop_after_sort): the runs are "
          "kept for --resume");
    }
  }
  stats.runs_spilled = sorter.runs_spilled();
  stats.merge_passes = sorter.merge_passes();
  stats.spill_bytes = sorter.spill_bytes();
  if (sorter.records() == 0) {
    return absl::InvalidArgumentError(
        stats.skipped > 0
            ? absl::StrFormat("the input has no valid surfels (%d invalid ones skipped)",
                              stats.skipped)
            : std::string("the input has no surfels"));
  }

  if (sorter.records() > kMaxStoredPointIndex) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "the input has %d surfels: a store holds at most 2^40 - 1 (format version 3 stores "
        "point indices in 40 bits)",
        sorter.records()));
  }

  // Pass 3: merge, octree, pages.
  t.Restart();
  // Positions and node bounds are stored on the grid of the Morton keys' cube (tree/format.h).
  const PositionGrid grid = GridOfCube(MortonCube(bounds));
  const Channels channels = back_radiance ? Channels::kRadianceBothSides : options.channels;
  NodePacker packer(options.layout, channels, &sink, options.shuffle_seed, grid);
  packer.set_upper_limit_bytes(plan.upper_bytes);
  PointPageWriter points(channels, &sink, grid);
  points.set_input_quantized(sorter.output_quantized());
  points.set_input_packed(sorter.output_packed());
  OctreeBuilder octree(options.leaf_size, channels, &points, &packer);
  const bool estimate = options.estimate.radius || options.estimate.normals;
  NeighbourEstimator estimator(options.estimate, bounds);
  uint64_t estimated = 0;
  auto to_octree = [&](const SortRecord& r) -> absl::Status {
    if (options.estimate.radius) {
      Surfel s;
      s.position = glm::vec3(r.position[0], r.position[1], r.position[2]);
      s.radius = std::fabs(r.radius);  // the sign bit is the two-sided flag
      float front[3], back[3];
      RecordRadiances(r.radius, r.radiance, front, back);
      s.radiance = glm::vec3(front[0], front[1], front[2]);
      PBGI_RETURN_IF_ERROR(range.AddEstimated(s, estimated++, radiance));
    }
    return octree.Add(r);
  };
  // Packed records are decoded a chunk at a time (SpillCodec::UnpackBlock), not one by one as
  // their point pages take them (docs/format.md, "Session 17").
  const bool unpack = sorter.output_packed() && !estimate;
  std::vector<SortRecord> unpacked(unpack ? kUnpackChunk : 0);
  uint64_t done = 0, next_report = kProgressEvery;
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(absl::Span<const SortRecord> recs, sorter.NextBlock());
    if (recs.empty()) break;
    PBGI_RETURN_IF_ERROR(CheckCancel(options));
    if (unpack) {
      for (size_t i = 0; i < recs.size(); i += kUnpackChunk) {
        const size_t k = std::min(kUnpackChunk, recs.size() - i);
        sort_options.compact->UnpackBlock(&recs[i], k, unpacked.data());
        for (size_t j = 0; j < k; ++j) PBGI_RETURN_IF_ERROR(octree.Add(recs[i + j], unpacked[j]));
      }
    } else {
      for (const SortRecord& r : recs) {
        PBGI_RETURN_IF_ERROR(estimate ? estimator.Add(r, to_octree) : octree.Add(r));
      }
    }
    done += recs.size();
    if (done >= next_report) {
      Report(options, "merge+octree", done, static_cast<int64_t>(sorter.records()));
      next_report = done + kProgressEvery;
    }
  }
  if (estimate) PBGI_RETURN_IF_ERROR(estimator.Finish(to_octree));
  PBGI_ASSIGN_OR_RETURN(NodeRef root, octree.Finish());
  stats.seconds_merge = t.Seconds();

  const OctreeStats& os = octree.stats();
  stats.points = points.points();
  stats.nodes = os.nodes;
  stats.leaves = os.leaves;
  stats.max_depth = os.max_depth;
  stats.max_leaf_points = os.max_leaf_points;
  stats.node_pages = packer.pages();
  stats.point_pages = points.pages();
  stats.node_page_fill = packer.pages() == 0 ? 0
                                             : double(packer.records_written()) /
                                                   (double(packer.pages()) * packer.capacity());
  stats.upper_records = packer.upper_records();
  stats.early_upper_writes = packer.early_upper_writes();
  stats.seconds_total = total.Seconds();

  *meta = StoreMeta{};
  meta->page_size = sink.page_size();
  meta->channels = channels;
  meta->sh_order = 2;
  meta->leaf_size = options.leaf_size;
  meta->bounds = os.bounds;
  meta->point_count = stats.points;
  meta->node_count = stats.nodes;
  meta->node_pages = stats.node_pages;
  meta->point_pages = stats.point_pages;
  meta->root = root;
  meta->max_depth = stats.max_depth;
  meta->layout = LayoutName(options.layout);
  for (int a = 0; a < 3; ++a) meta->grid_origin[a] = grid.origin[a];
  meta->grid_step = grid.step;
  auto& m = meta->stats;
  m["points"] = absl::StrFormat("%d", stats.points);
  m["skipped"] = absl::StrFormat("%d", stats.skipped);
  m["leaves"] = absl::StrFormat("%d", stats.leaves);
  m["max_leaf_points"] = absl::StrFormat("%d", stats.max_leaf_points);
  m["node_page_fill"] = absl::StrFormat("%.4f", stats.node_page_fill);
  m["seconds_bounds"] = absl::StrFormat("%.3f", stats.seconds_bounds);
  m["seconds_sort"] = absl::StrFormat("%.3f", stats.seconds_sort);
  m["seconds_merge"] = absl::StrFormat("%.3f", stats.seconds_merge);
  m["runs_spilled"] = absl::StrFormat("%d", stats.runs_spilled);
  m["merge_passes"] = absl::StrFormat("%d", stats.merge_passes);
  m["memory_bytes"] = absl::StrFormat("%d", options.memory_bytes);
  m["threads"] = absl::StrFormat("%d", stats.threads);
  // The box whose cube the Morton keys were made in (the source's declared bounds when it knew
  // them, which may be larger than the points' box): the reader's octree cells come from it
  // (query/database.cc KeyBounds), exactly, as hexadecimal floats.
  m["key_bounds"] = absl::StrFormat("%a %a %a %a %a %a", bounds.lo.x, bounds.lo.y, bounds.lo.z,
                                    bounds.hi.x, bounds.hi.y, bounds.hi.z);
  m["upper_records"] = absl::StrFormat("%d", stats.upper_records);
  m["early_upper_writes"] = absl::StrFormat("%d", stats.early_upper_writes);
  if (stats.resumed) m["resumed"] = "1";
  const std::string knn = absl::StrFormat("estimated from %d nearest neighbours",
                                          std::clamp(options.estimate.neighbours, 3, 64));
  if (options.estimate.radius) m["radius"] = knn;
  if (options.estimate.normals) {
    m["normals"] =
        knn + (options.estimate.towards_viewpoint
                   ? absl::StrFormat(" (PCA, towards %g,%g,%g)", options.estimate.viewpoint.x,
                                     options.estimate.viewpoint.y, options.estimate.viewpoint.z)
                   : std::string(" (PCA, away from the centre)"));
  }
  for (const auto& [k, v] : options.provenance) {
    if (m.count(k) == 0) m[k] = v;
  }
  return stats;
}

}  // namespace internal
}  // namespace pbgi
