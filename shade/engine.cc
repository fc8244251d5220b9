// ShadeEngine (shade/engine.h).
#include "shade/engine.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_format.h"
#include "oneapi/tbb/blocked_range.h"
#include "oneapi/tbb/parallel_for.h"
#include "pbgi/status.h"
#include "tree/morton.h"

namespace pbgi::internal {

float HarmonicDistance(const MicroBuffer& buffer) {
  double weight = 0, inverse = 0;
  for (int p = 0; p < buffer.pixel_count(); ++p) {
    const double w = buffer.PixelCosineWeight(p);
    if (w <= 0) continue;
    weight += w;
    const float depth = buffer.PixelDepth(p);
    if (!(depth < std::numeric_limits<float>::infinity())) continue;
    const double c = std::clamp(double(buffer.PixelCoverage(p)), 0.0, 1.0);
    inverse += w * c / std::max(double(depth), 1e-30);
  }
  if (!(inverse > 0)) return std::numeric_limits<float>::infinity();
  return static_cast<float>(weight / inverse);
}

// Everything one thread needs, made on first use in that thread.
struct ShadeEngine::Worker {
  std::unique_ptr<Reader> reader;
  MicroBuffer buffer;
  Gathered gathered;
  QueryStats query;
  double gather_seconds = 0;
  double raster_seconds = 0;
  absl::Status init;
};

ShadeEngine::ShadeEngine(Database& db, absl::Span<const ShadeReceiver> receivers,
                         const ShadeOptions& options, absl::Span<ShadeResult> out)
    : db_(db),
      receivers_(receivers),
      options_(options),
      out_(out),
      threads_(options.threads > 0 ? options.threads : DefaultShadeThreads()),
      arena_(threads_),
      workers_(std::make_unique<tbb::enumerable_thread_specific<Worker>>()) {
  cut_ = options.cut;
  const RasterOptions& ro = options.raster;
  lobe_cut_ = options.lobe_cut && ro.lobe != GlossyLobe::kNone &&
              options.cut.lobe.kind == CutLobeKind::kNone;
  if (lobe_cut_) {
    cut_.lobe.kind = ro.lobe == GlossyLobe::kPhong ? CutLobeKind::kPhong : CutLobeKind::kGgx;
    cut_.lobe.phong_exponent = ro.phong_exponent;
    cut_.lobe.ggx_roughness = ro.ggx_roughness;
  }
}

namespace {
// The cut for one receiver: cut_, with the lobe centred on its reflection direction.
inline Cut ReceiverCut(const Cut& cut, bool lobe_cut, const ShadeReceiver& r) {
  Cut c = cut;
  if (!lobe_cut) return c;
  const float len2 = glm::dot(r.reflection, r.reflection);
  if (len2 > 0.0f && std::isfinite(len2)) {
    c.lobe.direction = r.reflection;
  } else {
    c.lobe.kind = CutLobeKind::kNone;  // no lobe to refine for: its glossy is 0
  }
  return c;
}
}  // namespace

ShadeEngine::~ShadeEngine() = default;

void ShadeEngine::Fail(absl::Status s) {
  std::lock_guard<std::mutex> lock(error_mu_);
  if (first_error_.ok()) first_error_ = std::move(s);
  failed_.store(true, std::memory_order_relaxed);
}

absl::Status ShadeEngine::status() {
  if (!failed_.load()) return absl::OkStatus();
  std::lock_guard<std::mutex> lock(error_mu_);
  return first_error_;
}

absl::Status ShadeEngine::CheckCancel() {
  if (options_.cancel != nullptr && options_.cancel->load(std::memory_order_relaxed)) {
    Fail(absl::CancelledError(absl::StrFormat("shading was cancelled after %d of %d receivers",
                                              done_.load(), receivers_.size())));
  }
  return status();
}

void ShadeEngine::MaybeReportProgress(uint64_t done) {
  if (!options_.progress) return;
  std::unique_lock<std::mutex> lock(progress_mu_, std::try_to_lock);
  if (lock.owns_lock() && since_progress_.Seconds() >= options_.progress_interval_seconds) {
    since_progress_.Restart();
    options_.progress(ShadeProgress{done, receivers_.size()});
  }
}

void ShadeEngine::AddDone(uint64_t n) { MaybeReportProgress(done_.fetch_add(n) + n); }

absl::Status ShadeEngine::Shade(absl::Span<const uint32_t> indices, float* distance) {
  PBGI_RETURN_IF_ERROR(status());
  std::vector<uint32_t> order;
  if (options_.z_order) {
    order = MortonOrder(indices.size(), [&](size_t k) { return receivers_[indices[k]].position; });
    for (uint32_t& k : order) k = indices[k];
  } else {
    order.assign(indices.begin(), indices.end());
  }
  // Blocks of consecutive Z-ordered receivers keep each thread's pages coherent; at most 64,
  // and small enough that every thread gets about 16 of them, so that a small batch does not
  // wait for one thread's last block (docs/query.md).
  const size_t grain = std::clamp<size_t>(order.size() / (16 * size_t(threads_)), 1, 64);
  arena_.execute([&] {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, order.size(), grain),
                      [&](const tbb::blocked_range<size_t>& range) {
                        if (failed_.load(std::memory_order_relaxed)) return;
                        if (!CheckCancel().ok()) return;
                        bool exists = false;
                        Worker& w = workers_->local(exists);
                        if (!exists) {
                          auto reader = db_.NewReader();
                          if (!reader.ok()) {
                            w.init = reader.status();
                          } else {
                            w.reader = std::move(reader).value();
                            w.init = w.buffer.Prepare(options_.raster.resolution);
                          }
                        }
                        if (!w.init.ok()) return Fail(w.init);
                        for (size_t k = range.begin(); k != range.end(); ++k) {
                          if (failed_.load(std::memory_order_relaxed)) return;
                          const uint32_t i = order[k];
                          const ShadeReceiver& sr = receivers_[i];
                          const Stopwatch t;
                          absl::Status s = w.reader->Gather({sr.position, sr.normal},
                                                            ReceiverCut(cut_, lobe_cut_, sr),
                                                            &w.gathered, &w.query);
                          const double gather = t.Seconds();
                          if (!s.ok()) return Fail(std::move(s));
                          s = pbgi::Shade(w.gathered, sr, options_.raster, &w.buffer, &out_[i]);
                          if (!s.ok()) {
                            return Fail(absl::Status(
                                s.code(), absl::StrFormat("receiver %d: %s", i, s.message())));
                          }
                          if (distance != nullptr) distance[i] = HarmonicDistance(w.buffer);
                          w.gather_seconds += gather;
                          w.raster_seconds += t.Seconds() - gather;
                        }
                        shaded_.fetch_add(range.size(), std::memory_order_relaxed);
                        AddDone(range.size());
                      });
  });
  return status();
}

ShadeStats ShadeEngine::Stats() {
  ShadeStats stats;
  stats.receivers = receivers_.size();
  stats.seconds = clock_.Seconds();
  stats.cpu_seconds = ProcessCpuSeconds() - cpu_start_;
  stats.shaded = shaded_.load();
  for (Worker& w : *workers_) {
    stats.query.Add(w.query);
    if (w.reader) stats.cache.Add(w.reader->stats());
    stats.gather_seconds += w.gather_seconds;
    stats.raster_seconds += w.raster_seconds;
  }
  return stats;
}

void ShadeEngine::ReportEnd() {
  if (options_.progress) options_.progress(ShadeProgress{receivers_.size(), receivers_.size()});
}

}  // namespace pbgi::internal
