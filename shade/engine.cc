// ShadeEngine (shade/engine.h).
#include "shade/engine.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_format.h"
#include "base/tsan_region.h"
#include "oneapi/tbb/blocked_range.h"
#include "oneapi/tbb/parallel_for.h"
#include "pbgi/sh.h"
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
  FarCut far_cut;        // far sharing: the group's far field
  FarBuffer far_buffer;  // and its rasterization
  QueryStats query;
  double gather_seconds = 0;
  double raster_seconds = 0;
  absl::Status init;
};

ShadeEngine::ShadeEngine(Database& db, absl::Span<const ShadeReceiver> receivers,
                         const ShadeOptions& options, const Cut& cut, absl::Span<ShadeResult> out)
    : db_(db),
      receivers_(receivers),
      options_(options),
      out_(out),
      threads_(options.threads > 0 ? options.threads : DefaultShadeThreads()),
      arena_(threads_),
      workers_(std::make_unique<tbb::enumerable_thread_specific<Worker>>()) {
  cut_ = cut;
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
    // The count as it stands now, read under the lock: the caller's own count can be older
    // than one another thread has reported meanwhile, and reports went backwards (205, then
    // 18: bug: progress_reported_out_of_order).
    options_.progress(ShadeProgress{std::max(done, done_.load()), receivers_.size()});
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
  if (options_.far_sharing.enabled) return ShadeGroups(order, distance);
  // Blocks of consecutive Z-ordered receivers keep each thread's pages coherent; at most 64,
  // and small enough that every thread gets about 16 of them, so that a small batch does not
  // wait for one thread's last block (docs/query.md).
  const size_t grain = std::clamp<size_t>(order.size() / (16 * size_t(threads_)), 1, 64);
  const TsanRegion region;
  arena_.execute([&] {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, order.size(), grain),
                      [&](const tbb::blocked_range<size_t>& range) {
                        const TsanRegion::Task task(region);
                        if (failed_.load(std::memory_order_relaxed)) return;
                        if (!CheckCancel().ok()) return;
                        Worker* w = LocalWorker();
                        if (w == nullptr) return;
                        for (size_t k = range.begin(); k != range.end(); ++k) {
                          if (failed_.load(std::memory_order_relaxed)) return;
                          if (!ShadeOne(*w, order[k], distance)) return;
                        }
                        shaded_.fetch_add(range.size(), std::memory_order_relaxed);
                        AddDone(range.size());
                      });
  });
  region.Joined();
  return status();
}

ShadeEngine::Worker* ShadeEngine::LocalWorker() {
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
  if (!w.init.ok()) {
    Fail(w.init);
    return nullptr;
  }
  return &w;
}

bool ShadeEngine::ShadeOne(Worker& w, uint32_t i, float* distance) {
  const ShadeReceiver& sr = receivers_[i];
  const Stopwatch t;
  absl::Status s = w.reader->Gather({sr.position, sr.normal}, ReceiverCut(cut_, lobe_cut_, sr),
                                    &w.gathered, &w.query);
  const double gather = t.Seconds();
  if (!s.ok()) {
    Fail(std::move(s));
    return false;
  }
  s = pbgi::Shade(w.gathered, sr, options_.raster, &w.buffer, &out_[i]);
  if (!s.ok()) {
    Fail(absl::Status(s.code(), absl::StrFormat("receiver %d: %s", i, s.message())));
    return false;
  }
  if (distance != nullptr) distance[i] = HarmonicDistance(w.buffer);
  w.gather_seconds += gather;
  w.raster_seconds += t.Seconds() - gather;
  return true;
}

absl::Status ShadeEngine::ShadeGroups(const std::vector<uint32_t>& order, float* distance) {
  const FarSharingOptions& f = options_.far_sharing;
  // The groups, made serially over the Z-ordered receivers so that they do not depend on the
  // thread count: group g is members[start[g], start[g + 1]).
  std::vector<uint32_t> members;
  members.reserve(order.size());
  std::vector<uint32_t> start;
  std::vector<uint8_t> taken(order.size(), 0);
  const float cos_max = std::cos(f.max_normal_angle_degrees * static_cast<float>(sh::kPi / 180.0));
  const float radius2 = f.max_radius * f.max_radius;
  const size_t window = 4 * static_cast<size_t>(f.max_members);
  for (size_t k = 0; k < order.size(); ++k) {
    if (taken[k]) continue;
    start.push_back(static_cast<uint32_t>(members.size()));
    taken[k] = 1;
    members.push_back(order[k]);
    const ShadeReceiver& a = receivers_[order[k]];
    const glm::vec3 na = glm::normalize(a.normal);
    int count = 1;
    for (size_t j = k + 1; j < order.size() && j <= k + window && count < f.max_members; ++j) {
      if (taken[j]) continue;
      const ShadeReceiver& b = receivers_[order[j]];
      const glm::vec3 d = b.position - a.position;
      if (glm::dot(d, d) > radius2 || glm::dot(na, glm::normalize(b.normal)) < cos_max) continue;
      taken[j] = 1;
      members.push_back(order[j]);
      ++count;
    }
  }
  start.push_back(static_cast<uint32_t>(members.size()));
  const size_t groups = start.size() - 1;
  const size_t grain = std::clamp<size_t>(groups / (16 * size_t(threads_)), 1, 16);
  const TsanRegion region;
  arena_.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, groups, grain), [&](const tbb::blocked_range<size_t>& range) {
          const TsanRegion::Task task(region);
          if (failed_.load(std::memory_order_relaxed)) return;
          if (!CheckCancel().ok()) return;
          Worker* wp = LocalWorker();
          if (wp == nullptr) return;
          Worker& w = *wp;
          size_t done = 0;
          for (size_t g = range.begin(); g != range.end(); ++g) {
            if (failed_.load(std::memory_order_relaxed)) return;
            const absl::Span<const uint32_t> m(members.data() + start[g], start[g + 1] - start[g]);
            done += m.size();
            if (m.size() == 1) {
              if (!ShadeOne(w, m[0], distance)) return;
              continue;
            }
            const glm::vec3 normal = glm::normalize(receivers_[m[0]].normal);
            glm::vec3 lo = receivers_[m[0]].position, hi = lo;
            for (uint32_t i : m) {
              lo = glm::min(lo, receivers_[i].position);
              hi = glm::max(hi, receivers_[i].position);
            }
            const glm::vec3 centre = 0.5f * (lo + hi);
            float radius = 0.0f, thickness = 0.0f;
            for (uint32_t i : m) {
              const glm::vec3 d = receivers_[i].position - centre;
              radius = std::max(radius, glm::length(d));
              thickness = std::max(thickness, std::fabs(glm::dot(normal, d)));
            }
            thickness = std::min(thickness, radius);
            const Stopwatch t;
            absl::Status s = w.reader->GatherFar({centre, radius, normal, thickness}, cut_,
                                                 f.distance_factor, &w.far_cut, &w.query);
            double gather = t.Seconds();
            if (s.ok()) {
              s = ShadeFar(w.far_cut.far, ShadeReceiver{centre, normal, normal}, options_.raster,
                           &w.buffer, &w.far_buffer);
            }
            double raster = t.Seconds() - gather;
            for (size_t k = 0; k < m.size() && s.ok(); ++k) {
              const uint32_t i = m[k];
              const Stopwatch tm;
              s = w.reader->GatherNear(receivers_[i].position, cut_, w.far_cut, &w.gathered,
                                       &w.query);
              const double g1 = tm.Seconds();
              gather += g1;
              if (!s.ok()) break;
              s = ShadeWithFar(w.gathered, receivers_[i], w.far_buffer, options_.raster, &w.buffer,
                               &out_[i]);
              if (!s.ok()) {
                s = absl::Status(s.code(), absl::StrFormat("receiver %d: %s", i, s.message()));
                break;
              }
              if (distance != nullptr) distance[i] = HarmonicDistance(w.buffer);
              raster += tm.Seconds() - g1;
            }
            if (!s.ok()) return Fail(std::move(s));
            w.gather_seconds += gather;
            w.raster_seconds += raster;
            far_groups_.fetch_add(1, std::memory_order_relaxed);
            far_members_.fetch_add(m.size(), std::memory_order_relaxed);
          }
          shaded_.fetch_add(done, std::memory_order_relaxed);
          AddDone(done);
        });
  });
  region.Joined();
  return status();
}

ShadeStats ShadeEngine::Stats() {
  ShadeStats stats;
  stats.receivers = receivers_.size();
  stats.seconds = clock_.Seconds();
  stats.cpu_seconds = ProcessCpuSeconds() - cpu_start_;
  stats.shaded = shaded_.load();
  stats.far_groups = far_groups_.load();
  stats.far_members = far_members_.load();
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
