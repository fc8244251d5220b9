// Surfel generation rate (points/s, with direct light baked) per procedural scene, and the
// reference integrator's ray rate. The builder consumes about 2 M points/s: generation should
// stay faster than that so that it is never the bottleneck of `pbgi generate | build`.
#include <ctime>
#include <memory>
#include <string>
#include <vector>

#include "benchmark/benchmark.h"
#include "pbgi/scene.h"

namespace pbgi {
namespace {

const char* const kScenes[] = {"cornell", "city", "forest", "sphere-in-box"};

void BM_Generate(benchmark::State& state) {
  const std::string name = kScenes[state.range(0)];
  const int64_t count = state.range(1);
  const bool bake = state.range(2) != 0;
  const bool drop_hidden = state.range(3) != 0;
  auto scene = MakeScene(name);
  if (!scene.ok()) {
    state.SkipWithError(std::string(scene.status().message()).c_str());
    return;
  }
  auto shared = std::make_shared<Scene>(*std::move(scene));
  std::vector<Surfel> buf(1 << 16);
  // Process CPU time (all threads): on a shared machine, points per CPU-second times the cores
  // one has is a steadier figure than wall-clock rate.
  const std::clock_t cpu0 = std::clock();
  int64_t total = 0;  // surfels made (with drop_hidden, within 1% of the request)
  for (auto _ : state) {
    SamplerOptions o;
    o.count = count;
    o.bake = bake;
    o.drop_hidden = drop_hidden;
    auto source = MakeSceneSurfelSource(shared, o);
    if (!source.ok()) {
      state.SkipWithError(std::string(source.status().message()).c_str());
      return;
    }
    int64_t got = 0;
    for (;;) {
      auto n = (*source)->Next(absl::MakeSpan(buf));
      if (!n.ok() || *n == 0) break;
      got += static_cast<int64_t>(*n);
    }
    benchmark::DoNotOptimize(got);
    total += got;
  }
  const double cpu = static_cast<double>(std::clock() - cpu0) / CLOCKS_PER_SEC;
  const double points = static_cast<double>(total);
  state.SetLabel(name + (bake ? " baked" : " geometry") + (drop_hidden ? " drop-hidden" : ""));
  state.counters["points/s"] = benchmark::Counter(points, benchmark::Counter::kIsRate);
  state.counters["points/cpu_s"] = points / cpu;
}
BENCHMARK(BM_Generate)
    ->ArgNames({"scene", "count", "bake", "drop_hidden"})
    ->ArgsProduct({{0, 1, 2, 3}, {1 << 20}, {0, 1}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_ReferenceOcclusion(benchmark::State& state) {
  auto scene = MakeScene(kScenes[state.range(0)]);
  auto tracer = Tracer::Create(*scene);
  if (!tracer.ok()) {
    state.SkipWithError(std::string(tracer.status().message()).c_str());
    return;
  }
  // Receivers on the scene's own surfaces.
  SamplerOptions o;
  o.count = 4096;
  o.bake = false;
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(*scene), o);
  std::vector<Surfel> s(4096);
  auto n = (*source)->Next(absl::MakeSpan(s));
  std::vector<Receiver> receivers;
  for (size_t i = 0; i < *n; ++i) receivers.push_back({s[i].position, s[i].normal});
  const int rays = static_cast<int>(state.range(1));
  const std::clock_t cpu0 = std::clock();
  for (auto _ : state) {
    auto occ = (*tracer)->ReferenceOcclusion(receivers, rays, 1e30f);
    benchmark::DoNotOptimize(occ.data());
  }
  const double cpu = static_cast<double>(std::clock() - cpu0) / CLOCKS_PER_SEC;
  const double total =
      static_cast<double>(receivers.size()) * rays * static_cast<double>(state.iterations());
  state.SetLabel(kScenes[state.range(0)]);
  state.counters["rays/s"] = benchmark::Counter(total, benchmark::Counter::kIsRate);
  state.counters["rays/cpu_s"] = total / cpu;
}
BENCHMARK(BM_ReferenceOcclusion)
    ->ArgsProduct({{0, 1, 2}, {256}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// One receiver's rays as single rays (rtcOccluded1, what the reference uses) or as 16-wide
// packets (rtcOccluded16), on one thread, same receivers and rays: is the reference as fast as
// Embree can make it?
void BM_ReferenceRayKind(benchmark::State& state) {
  auto scene = MakeScene(kScenes[state.range(0)]);
  auto tracer = Tracer::Create(*scene);
  if (!tracer.ok()) {
    state.SkipWithError(std::string(tracer.status().message()).c_str());
    return;
  }
  SamplerOptions o;
  o.count = 1024;
  o.bake = false;
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(*scene), o);
  std::vector<Surfel> s(2048);
  auto n = (*source)->Next(absl::MakeSpan(s));
  const int rays = static_cast<int>(state.range(1));
  const bool packets = state.range(2) != 0;
  const Tracer& t = **tracer;
  double sum = 0.0;
  for (auto _ : state) {
    for (size_t i = 0; i < *n; ++i) {
      const glm::vec3 p = s[i].position + t.epsilon() * s[i].normal;
      sum += packets ? t.ReferenceOcclusionPackets(p, s[i].normal, rays, 1e30f, i)
                     : t.ReferenceOcclusion(p, s[i].normal, rays, 1e30f, i);
    }
  }
  benchmark::DoNotOptimize(sum);
  const double total = static_cast<double>(*n) * rays * static_cast<double>(state.iterations());
  state.SetLabel(std::string(kScenes[state.range(0)]) + (packets ? " packets" : " single"));
  state.counters["rays/s"] = benchmark::Counter(total, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_ReferenceRayKind)
    ->ArgNames({"scene", "rays", "packets"})
    ->ArgsProduct({{0, 1, 2}, {16, 256}, {0, 1}})
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace pbgi

BENCHMARK_MAIN();
