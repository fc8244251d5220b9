// The parallel core of ShadeBatch (include/pbgi/shade.h): shades a list of receivers of a batch
// on a TBB arena, one Reader, MicroBuffer and Gathered per thread, in Z-ordered blocks; owns the
// batch's progress, cancellation and first error. Both modes run on it: kExact calls Shade() once
// with every receiver, kShared once per level of its refinement (shade/image_sharing.h,
// shade/point_sharing.h). Internal.
#ifndef PBGI_SHADE_ENGINE_H_
#define PBGI_SHADE_ENGINE_H_

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "base/stopwatch.h"
#include "oneapi/tbb/enumerable_thread_specific.h"
#include "oneapi/tbb/task_arena.h"
#include "pbgi/shade.h"

namespace pbgi::internal {

// The harmonic mean distance that a receiver's micro-buffer saw: the cosine-weighted mean of
// coverage / depth over the hemisphere's pixels, inverted (an uncovered pixel counts as
// infinitely far; nothing covered gives +inf). Ward's R_i: occlusion and irradiance change by
// about |dx| / R over a step dx (Ward, Rubinstein, Clear 1988; Ward & Heckbert 1992).
float HarmonicDistance(const MicroBuffer& buffer);

class ShadeEngine {
 public:
  // REQUIRES: the arguments outlive the engine and were validated (ShadeBatch does both).
  // `cut` is the cut that every receiver's starts from (options.cut, or ShadeBatch's with the
  // radiance contrast set: EffectiveCut).
  ShadeEngine(Database& db, absl::Span<const ShadeReceiver> receivers, const ShadeOptions& options,
              const Cut& cut, absl::Span<ShadeResult> out);
  ShadeEngine(const ShadeEngine&) = delete;
  ShadeEngine& operator=(const ShadeEngine&) = delete;
  ~ShadeEngine();

  int threads() const { return threads_; }
  tbb::task_arena& arena() { return arena_; }

  // Shades receivers[i] into out[i] for every i in `indices` (visited in Z-order when
  // options.z_order). When `distance` is not null, distance[i] = HarmonicDistance of receiver i.
  // Counts them as done. Returns the batch's first error (also of an earlier call).
  absl::Status Shade(absl::Span<const uint32_t> indices, float* distance = nullptr);

  // Counts receivers decided without shading (kShared), for progress.
  void AddDone(uint64_t n);
  // A Cancelled error (and the batch failed) when options.cancel is raised, else OK.
  absl::Status CheckCancel();
  // Records a failure (the first one wins).
  void Fail(absl::Status s);
  absl::Status status();

  // The batch's figures so far (receivers, seconds, query and cache counters, stage times).
  ShadeStats Stats();
  // The final progress report (done == total) of a batch that succeeded.
  void ReportEnd();

 private:
  struct Worker;
  void MaybeReportProgress(uint64_t done);
  // This thread's Worker, made on first use; null (and the batch failed) when that failed.
  Worker* LocalWorker();
  // Shades receiver i on its own into out_[i] (and distance[i]). False when it failed.
  bool ShadeOne(Worker& w, uint32_t i, float* distance);
  // Shade() with far-field sharing (ShadeOptions::far_sharing), over receivers in Z-order.
  absl::Status ShadeGroups(const std::vector<uint32_t>& order, float* distance);

  Database& db_;
  absl::Span<const ShadeReceiver> receivers_;
  const ShadeOptions& options_;
  absl::Span<ShadeResult> out_;
  // options.cut, with the lobe-aware cut's lobe when it applies (lobe_cut_; its direction is
  // each receiver's reflection).
  Cut cut_;
  bool lobe_cut_ = false;
  const Stopwatch clock_;
  const double cpu_start_ = ProcessCpuSeconds();
  const int threads_;
  tbb::task_arena arena_;
  std::unique_ptr<tbb::enumerable_thread_specific<Worker>> workers_;
  std::atomic<bool> failed_{false};
  std::mutex error_mu_;
  absl::Status first_error_;
  std::atomic<uint64_t> done_{0};
  std::atomic<uint64_t> shaded_{0};
  std::atomic<uint64_t> far_groups_{0};
  std::atomic<uint64_t> far_members_{0};
  std::mutex progress_mu_;
  Stopwatch since_progress_;
};

}  // namespace pbgi::internal

#endif  // PBGI_SHADE_ENGINE_H_
