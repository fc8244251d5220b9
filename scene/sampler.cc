// The scene surfel sampler: a streaming SurfelSource that stratifies surfels over the area of a
// scene's instanced triangles and bakes direct light into them (DESIGN.md, "Scenes").
//
// Counts per triangle come from systematic sampling along the cumulative area, measured in
// surfels: triangle i owns the surfels s with floor(C_i + u) <= s < floor(C_{i+1} + u), where
// C_i is the area before triangle i times count / total area and u is one offset per seed. The
// counts sum to the request exactly, a triangle gets its expected count rounded up or down, and
// which triangle owns surfel s is a binary search: any surfel can be made on its own, so chunks
// are generated in parallel and the stream is the same for any number of threads.
#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_format.h"
#include "pbgi/scene.h"
#include "scene/sample_math.h"
#include "scene/scene_index.h"
#include "tbb/blocked_range.h"
#include "tbb/parallel_for.h"
#include "tbb/task_group.h"

namespace pbgi {
namespace {

using internal::HashCombine;
using internal::SceneIndex;

constexpr int64_t kBlock = 2048;  // surfels per parallel task inside a chunk

class SceneSurfelSource final : public SurfelSource {
 public:
  SceneSurfelSource(std::shared_ptr<const Scene> scene, std::unique_ptr<Tracer> tracer,
                    const SamplerOptions& options)
      : scene_(std::move(scene)),
        tracer_(std::move(tracer)),
        index_(*scene_),
        options_(options),
        bake_(options.bake && scene_->has_radiance) {}

  ~SceneSurfelSource() override { pending_->wait(); }

  // Builds the cumulative area table; returns an error when the request cannot be met.
  absl::Status Init() {
    const int64_t tris = index_.triangle_count();
    cumulative_.resize(static_cast<size_t>(tris) + 1);
    double area = 0.0;
    cumulative_[0] = 0.0;
    for (uint32_t i = 0; i < scene_->instances.size(); ++i) {
      const int64_t first = index_.instance_first()[i];
      const int64_t n = index_.instance_first()[i + 1] - first;
      for (int64_t t = 0; t < n; ++t) {
        area += index_.Triangle(i, static_cast<uint32_t>(t)).Area();
        cumulative_[first + t + 1] = area;
      }
    }
    total_area_ = area;
    if (options_.count > 0) {
      count_ = options_.count;
    } else if (options_.density > 0.0) {
      count_ = std::llround(area * options_.density);
    } else if (options_.count < 0 || options_.density < 0.0) {
      return absl::InvalidArgumentError(
          absl::StrFormat("scene '%s': negative surfel count or density requested", scene_->name));
    } else {
      return absl::InvalidArgumentError(
          absl::StrFormat("scene '%s': give a surfel count or a density", scene_->name));
    }
    if (count_ > 0 && !(area > 0.0)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "scene '%s' has no surface area to put %d surfels on", scene_->name, count_));
    }
    if (options_.chunk_size <= 0) {
      return absl::InvalidArgumentError("sampler chunk size must be positive");
    }
    // Measure the cumulative area in surfels, with the last entry exactly the count so that
    // floor(C_T + u) == count.
    const double scale = count_ > 0 ? static_cast<double>(count_) / area : 0.0;
    for (double& c : cumulative_) c = std::min(c * scale, static_cast<double>(count_));
    cumulative_.back() = static_cast<double>(count_);
    offset_ = internal::ToUnitFloat(HashCombine(options_.seed, 0x6f6666u));
    area_per_surfel_ = count_ > 0 ? area / static_cast<double>(count_) : 0.0;
    radius_ = static_cast<float>(std::sqrt(area_per_surfel_ / 3.14159265358979323846));
    for (auto& b : buffers_) b.resize(static_cast<size_t>(std::min(options_.chunk_size, count_)));
    return Rewind();
  }

  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    size_t written = 0;
    while (written < out.size()) {
      if (pos_ == size_) {
        if (first_ + size_ >= count_) break;
        pending_->wait();
        std::swap(buffers_[0], buffers_[1]);
        first_ = next_first_;
        size_ = next_size_;
        pos_ = 0;
        Prefetch(first_ + size_);
      }
      size_t n = std::min(out.size() - written, static_cast<size_t>(size_ - pos_));
      std::copy_n(buffers_[0].begin() + pos_, n, out.begin() + written);
      pos_ += static_cast<int64_t>(n);
      written += n;
    }
    return written;
  }

  absl::Status Rewind() override {
    pending_->wait();
    first_ = 0;
    size_ = 0;
    pos_ = 0;
    Prefetch(0);
    return absl::OkStatus();
  }

  Bounds KnownBounds() const override { return index_.bounds(); }
  int64_t KnownCount() const override { return count_; }
  bool HasRadiance() const override { return bake_; }

 private:
  // Starts generating surfels [first, first + chunk) into buffers_[1] in the background.
  void Prefetch(int64_t first) {
    next_first_ = first;
    next_size_ = std::max<int64_t>(0, std::min(options_.chunk_size, count_ - first));
    if (next_size_ == 0) return;
    pending_->run([this] {
      const int64_t n = next_size_;
      const int64_t base = next_first_;
      Surfel* dst = buffers_[1].data();
      // simple_partitioner: the same blocks for any thread count.
      tbb::parallel_for(
          tbb::blocked_range<int64_t>(0, n, kBlock),
          [&](const tbb::blocked_range<int64_t>& r) {
            Generate(base + r.begin(), base + r.end(), dst + r.begin());
          },
          tbb::simple_partitioner());
    });
  }

  // First surfel owned by triangle g: floor(C_g + u).
  int64_t FirstOf(int64_t g) const {
    return static_cast<int64_t>(std::floor(cumulative_[g] + offset_));
  }

  // Surfels [begin, end) in order.
  void Generate(int64_t begin, int64_t end, Surfel* out) const {
    // The triangle of `begin`: the last g with floor(C_g + u) <= begin, i.e. C_g < begin+1-u.
    const double key = static_cast<double>(begin) + 1.0 - offset_;
    int64_t g =
        (std::lower_bound(cumulative_.begin(), cumulative_.end(), key) - cumulative_.begin()) - 1;
    const int64_t tris = index_.triangle_count();
    uint32_t inst = index_.InstanceOf(g);
    int64_t tri_first = 0, tri_end = -1;
    internal::WorldTriangle w{};
    glm::vec3 normal(0.0f);
    uint32_t material = 0;
    float r0 = 0.0f, r1 = 0.0f;
    std::vector<uint32_t> materials(bake_ ? static_cast<size_t>(end - begin) : 0);
    for (int64_t s = begin; s < end; ++s) {
      if (s >= tri_end) {
        if (tri_end >= 0) ++g;
        tri_first = FirstOf(g);
        tri_end = FirstOf(g + 1);
        while (tri_end <= s && g + 1 < tris) {  // triangles that own no surfel
          ++g;
          tri_first = tri_end;
          tri_end = FirstOf(g + 1);
        }
        while (index_.instance_first()[inst + 1] <= g) ++inst;
        const uint32_t t = static_cast<uint32_t>(g - index_.instance_first()[inst]);
        w = index_.Triangle(inst, t);
        normal = glm::normalize(w.Cross());
        material = index_.MaterialOf(inst, t);
        const uint64_t tk = HashCombine(options_.seed, static_cast<uint64_t>(g));
        r0 = internal::Random(tk, 0);
        r1 = internal::Random(tk, 1);
      }
      Surfel& sf = out[s - begin];
      const uint64_t j = static_cast<uint64_t>(s - tri_first);
      const uint64_t k = static_cast<uint64_t>(tri_end - tri_first);
      sf.position =
          internal::TrianglePoint(w.a, w.b, w.c, internal::RotatedHammersley(j, k, r0, r1));
      sf.normal = normal;
      sf.radius = radius_;
      sf.radiance = glm::vec3(0.0f);
      if (bake_) materials[s - begin] = material;
    }
    if (bake_) Bake(begin, end, out, materials.data());
  }

  // Bakes radiance in groups of surfels [16q, 16q + 16) (global numbers): a group shares its
  // light samples, keyed by q, so a group split between two calls still gets the same ones.
  void Bake(int64_t begin, int64_t end, Surfel* out, const uint32_t* materials) const {
    constexpr int64_t kP = Tracer::kGroup;
    glm::vec3 p[kP], n[kP], l[kP];
    for (int64_t first = begin; first < end;) {
      const int64_t q = first / kP;
      const int64_t last = std::min(end, (q + 1) * kP);
      const int count = static_cast<int>(last - first);
      for (int i = 0; i < count; ++i) {
        p[i] = out[first - begin + i].position;
        n[i] = out[first - begin + i].normal;
      }
      tracer_->SurfaceRadiance(absl::MakeConstSpan(p, count), absl::MakeConstSpan(n, count),
                               absl::MakeConstSpan(materials + (first - begin), count),
                               HashCombine(options_.seed ^ 0x62616b65u, static_cast<uint64_t>(q)),
                               absl::MakeSpan(l, count));
      for (int i = 0; i < count; ++i) out[first - begin + i].radiance = l[i];
      first = last;
    }
  }

  std::shared_ptr<const Scene> scene_;
  std::unique_ptr<Tracer> tracer_;
  SceneIndex index_;
  SamplerOptions options_;
  bool bake_;
  std::vector<double> cumulative_;  // per triangle boundary, in surfels
  double total_area_ = 0.0;
  double area_per_surfel_ = 0.0;
  double offset_ = 0.0;
  float radius_ = 0.0f;
  int64_t count_ = 0;

  // buffers_[0] is being served, buffers_[1] is being filled by `pending_`.
  std::vector<Surfel> buffers_[2];
  int64_t first_ = 0, size_ = 0, pos_ = 0;
  int64_t next_first_ = 0, next_size_ = 0;
  // Held by pointer: tbb::task_group's destructor may throw, which SurfelSource's may not.
  std::unique_ptr<tbb::task_group> pending_ = std::make_unique<tbb::task_group>();
};

}  // namespace

absl::StatusOr<std::unique_ptr<SurfelSource>> MakeSceneSurfelSource(
    std::shared_ptr<const Scene> scene, const SamplerOptions& options) {
  if (scene == nullptr) return absl::InvalidArgumentError("MakeSceneSurfelSource: no scene");
  auto tracer = Tracer::Create(*scene);
  if (!tracer.ok()) return tracer.status();
  auto source = std::make_unique<SceneSurfelSource>(std::move(scene), *std::move(tracer), options);
  absl::Status s = source->Init();
  if (!s.ok()) return s;
  return std::unique_ptr<SurfelSource>(std::move(source));
}

}  // namespace pbgi
