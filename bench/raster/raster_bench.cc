// Time per receiver of the micro-buffer rasterizer, by resolution and element count, and the
// error that each resolution buys on the analytic disk (occlusion r^2 / (h^2 + r^2)).
//
//   out/raster/bench/raster/raster_bench --benchmark_min_time=0.2
#include <cmath>
#include <random>
#include <vector>

#include "benchmark/benchmark.h"
#include "pbgi/raster.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

using testing_raster::Aggregate;
using testing_raster::Clusters;
using testing_raster::DiskSurfels;

// `count` elements around a receiver at the origin (normal +z), half clusters and half
// surfels, in random directions of the upper hemisphere at distances 1..4, sized so that the
// hemisphere is covered about twice over (some depth complexity), all with radiance.
Gathered RandomScene(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g;
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  auto direction = [&] {
    glm::vec3 d;
    do {
      d = glm::vec3(g(rng), g(rng), g(rng));
    } while (glm::dot(d, d) < 1e-6f);
    d = glm::normalize(d);
    d.z = std::fabs(d.z) + 0.02f;
    return glm::normalize(d);
  };
  const float omega = 4.0f * static_cast<float>(testing_raster::kPi) / count;
  Gathered out;
  for (int i = 0; i < count; ++i) {
    const glm::vec3 d = direction();
    const float dist = 1.0f + 3.0f * u(rng);
    const glm::vec3 p = dist * d;
    const glm::vec3 normal = glm::normalize(-d + 0.3f * glm::vec3(g(rng), g(rng), g(rng)));
    const glm::vec3 radiance(u(rng), u(rng), u(rng));
    // Projected area omega * dist^2 split into 8 surfels (cluster) or one (surfel).
    const float area = omega * dist * dist;
    if (i % 2 == 0) {
      std::vector<Surfel> group;
      for (int k = 0; k < 8; ++k) {
        Surfel s;
        s.position = p + 0.3f * std::sqrt(area) * glm::vec3(g(rng), g(rng), g(rng));
        s.normal = glm::normalize(normal + 0.2f * glm::vec3(g(rng), g(rng), g(rng)));
        s.radius = std::sqrt(area / 8.0f / static_cast<float>(testing_raster::kPi));
        s.radiance = radiance;
        group.push_back(s);
      }
      out.clusters.push_back(Aggregate(group));
    } else {
      Surfel s;
      s.position = p;
      s.normal = normal;
      s.radius = std::sqrt(area / static_cast<float>(testing_raster::kPi));
      s.radiance = radiance;
      out.surfels.push_back(s);
    }
  }
  return out;
}

// Args: resolution, element count, mode (0 occlusion only, 1 radiance + glossy).
void BM_Shade(benchmark::State& state) {
  const int res = static_cast<int>(state.range(0));
  const int count = static_cast<int>(state.range(1));
  const bool radiance = state.range(2) != 0;
  const Gathered g = RandomScene(count, 42);
  RasterOptions o;
  o.resolution = res;
  o.compute_radiance = radiance;
  if (radiance) o.lobe = GlossyLobe::kPhong;
  MicroBuffer mb;
  ShadeReceiver r;
  r.reflection = glm::normalize(glm::vec3(1, 0, 1));
  ShadeResult out;
  double occ = 0.0;
  int i = 0;
  for (auto _ : state) {
    // Jitter the receiver a little so that no two calls are identical.
    r.position = glm::vec3(1e-3f * static_cast<float>(i++ % 7), 0.0f, 0.0f);
    if (!Shade(g, r, o, &mb, &out).ok()) state.SkipWithError("Shade failed");
    occ += out.occlusion;
    benchmark::DoNotOptimize(out);
  }
  state.counters["occlusion"] = occ / std::max<int64_t>(1, state.iterations());
  state.counters["near_disks"] = out.near_disks_drawn;
  state.counters["receivers/s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_Shade)
    ->ArgNames({"res", "elements", "radiance"})
    ->ArgsProduct({{4, 8, 12, 16, 32}, {100, 1000, 10000}, {0, 1}})
    ->Unit(benchmark::kMicrosecond);

// Error against the analytic form factor of a disk of radius 1 seen on its axis from height 1
// (0.5), over four copies of the disk whose surfel grid is turned about the axis (so that the
// error is not one lucky alignment with the pixels). Args: resolution, cut (0 fine: 7.8k
// surfels; 1 default: ~160 clusters aggregated from 0.15 x 0.15 tiles, each < 0.03 sr),
// cluster model (0 moments, 1 plain SH evaluation).
void BM_DiskAccuracy(benchmark::State& state) {
  const int res = static_cast<int>(state.range(0));
  const bool clusters = state.range(1) != 0;
  const bool sh_eval = state.range(2) != 0;
  std::vector<Gathered> scenes;
  for (int k = 0; k < 4; ++k) {
    const std::vector<Surfel> disk = testing_raster::Transform(
        DiskSurfels(glm::vec3(0.0f), glm::vec3(0, 0, -1), 1.0f, 0.02f),
        testing_raster::Rotation(glm::vec3(0, 0, 1), 0.2f * k), 1.0f, glm::vec3(0, 0, 1));
    Gathered g;
    if (clusters) {
      g.clusters = Clusters(disk, 0.15f);
    } else {
      g.surfels = disk;
    }
    scenes.push_back(std::move(g));
  }
  RasterOptions o;
  o.resolution = res;
  o.compute_radiance = false;
  if (sh_eval) o.cluster_model = ClusterModel::kShEval;
  MicroBuffer mb;
  ShadeReceiver r;
  ShadeResult out;
  double err = 0.0, max_err = 0.0;
  int64_t n = 0;
  for (auto _ : state) {
    const Gathered& g = scenes[n % scenes.size()];
    if (!Shade(g, r, o, &mb, &out).ok()) state.SkipWithError("Shade failed");
    const double e = std::fabs(out.occlusion - 0.5);
    err += e;
    max_err = std::max(max_err, e);
    ++n;
  }
  state.counters["elements"] = static_cast<double>(scenes[0].size());
  state.counters["mean_abs_err"] = err / std::max<int64_t>(1, n);
  state.counters["max_abs_err"] = max_err;
}
BENCHMARK(BM_DiskAccuracy)
    ->ArgNames({"res", "clusters", "sh_eval"})
    ->Apply([](benchmark::internal::Benchmark* b) {
      for (int res : {4, 8, 12, 16, 32, 64}) {
        b->Args({res, 0, 0});
        b->Args({res, 1, 0});
        b->Args({res, 1, 1});
      }
    })
    ->Unit(benchmark::kMicrosecond);

// A receiver on the floor 0.1 from a wall of surfels (pitch 0.05): the wall's nearest surfels
// are drawn as exact disks. Args: resolution, near_field_factor (0 = all far), samples.
void BM_NearField(benchmark::State& state) {
  const int res = static_cast<int>(state.range(0));
  Gathered g;
  g.surfels = DiskSurfels(glm::vec3(0.1f, 0, 1.0f), glm::vec3(-1, 0, 0), 1.0f, 0.05f);
  RasterOptions o;
  o.resolution = res;
  o.compute_radiance = false;
  o.near_field_factor = static_cast<float>(state.range(1));
  o.near_field_samples = static_cast<int>(state.range(2));
  MicroBuffer mb;
  ShadeReceiver r;
  ShadeResult out;
  for (auto _ : state) {
    if (!Shade(g, r, o, &mb, &out).ok()) state.SkipWithError("Shade failed");
    benchmark::DoNotOptimize(out);
  }
  state.counters["near_disks"] = out.near_disks_drawn;
  state.counters["occlusion"] = out.occlusion;
}
BENCHMARK(BM_NearField)
    ->ArgNames({"res", "factor", "samples"})
    ->Args({12, 0, 4})
    ->Args({12, 4, 4})
    ->Args({12, 4, 8})
    ->Args({12, 8, 4})
    ->Args({32, 0, 4})
    ->Args({32, 4, 4})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace pbgi

BENCHMARK_MAIN();
