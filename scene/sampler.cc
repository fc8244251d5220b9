// The scene surfel sampler: a streaming SurfelSource that stratifies surfels over the area of a
// scene's instanced triangles and bakes direct light into them (docs/design.md, "Scenes").
//
// Counts per triangle come from systematic sampling along the cumulative area, measured in
// surfels (inside a triangle, SamplerOptions::placement says where they go): triangle i owns the
// surfels s with floor(C_i + u) <= s < floor(C_{i+1} + u), where C_i is the area before triangle i
// times count / total area and u is one offset per seed. The counts sum to the request exactly, a
// triangle gets its expected count rounded up or down, and which triangle owns surfel s is a binary
// search: any surfel can be made on its own, so chunks are generated in parallel and the stream is
// the same for any number of threads.
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <utility>

#include "absl/strings/str_format.h"
#include "base/tsan_region.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "scene/sample_math.h"
#include "scene/scene_index.h"
#include "tbb/blocked_range.h"
#include "tbb/parallel_for.h"
#include "tbb/parallel_reduce.h"
#include "tbb/task_group.h"

namespace pbgi {
namespace {

using internal::HashCombine;
using internal::SceneIndex;

constexpr int64_t kBlock = 2048;      // surfels per parallel task inside a chunk
constexpr double kNarrowWidth = 0.7;  // SceneSurfelSource::Narrow, in surfel spacings
// Placement::kPieces cuts a triangle into pieces when it holds at most this many surfels (or is
// narrow); a larger one keeps the rotated Hammersley set, as even as pieces' centres there and
// without their pairs (two halves of a square cell put their centres a third of a diagonal
// apart): the city's large quads were 5 % worse with pieces (docs/eval.md, Session 25).
constexpr uint64_t kMaxPieces = 32;

// The scene without its thin triangles (Material::thin): what the hidden-sample test traces, so
// that a leaf's back side never counts as the inside of a solid.
std::shared_ptr<const Scene> SolidPart(const Scene& scene) {
  bool any_thin = false;
  for (const Material& m : scene.materials) any_thin = any_thin || m.thin;
  if (!any_thin) return nullptr;
  auto solid = std::make_shared<Scene>();
  solid->name = scene.name + " (solid part)";
  solid->materials = scene.materials;
  solid->has_radiance = false;
  // Meshes [0, M) as they are (for instances whose override material is solid), then [M, 2M)
  // without their thin triangles.
  const uint32_t m_count = static_cast<uint32_t>(scene.meshes.size());
  solid->meshes = scene.meshes;
  for (const Mesh& m : scene.meshes) {
    Mesh f;
    f.positions = m.positions;
    for (size_t t = 0; t < m.triangles.size(); ++t) {
      if (scene.materials[m.materials[t]].thin) continue;
      f.triangles.push_back(m.triangles[t]);
      f.materials.push_back(m.materials[t]);
    }
    solid->meshes.push_back(std::move(f));
  }
  for (const Instance& in : scene.instances) {
    if (in.material >= 0) {
      if (!scene.materials[static_cast<size_t>(in.material)].thin) {
        solid->instances.push_back(in);
      }
    } else {
      Instance f = in;
      f.mesh += m_count;
      solid->instances.push_back(f);
    }
  }
  return solid;
}

class SceneSurfelSource final : public SurfelSource {
 public:
  SceneSurfelSource(std::shared_ptr<const Scene> scene, std::unique_ptr<Tracer> tracer,
                    const SamplerOptions& options)
      : scene_(std::move(scene)),
        tracer_(std::move(tracer)),
        index_(*scene_),
        options_(options),
        bake_(options.bake && scene_->has_radiance) {}

  ~SceneSurfelSource() override {
    pending_->wait();
    prefetch_region_.Joined();
  }

  // Builds the cumulative area table, runs the pilot pass for hidden samples; returns an error
  // when the request cannot be met.
  absl::Status Init() {
    const int64_t tris = index_.triangle_count();
    area_.resize(static_cast<size_t>(tris) + 1);
    double area = 0.0;
    area_[0] = 0.0;
    for (uint32_t i = 0; i < scene_->instances.size(); ++i) {
      const int64_t first = index_.instance_first()[i];
      const int64_t n = index_.instance_first()[i + 1] - first;
      for (int64_t t = 0; t < n; ++t) {
        area += index_.Triangle(i, static_cast<uint32_t>(t)).Area();
        area_[first + t + 1] = area;
      }
    }
    total_area_ = area;
    if (options_.count < 0 || options_.density < 0.0) {
      return absl::InvalidArgumentError(
          absl::StrFormat("scene '%s': negative surfel count or density requested", scene_->name));
    }
    if (options_.count == 0 && !(options_.density > 0.0)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("scene '%s': give a surfel count or a density", scene_->name));
    }
    if (options_.chunk_size <= 0) {
      return absl::InvalidArgumentError("sampler chunk size must be positive");
    }
    int64_t request = options_.count > 0 ? options_.count : std::llround(area * options_.density);
    if (request > 0 && !(area > 0.0)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "scene '%s' has no surface area to put %d surfels on", scene_->name, request));
    }
    // The pilot: which fraction of the area is visible (not inside solid geometry)?
    visible_fraction_ = 1.0;
    if (options_.drop_hidden && request > 0) {
      PBGI_RETURN_IF_ERROR(Pilot(request));
      if (options_.count == 0) request = std::llround(area * visible_fraction_ * options_.density);
    }
    request_ = request;
    // Candidates: as many as make `request` visible ones at a uniform density.
    count_ = test_hidden_ ? std::max<int64_t>(
                                1, std::llround(static_cast<double>(request) / visible_fraction_))
                          : request;
    if (request == 0) count_ = 0;
    layout_ = MakeLayout(count_, options_.seed, options_.placement);
    area_per_surfel_ = count_ > 0 ? area / static_cast<double>(count_) : 0.0;
    radius_ = static_cast<float>(std::sqrt(area_per_surfel_ / sh::kPi));
    const size_t chunk = static_cast<size_t>(std::min(options_.chunk_size, count_));
    for (auto& b : buffers_) b.resize(chunk);
    for (auto& k : keep_) k.resize(test_hidden_ ? chunk : 0);
    return Rewind();
  }

  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    size_t written = 0;
    while (written < out.size()) {
      if (pos_ == size_) {
        if (end_ >= count_) break;
        pending_->wait();
        prefetch_region_.Joined();
        std::swap(buffers_[0], buffers_[1]);
        end_ = next_end_;
        size_ = next_size_;
        pos_ = 0;
        Prefetch(end_);
        continue;
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
    prefetch_region_.Joined();
    end_ = 0;
    size_ = 0;
    pos_ = 0;
    Prefetch(0);
    return absl::OkStatus();
  }

  Bounds KnownBounds() const override { return index_.bounds(); }
  int64_t KnownCount() const override { return test_hidden_ ? -1 : count_; }
  bool HasRadiance() const override { return bake_; }

  int64_t candidates() const { return count_; }
  double visible_fraction() const { return visible_fraction_; }

 private:
  // Where the candidates of a stream of `count` go: the cumulative area measured in candidates
  // (C_g = area_[g] * scale, the last one exactly `count`) and the systematic offset u.
  struct Layout {
    int64_t count = 0;
    double scale = 0.0;
    double offset = 0.0;
    uint64_t seed = 0;
    SamplerOptions::Placement placement = SamplerOptions::Placement::kUniform;
  };

  Layout MakeLayout(int64_t count, uint64_t seed, SamplerOptions::Placement placement) const {
    Layout l;
    l.placement = placement;
    l.count = count;
    l.scale = count > 0 ? static_cast<double>(count) / total_area_ : 0.0;
    l.offset = internal::ToUnitFloat(HashCombine(seed, 0x6f6666u));
    l.seed = seed;
    return l;
  }

  // C_g of a layout.
  double Cumulative(const Layout& l, int64_t g) const {
    if (g >= index_.triangle_count()) return static_cast<double>(l.count);
    return std::min(area_[g] * l.scale, static_cast<double>(l.count));
  }

  // First candidate owned by triangle g: floor(C_g + u).
  int64_t FirstOf(const Layout& l, int64_t g) const {
    return static_cast<int64_t>(std::floor(Cumulative(l, g) + l.offset));
  }

  // Estimates the visible fraction of the area from a stratified pilot sample of up to 2^17
  // points with its own seed; decides whether the stream tests its candidates at all.
  absl::Status Pilot(int64_t request) {
    const std::shared_ptr<const Scene> solid = SolidPart(*scene_);
    if (solid != nullptr) {
      solid_scene_ = solid;
      PBGI_ASSIGN_OR_RETURN(solid_tracer_, Tracer::Create(*solid_scene_));
    }
    const int64_t m = std::clamp<int64_t>(request, int64_t{1} << 14, int64_t{1} << 17);
    // Uniform placement: the pilot estimates a fraction of the area, so its points must be
    // equally likely anywhere, not only at pieces' centres.
    const Layout pilot =
        MakeLayout(m, HashCombine(options_.seed, 0x70696c6fu), SamplerOptions::Placement::kUniform);
    std::vector<Surfel> s(static_cast<size_t>(m));
    std::vector<uint32_t> mats(static_cast<size_t>(m));
    const internal::TsanRegion region;
    const int64_t visible = tbb::parallel_reduce(
        tbb::blocked_range<int64_t>(0, m, kBlock), int64_t{0},
        [&](const tbb::blocked_range<int64_t>& r, int64_t acc) {
          const internal::TsanRegion::Task task(region);
          Place(pilot, r.begin(), r.end(), s.data() + r.begin(), mats.data() + r.begin());
          for (int64_t i = r.begin(); i < r.end(); ++i) acc += Hidden(s[i]) ? 0 : 1;
          return acc;
        },
        std::plus<int64_t>(), tbb::simple_partitioner());
    region.Joined();
    if (visible == 0) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "scene '%s': all %d pilot samples lie inside solid geometry (back faces all round); "
          "use keep-hidden sampling",
          scene_->name, m));
    }
    test_hidden_ = visible < m;
    visible_fraction_ = static_cast<double>(visible) / static_cast<double>(m);
    return absl::OkStatus();
  }

  // Whether a sample lies inside solid geometry: the ray along its normal first meets the back
  // of a (non-thin) face.
  bool Hidden(const Surfel& s) const {
    const Tracer& t = solid_tracer_ ? *solid_tracer_ : *tracer_;
    const Hit h = t.Intersect(s.position + t.epsilon() * s.normal, s.normal,
                              std::numeric_limits<float>::infinity());
    return h.hit && !h.front;
  }

  // Starts generating candidates [first, first + chunk) into buffers_[1] in the background and
  // compacting the visible ones to its front.
  void Prefetch(int64_t first) {
    next_end_ = first + std::max<int64_t>(0, std::min(options_.chunk_size, count_ - first));
    next_size_ = next_end_ - first;
    if (next_size_ == 0) return;
    prefetch_region_.Fork();
    pending_->run([this, first] {
      const internal::TsanRegion::Task task(prefetch_region_);
      const int64_t n = next_end_ - first;
      Surfel* dst = buffers_[1].data();
      uint8_t* keep = test_hidden_ ? keep_[1].data() : nullptr;
      // simple_partitioner: the same blocks for any thread count.
      const internal::TsanRegion blocks;
      tbb::parallel_for(
          tbb::blocked_range<int64_t>(0, n, kBlock),
          [&](const tbb::blocked_range<int64_t>& r) {
            const internal::TsanRegion::Task block(blocks);
            Generate(first + r.begin(), first + r.end(), dst + r.begin(),
                     keep ? keep + r.begin() : nullptr);
          },
          tbb::simple_partitioner());
      blocks.Joined();
      if (keep != nullptr) {
        int64_t kept = 0;
        for (int64_t i = 0; i < n; ++i) {
          if (keep[i]) dst[kept++] = dst[i];
        }
        next_size_ = kept;
      }
    });
  }

  // A triangle narrower across its longest edge than kNarrowWidth surfel spacings: its samples go
  // along it (internal::StripPoint), as the pieces of a strip that narrow are slivers whose
  // centres sit a third of their length from their ends (a trunk's lowest centres left a gap
  // above the ground that the contact rule does not close).
  bool Narrow(const internal::WorldTriangle& w) const {
    const glm::dvec3 a(w.a), b(w.b), c(w.c);
    const double l2 =
        std::max({glm::dot(b - a, b - a), glm::dot(c - b, c - b), glm::dot(a - c, a - c)});
    const glm::dvec3 x = glm::cross(b - a, c - a);  // |x| / l: the width across the longest edge
    return l2 > 0.0 && glm::dot(x, x) < kNarrowWidth * kNarrowWidth * area_per_surfel_ * l2;
  }

  // Candidates [begin, end) of layout l, in order, with their materials: positions and normals.
  void Place(const Layout& l, int64_t begin, int64_t end, Surfel* out, uint32_t* materials) const {
    // The triangle of `begin`: the last g with floor(C_g + u) <= begin, i.e. C_g < begin+1-u.
    const double key = static_cast<double>(begin) + 1.0 - l.offset;
    const int64_t tris = index_.triangle_count();
    int64_t lo = 0, hi = tris + 1;  // first g in [0, T] with C_g >= key
    while (lo < hi) {
      const int64_t mid = lo + (hi - lo) / 2;
      if (Cumulative(l, mid) < key) {
        lo = mid + 1;
      } else {
        hi = mid;
      }
    }
    int64_t g = lo - 1;
    uint32_t inst = index_.InstanceOf(g);
    int64_t tri_first = 0, tri_end = -1;
    internal::WorldTriangle w{};
    glm::vec3 normal(0.0f);
    uint32_t material = 0;
    bool thin = false;
    uint8_t sheet = 0;
    float r0 = 0.0f, r1 = 0.0f;
    uint64_t k = 0;  // the triangle's surfel count
    enum class How { kHammersley, kStrip, kPieces } how = How::kHammersley;
    for (int64_t s = begin; s < end; ++s) {
      if (s >= tri_end) {
        if (tri_end >= 0) ++g;
        tri_first = FirstOf(l, g);
        tri_end = FirstOf(l, g + 1);
        while (tri_end <= s && g + 1 < tris) {  // triangles that own no surfel
          ++g;
          tri_first = tri_end;
          tri_end = FirstOf(l, g + 1);
        }
        while (index_.instance_first()[inst + 1] <= g) ++inst;
        const uint32_t t = static_cast<uint32_t>(g - index_.instance_first()[inst]);
        w = index_.Triangle(inst, t);
        normal = glm::normalize(w.Cross());
        material = index_.MaterialOf(inst, t);
        // A thin sheet's surfels are two-sided: its back is the sheet's other side.
        thin = material < scene_->materials.size() && scene_->materials[material].thin;
        sheet = index_.SheetOf(inst, t);
        const uint64_t tk = HashCombine(l.seed, static_cast<uint64_t>(g));
        r0 = internal::Random(tk, 0);
        r1 = internal::Random(tk, 1);
        k = static_cast<uint64_t>(tri_end - tri_first);
        how = How::kHammersley;
        if (l.placement == SamplerOptions::Placement::kPieces) {
          if (k >= 2 && Narrow(w)) {
            how = How::kStrip;
          } else if (k <= kMaxPieces) {
            how = How::kPieces;
          }
        }
      }
      Surfel& sf = out[s - begin];
      const uint64_t j = static_cast<uint64_t>(s - tri_first);
      switch (how) {
        case How::kHammersley:
          sf.position =
              internal::TrianglePoint(w.a, w.b, w.c, internal::RotatedHammersley(j, k, r0, r1));
          break;
        case How::kStrip:
          sf.position = internal::StripPoint(w.a, w.b, w.c, j, k);
          break;
        case How::kPieces:
          sf.position = internal::EqualAreaPiecePoint(w.a, w.b, w.c, j, k);
          break;
      }
      sf.normal = normal;
      sf.radius = radius_;
      sf.radiance = glm::vec3(0.0f);
      sf.back_radiance = glm::vec3(0.0f);
      sf.two_sided = thin;
      sf.sheet = sheet;
      materials[s - begin] = material;
    }
  }

  // Candidates [begin, end) of the stream in order; keep[i] says whether candidate begin + i is
  // visible (when hidden samples are tested), and only visible ones are baked.
  void Generate(int64_t begin, int64_t end, Surfel* out, uint8_t* keep) const {
    std::vector<uint32_t> materials(static_cast<size_t>(end - begin));
    Place(layout_, begin, end, out, materials.data());
    if (keep != nullptr) {
      for (int64_t i = 0; i < end - begin; ++i) keep[i] = Hidden(out[i]) ? 0 : 1;
    }
    if (bake_) Bake(begin, end, out, materials.data(), keep);
  }

  // Bakes radiance in groups of candidates [16q, 16q + 16) (global numbers): a group shares its
  // light samples' shift, keyed by q, and each candidate's slot is its number less 16q, so a
  // group split between two calls still gets the same samples, and a dropped candidate changes
  // nobody else's light.
  void Bake(int64_t begin, int64_t end, Surfel* out, const uint32_t* materials,
            const uint8_t* keep) const {
    constexpr int64_t kP = Tracer::kGroup;
    glm::vec3 p[kP], n[kP], l[kP];
    uint32_t m[kP];
    uint8_t slot[kP];
    int64_t at[kP];
    for (int64_t first = begin; first < end;) {
      const int64_t q = first / kP;
      const int64_t last = std::min(end, (q + 1) * kP);
      int count = 0;
      for (int64_t s = first; s < last; ++s) {
        const int64_t i = s - begin;
        if (keep != nullptr && !keep[i]) continue;
        p[count] = out[i].position;
        n[count] = out[i].normal;
        m[count] = materials[i];
        slot[count] = static_cast<uint8_t>(s - q * kP);
        at[count] = i;
        ++count;
      }
      if (count > 0) {
        tracer_->SurfaceRadiance(absl::MakeConstSpan(p, count), absl::MakeConstSpan(n, count),
                                 absl::MakeConstSpan(m, count),
                                 HashCombine(options_.seed ^ 0x62616b65u, static_cast<uint64_t>(q)),
                                 absl::MakeSpan(l, count), absl::MakeConstSpan(slot, count));
      }
      for (int i = 0; i < count; ++i) out[at[i]].radiance = l[i];
      // A two-sided surfel's back is lit from its own side, without emission, as the reference
      // shades a thin sheet's back (Tracer::ReferenceIrradiance); its own group of samples.
      int backs = 0;
      for (int i = 0; i < count; ++i) {
        if (!out[at[i]].two_sided) continue;
        p[backs] = p[i];
        n[backs] = -n[i];
        m[backs] = m[i];
        slot[backs] = slot[i];
        at[backs] = at[i];
        ++backs;
      }
      if (backs > 0) {
        tracer_->SurfaceRadiance(absl::MakeConstSpan(p, backs), absl::MakeConstSpan(n, backs),
                                 absl::MakeConstSpan(m, backs),
                                 HashCombine(options_.seed ^ 0x6b636162u, static_cast<uint64_t>(q)),
                                 absl::MakeSpan(l, backs), absl::MakeConstSpan(slot, backs));
        for (int i = 0; i < backs; ++i) {
          out[at[i]].back_radiance = l[i] - scene_->materials[m[i]].emission;
        }
      }
      first = last;
    }
  }

  std::shared_ptr<const Scene> scene_;
  std::unique_ptr<Tracer> tracer_;
  // The scene without thin triangles and its tracer, when the scene has thin materials.
  std::shared_ptr<const Scene> solid_scene_;
  std::unique_ptr<Tracer> solid_tracer_;
  SceneIndex index_;
  SamplerOptions options_;
  bool bake_;
  std::vector<double> area_;  // cumulative area per triangle boundary
  double total_area_ = 0.0;
  double area_per_surfel_ = 0.0;
  double visible_fraction_ = 1.0;
  bool test_hidden_ = false;
  float radius_ = 0.0f;
  int64_t request_ = 0;
  int64_t count_ = 0;  // candidates
  Layout layout_;

  // buffers_[0] is being served, buffers_[1] is being filled by `pending_`; keep_ likewise.
  std::vector<Surfel> buffers_[2];
  std::vector<uint8_t> keep_[2];
  int64_t end_ = 0, size_ = 0, pos_ = 0;  // candidates before end_ are done; size_ surfels kept
  int64_t next_end_ = 0, next_size_ = 0;
  // Held by pointer: tbb::task_group's destructor may throw, which SurfelSource's may not.
  std::unique_ptr<tbb::task_group> pending_ = std::make_unique<tbb::task_group>();
  // The edges between this thread and the prefetch task, which TSan cannot see in libtbb.
  internal::TsanRegion prefetch_region_;
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
