// pbgi::ShadeBatch: the library's main composition. Shades a batch of receivers from a database
// on several threads: each thread gathers the cut for a receiver (pbgi/query.h) and rasterizes it
// (pbgi/raster.h), with one Reader, one MicroBuffer and one Gathered of its own, visiting the
// receivers in Z-order in blocks of consecutive ones so that each thread's pages stay coherent
// (docs/design.md, "Shading").
//
//   auto db = pbgi::Database::Open("scene.pbgi", {.cache_bytes = 512 << 20});
//   std::vector<pbgi::ShadeResult> out(receivers.size());
//   pbgi::ShadeOptions options;                 // cut, raster options, threads, ...
//   absl::Status s = pbgi::ShadeBatch(**db, receivers, options, absl::MakeSpan(out));
//
// Each result depends only on its receiver, the database and the options: not on the thread
// count, the order or the other receivers of the batch.
//
// Thread safety: ShadeBatch may run concurrently on one Database (each call makes its own
// Readers; mind the cache budget rule of pbgi/query.h: readers * reader_cache_bytes <=
// cache_bytes, which the default per-Reader share keeps). The progress callback runs on one of
// the worker threads, never on two at once.
//
// Memory: the batch's receivers and results (the caller's), one order index per receiver, and
// per thread a Reader (its share of the cache budget), a MicroBuffer and a Gathered.
#ifndef PBGI_SHADE_H_
#define PBGI_SHADE_H_

#include <atomic>
#include <cstdint>
#include <functional>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"

namespace pbgi {

// Where a batch is, for ShadeOptions::progress.
struct ShadeProgress {
  uint64_t done = 0;   // receivers shaded so far
  uint64_t total = 0;  // receivers in the batch
};

// How to shade a batch. New ways of shading (e.g. sharing work between neighbouring receivers)
// come as new fields whose defaults keep today's behaviour.
struct ShadeOptions {
  Cut cut;
  RasterOptions raster;
  int threads = 0;      // 0: all cores (DefaultShadeThreads())
  bool z_order = true;  // visit receivers in Z-order (coherence); false: in the given order
  // Called from one worker thread at most every progress_interval_seconds, and once at the end
  // of a batch that succeeds (done == total).
  std::function<void(const ShadeProgress&)> progress;
  double progress_interval_seconds = 1.0;
  // When set and it becomes true (a renderer's abort, a SIGINT handler), the batch stops at the
  // next block of receivers with a Cancelled error; the results are then incomplete.
  const std::atomic<bool>* cancel = nullptr;
};

// What a batch cost.
struct ShadeStats {
  uint64_t receivers = 0;
  double seconds = 0;         // wall time
  QueryStats query;           // summed over threads
  CacheStats cache;           // the batch's Readers' counters, summed
  double gather_seconds = 0;  // summed over threads (thread time in Gather)
  double raster_seconds = 0;  // summed over threads (thread time in Shade)
  // Sums another batch's figures into these.
  void Add(const ShadeStats& o);
};

// Shades every receiver: out[i] belongs to receivers[i] (out.size() must equal
// receivers.size()). Errors: InvalidArgument naming the receiver for a non-finite position or
// a zero or non-finite normal, and for invalid options (before anything is shaded); the first
// error of any thread otherwise (a damaged page, ...), after which the other threads stop at
// their next receiver; Cancelled when options.cancel is raised. On error `out` is incomplete.
// `stats`, when not null, is overwritten with what the batch cost.
absl::Status ShadeBatch(Database& db, absl::Span<const ShadeReceiver> receivers,
                        const ShadeOptions& options, absl::Span<ShadeResult> out,
                        ShadeStats* stats = nullptr);

// The default thread count: the number of cores.
int DefaultShadeThreads();

}  // namespace pbgi

#endif  // PBGI_SHADE_H_
