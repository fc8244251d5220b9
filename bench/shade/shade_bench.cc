// The shading driver (pbgi/shade.h) end to end: receivers per second through gather + raster on
// 1 and 2 threads, warm cache, random scene of 200 k surfels (docs/query.md has the figures of
// the full pipeline; this tracks the driver's own overhead and scaling).
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "benchmark/benchmark.h"
#include "pbgi/shade.h"
#include "pbgi/testing.h"

namespace pbgi {
namespace {

struct Fixture {
  std::unique_ptr<testing::TempDatabase> db;
  std::vector<ShadeReceiver> receivers;
};

Fixture& Get() {
  static Fixture* f = [] {
    auto* f = new Fixture;
    auto db = testing::TempDatabase::Create(testing::RandomSceneSurfels(200000, 3));
    if (!db.ok()) std::abort();
    f->db = std::move(db).value();
    for (const Receiver& r : testing::RandomReceivers(4096, 9)) {
      f->receivers.push_back({r.position, r.normal, r.normal});
    }
    return f;
  }();
  return *f;
}

void BM_ShadeBatch(benchmark::State& state) {
  Fixture& f = Get();
  ShadeOptions o;
  o.threads = static_cast<int>(state.range(0));
  o.cut.cosine_weighted = true;
  std::vector<ShadeResult> out(f.receivers.size());
  for (auto _ : state) {
    absl::Status s = ShadeBatch(f.db->db(), f.receivers, o, absl::MakeSpan(out));
    if (!s.ok()) state.SkipWithError(std::string(s.message()).c_str());
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * f.receivers.size()));
}
BENCHMARK(BM_ShadeBatch)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace pbgi

BENCHMARK_MAIN();
