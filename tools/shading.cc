#include "tools/shading.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <thread>

#include "absl/strings/str_format.h"
#include "oneapi/tbb/enumerable_thread_specific.h"
#include "oneapi/tbb/parallel_for.h"
#include "oneapi/tbb/task_arena.h"
#include "pbgi/status.h"

namespace pbgi::tools {
namespace {

using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

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

}  // namespace

int DefaultThreads() { return std::max(1u, std::thread::hardware_concurrency()); }

absl::Status ShadeReceivers(Database& db, absl::Span<const Receiver> receivers,
                            absl::Span<const glm::vec3> reflections, const ShadeJobOptions& options,
                            std::vector<ShadeResult>* results, ShadeJobStats* stats) {
  if (!reflections.empty() && reflections.size() != receivers.size()) {
    return absl::InvalidArgumentError(absl::StrFormat("%d reflection directions for %d receivers",
                                                      reflections.size(), receivers.size()));
  }
  if (!(options.cut.max_solid_angle >= 0.0f)) {
    return absl::InvalidArgumentError("max_solid_angle must be >= 0");
  }
  PBGI_RETURN_IF_ERROR(ValidateRasterOptions(options.raster));
  for (size_t i = 0; i < receivers.size(); ++i) {
    const Receiver& r = receivers[i];
    const bool finite = std::isfinite(r.position.x) && std::isfinite(r.position.y) &&
                        std::isfinite(r.position.z) && std::isfinite(r.normal.x) &&
                        std::isfinite(r.normal.y) && std::isfinite(r.normal.z);
    if (!finite || glm::dot(r.normal, r.normal) == 0.0f) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "receiver %d has a %s", i, finite ? "zero normal" : "NaN or infinite coordinate"));
    }
  }

  results->assign(receivers.size(), ShadeResult{});
  std::vector<uint32_t> order;
  if (options.z_order) {
    order = ZOrder(receivers);
  } else {
    order.resize(receivers.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<uint32_t>(i);
  }

  const int threads = options.threads > 0 ? options.threads : DefaultThreads();
  tbb::enumerable_thread_specific<Worker> workers;
  std::atomic<bool> failed{false};
  std::mutex error_mu;
  absl::Status first_error;
  std::atomic<uint64_t> done{0};
  const auto start = Clock::now();
  auto last_progress = start;
  std::mutex progress_mu;

  auto fail = [&](absl::Status s) {
    std::lock_guard<std::mutex> lock(error_mu);
    if (first_error.ok()) first_error = std::move(s);
    failed.store(true, std::memory_order_relaxed);
  };

  // Blocks of consecutive Z-ordered receivers keep each thread's pages coherent; at most 64,
  // and small enough that every thread gets about 16 of them, so that a small job does not
  // wait for one thread's last block (300 receivers in blocks of 64 left one of 2 threads idle
  // for up to a fifth of the run).
  const size_t grain = std::clamp<size_t>(order.size() / (16 * size_t(threads)), 1, 64);
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, order.size(), grain),
        [&](const tbb::blocked_range<size_t>& range) {
          if (failed.load(std::memory_order_relaxed)) return;
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
            const uint32_t i = order[k];
            const auto t0 = Clock::now();
            absl::Status s = w.reader->Gather(receivers[i], options.cut, &w.gathered, &w.query);
            const auto t1 = Clock::now();
            if (!s.ok()) return fail(std::move(s));
            ShadeReceiver sr;
            sr.position = receivers[i].position;
            sr.normal = receivers[i].normal;
            sr.reflection = reflections.empty() ? receivers[i].normal : reflections[i];
            s = Shade(w.gathered, sr, options.raster, &w.buffer, &(*results)[i]);
            const auto t2 = Clock::now();
            if (!s.ok()) {
              return fail(
                  absl::Status(s.code(), absl::StrFormat("receiver %d: %s", i, s.message())));
            }
            w.gather_seconds += Seconds(t0, t1);
            w.raster_seconds += Seconds(t1, t2);
          }
          const uint64_t now_done = done.fetch_add(range.size()) + range.size();
          if (options.progress) {
            std::unique_lock<std::mutex> lock(progress_mu, std::try_to_lock);
            if (lock.owns_lock()) {
              const auto now = Clock::now();
              if (Seconds(last_progress, now) >= 1.0) {
                last_progress = now;
                options.progress(now_done);
              }
            }
          }
        });
  });
  if (failed.load()) return first_error;

  if (stats != nullptr) {
    *stats = ShadeJobStats{};
    stats->receivers = receivers.size();
    stats->seconds = Seconds(start, Clock::now());
    for (Worker& w : workers) {
      stats->query.Add(w.query);
      if (w.reader) stats->cache.Add(w.reader->stats());
      stats->gather_seconds += w.gather_seconds;
      stats->raster_seconds += w.raster_seconds;
    }
  }
  if (options.progress) options.progress(receivers.size());
  return absl::OkStatus();
}

}  // namespace pbgi::tools
