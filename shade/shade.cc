// ShadeBatch (include/pbgi/shade.h): gather + rasterize on a TBB arena of `threads` threads.
#include "pbgi/shade.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "base/stopwatch.h"
#include "oneapi/tbb/blocked_range.h"
#include "oneapi/tbb/enumerable_thread_specific.h"
#include "oneapi/tbb/parallel_for.h"
#include "oneapi/tbb/task_arena.h"
#include "pbgi/status.h"
#include "tree/morton.h"

namespace pbgi {
namespace {

using internal::Stopwatch;

// Everything one thread needs, made on first use in that thread.
struct Worker {
  std::unique_ptr<Reader> reader;
  MicroBuffer buffer;
  Gathered gathered;
  QueryStats query;
  double gather_seconds = 0;
  double raster_seconds = 0;
  absl::Status init;
};

absl::Status Validate(absl::Span<const ShadeReceiver> receivers, const ShadeOptions& options,
                      absl::Span<ShadeResult> out) {
  if (out.size() != receivers.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ShadeBatch: %d results for %d receivers", out.size(), receivers.size()));
  }
  if (!(options.cut.max_solid_angle >= 0.0f)) {
    return absl::InvalidArgumentError("max_solid_angle must be >= 0");
  }
  if (!(options.cut.curved_scale > 0.0f && options.cut.curved_scale <= 1.0f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("Cut.curved_scale = %g: must be in (0, 1]", options.cut.curved_scale));
  }
  PBGI_RETURN_IF_ERROR(ValidateRasterOptions(options.raster));
  for (size_t i = 0; i < receivers.size(); ++i) {
    const ShadeReceiver& r = receivers[i];
    const bool finite = std::isfinite(r.position.x) && std::isfinite(r.position.y) &&
                        std::isfinite(r.position.z) && std::isfinite(r.normal.x) &&
                        std::isfinite(r.normal.y) && std::isfinite(r.normal.z);
    if (!finite || glm::dot(r.normal, r.normal) == 0.0f) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "receiver %d has a %s", i, finite ? "zero normal" : "NaN or infinite coordinate"));
    }
  }
  return absl::OkStatus();
}

}  // namespace

void ShadeStats::Add(const ShadeStats& o) {
  receivers += o.receivers;
  seconds += o.seconds;
  query.Add(o.query);
  cache.Add(o.cache);
  gather_seconds += o.gather_seconds;
  raster_seconds += o.raster_seconds;
}

int DefaultShadeThreads() { return std::max(1u, std::thread::hardware_concurrency()); }

absl::Status ShadeBatch(Database& db, absl::Span<const ShadeReceiver> receivers,
                        const ShadeOptions& options, absl::Span<ShadeResult> out,
                        ShadeStats* stats) {
  PBGI_RETURN_IF_ERROR(Validate(receivers, options, out));
  const Stopwatch clock;
  std::fill(out.begin(), out.end(), ShadeResult{});
  std::vector<uint32_t> order;
  if (options.z_order) {
    order =
        internal::MortonOrder(receivers.size(), [&](size_t i) { return receivers[i].position; });
  } else {
    order.resize(receivers.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<uint32_t>(i);
  }

  const int threads = options.threads > 0 ? options.threads : DefaultShadeThreads();
  const uint64_t total = receivers.size();
  tbb::enumerable_thread_specific<Worker> workers;
  std::atomic<bool> failed{false};
  std::mutex error_mu;
  absl::Status first_error;
  std::atomic<uint64_t> done{0};
  std::mutex progress_mu;
  Stopwatch since_progress;

  auto fail = [&](absl::Status s) {
    std::lock_guard<std::mutex> lock(error_mu);
    if (first_error.ok()) first_error = std::move(s);
    failed.store(true, std::memory_order_relaxed);
  };
  auto cancelled = [&] {
    return options.cancel != nullptr && options.cancel->load(std::memory_order_relaxed);
  };

  // Blocks of consecutive Z-ordered receivers keep each thread's pages coherent; at most 64,
  // and small enough that every thread gets about 16 of them, so that a small batch does not
  // wait for one thread's last block (docs/query.md).
  const size_t grain = std::clamp<size_t>(order.size() / (16 * size_t(threads)), 1, 64);
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, order.size(), grain),
        [&](const tbb::blocked_range<size_t>& range) {
          if (failed.load(std::memory_order_relaxed)) return;
          if (cancelled()) {
            return fail(absl::CancelledError(absl::StrFormat(
                "shading was cancelled after %d of %d receivers", done.load(), total)));
          }
          bool exists = false;
          Worker& w = workers.local(exists);
          if (!exists) {
            auto reader = db.NewReader();
            if (!reader.ok()) {
              w.init = reader.status();
            } else {
              w.reader = std::move(reader).value();
              w.init = w.buffer.Prepare(options.raster.resolution);
            }
          }
          if (!w.init.ok()) return fail(w.init);
          for (size_t k = range.begin(); k != range.end(); ++k) {
            if (failed.load(std::memory_order_relaxed)) return;
            const uint32_t i = order[k];
            const ShadeReceiver& sr = receivers[i];
            const Stopwatch t;
            absl::Status s =
                w.reader->Gather({sr.position, sr.normal}, options.cut, &w.gathered, &w.query);
            const double gather = t.Seconds();
            if (!s.ok()) return fail(std::move(s));
            s = Shade(w.gathered, sr, options.raster, &w.buffer, &out[i]);
            if (!s.ok()) {
              return fail(
                  absl::Status(s.code(), absl::StrFormat("receiver %d: %s", i, s.message())));
            }
            w.gather_seconds += gather;
            w.raster_seconds += t.Seconds() - gather;
          }
          const uint64_t now_done = done.fetch_add(range.size()) + range.size();
          if (options.progress) {
            std::unique_lock<std::mutex> lock(progress_mu, std::try_to_lock);
            if (lock.owns_lock() && since_progress.Seconds() >= options.progress_interval_seconds) {
              since_progress.Restart();
              options.progress(ShadeProgress{now_done, total});
            }
          }
        });
  });
  if (failed.load()) return first_error;

  if (stats != nullptr) {
    *stats = ShadeStats{};
    stats->receivers = total;
    stats->seconds = clock.Seconds();
    for (Worker& w : workers) {
      stats->query.Add(w.query);
      if (w.reader) stats->cache.Add(w.reader->stats());
      stats->gather_seconds += w.gather_seconds;
      stats->raster_seconds += w.raster_seconds;
    }
  }
  if (options.progress) options.progress(ShadeProgress{total, total});
  return absl::OkStatus();
}

}  // namespace pbgi
