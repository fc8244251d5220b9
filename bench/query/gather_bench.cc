// I/O-pattern study of Gather (DESIGN.md, "Query"; Kontkanen et al. 2011, section 5): time per
// gather, nodes visited, hit rates per cache level, pages read per 1000 receivers, for
// receivers in Z-order vs shuffled, node layouts, cache budgets from 1% to 100% of the
// database, and 1 or 2 threads. Every run is cold: a fresh Database (empty caches) after
// posix_fadvise(POSIX_FADV_DONTNEED) has dropped data.mdb from the OS page cache.
//
//   gather_bench [--db=PATH] [--points=N] [--receivers=N] [--page_size=BYTES]
//                [--leaf_size=N] [--reader_share=F] [--work_dir=DIR] [benchmark flags]
//   gather_bench [--db=PATH] --profile_gathers=N   (under valgrind --tool=callgrind
//                --instr-atstart=no: instructions of N warm gathers, nothing else)
// --db studies an existing database (one layout: its own); otherwise the benchmark builds one
// database per layout from a random scene under --work_dir (kept and reused across runs).
#include <fcntl.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <numeric>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_format.h"
#include "benchmark/benchmark.h"
#include "valgrind/callgrind.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"

namespace pbgi {
namespace {

struct Flags {
  std::string db;
  std::string work_dir = "out/query-bench";
  uint64_t points = 1000000;
  uint64_t receivers = 20000;
  // 16 KiB pages: a gather touches ~100-300 distinct pages, so smaller pages keep its working
  // set (in bytes) well inside a 5% budget (docs/query.md).
  uint32_t page_size = EfficientPageSize(4);
  uint32_t leaf_size = 16;
  // Each Reader's own LRU as a fraction of the budget (0: the library default, 1/16).
  double reader_share = 0;
  // > 0: no benchmarks; gather every receiver once (warm-up), then the first N receivers in
  // Z-order again with callgrind's instrumentation on (CALLGRIND_START_INSTRUMENTATION).
  uint64_t profile_gathers = 0;
};
Flags g_flags;

struct Subject {
  std::string name;  // layout
  std::string path;
};

double ThreadCpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

void DropFromPageCache(const std::string& db_path) {
  const std::string file = db_path + "/data.mdb";
  int fd = open(file.c_str(), O_RDONLY);
  if (fd < 0) return;
  fdatasync(fd);
  posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
  close(fd);
}

// Receivers where a renderer would shade: on the scene's surfels (a random subset).
std::vector<Receiver> MakeReceivers(const std::string& db_path, uint64_t n) {
  auto db = Database::Open(db_path);
  if (!db.ok()) return {};
  auto all = testing::ReadAllSurfels(**db);
  if (!all.ok() || all->empty()) return {};
  std::mt19937_64 rng(99);
  std::vector<Receiver> r(n);
  for (Receiver& x : r) {
    const Surfel& s = (*all)[rng() % all->size()];
    x = {s.position + 1e-4f * s.normal, s.normal};
  }
  return r;
}

struct RunResult {
  QueryStats stats;
  double seconds = 0;
  double cpu_seconds = 0;  // of all gathering threads
  uint64_t cache_bytes = 0;
  uint64_t file_bytes = 0;
  uint64_t peak_cache_usage = 0;
};

// One cold pass over all receivers in `order` with `threads` Readers that take blocks of 256
// receivers in turn (as a renderer's tile scheduler would).
absl::StatusOr<RunResult> ColdPass(const std::string& path, const std::vector<Receiver>& recv,
                                   const std::vector<uint32_t>& order, double cache_fraction,
                                   int threads) {
  DropFromPageCache(path);
  RunResult res;
  {
    auto probe = Database::Open(path);
    if (!probe.ok()) return probe.status();
    res.file_bytes = (*probe)->FileBytes();
  }
  DatabaseOptions o;
  o.cache_bytes = cache_fraction > 0 ? static_cast<uint64_t>(cache_fraction * res.file_bytes)
                                     : (uint64_t{1} << 40);
  res.cache_bytes = o.cache_bytes;
  if (g_flags.reader_share > 0) {
    o.reader_cache_bytes = static_cast<uint64_t>(g_flags.reader_share * o.cache_bytes);
  }
  auto db = Database::Open(path, o);
  if (!db.ok()) return db.status();
  std::vector<std::unique_ptr<Reader>> readers;
  for (int t = 0; t < threads; ++t) {
    auto r = (*db)->NewReader();
    if (!r.ok()) return r.status();
    readers.push_back(std::move(*r));
  }
  std::vector<QueryStats> stats(threads);
  std::atomic<size_t> next{0};
  std::atomic<bool> failed{false};
  constexpr size_t kBlock = 256;
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<double> cpu(threads, 0.0);
  auto work = [&](int t) {
    const double c0 = ThreadCpuSeconds();
    Gathered g;
    for (;;) {
      const size_t b = next.fetch_add(kBlock);
      if (b >= order.size()) break;
      const size_t e = std::min(order.size(), b + kBlock);
      for (size_t k = b; k < e; ++k) {
        if (!readers[t]->Gather(recv[order[k]], Cut{}, &g, &stats[t]).ok()) failed = true;
      }
    }
    cpu[t] = ThreadCpuSeconds() - c0;
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(work, t);
  work(0);
  for (auto& th : pool) th.join();
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (failed) return absl::InternalError("a gather failed");
  for (const QueryStats& s : stats) res.stats.Add(s);
  for (double c : cpu) res.cpu_seconds += c;
  res.peak_cache_usage = (*db)->CacheUsageBytes();
  return res;
}

void Report(benchmark::State& state, const RunResult& r) {
  const QueryStats& s = r.stats;
  const double n = static_cast<double>(std::max<uint64_t>(1, s.queries));
  const double touched = static_cast<double>(std::max<uint64_t>(1, s.TotalPagesTouched()));
  const double reader_misses = touched - static_cast<double>(s.TotalReaderHits());
  state.counters["us_per_gather"] = r.seconds * 1e6 / n;
  state.counters["gathers_per_s"] = n / r.seconds;
  // CPU time of the gathering threads: what a gather costs when the machine is shared.
  state.counters["cpu_us_per_gather"] = r.cpu_seconds * 1e6 / n;
  state.counters["nodes_per_gather"] = static_cast<double>(s.nodes_visited) / n;
  state.counters["elems_per_gather"] = static_cast<double>(s.clusters + s.surfels) / n;
  state.counters["hit_rate"] = 1.0 - static_cast<double>(s.pages_read) / touched;
  state.counters["reader_hit_rate"] = static_cast<double>(s.TotalReaderHits()) / touched;
  state.counters["shared_hit_rate"] =
      reader_misses > 0 ? static_cast<double>(s.TotalSharedHits()) / reader_misses : 1.0;
  state.counters["pages_read_per_1000"] = static_cast<double>(s.pages_read) * 1000.0 / n;
  state.counters["node_pages_read_per_1000"] =
      static_cast<double>(s.pages_read - s.shared_misses[kPointLevel]) * 1000.0 / n;
  state.counters["point_pages_read_per_1000"] =
      static_cast<double>(s.shared_misses[kPointLevel]) * 1000.0 / n;
  state.counters["MB_read"] = static_cast<double>(s.bytes_read) / 1e6;
  state.counters["cache_MB"] = static_cast<double>(std::min(r.cache_bytes, r.file_bytes)) / 1e6;
  state.counters["db_MB"] = static_cast<double>(r.file_bytes) / 1e6;
}

void Register(const Subject& subj, std::shared_ptr<const std::vector<Receiver>> recv) {
  auto zorder = std::make_shared<std::vector<uint32_t>>(ZOrder(*recv));
  auto shuffled = std::make_shared<std::vector<uint32_t>>(recv->size());
  std::iota(shuffled->begin(), shuffled->end(), 0);
  std::shuffle(shuffled->begin(), shuffled->end(), std::mt19937_64(7));
  struct Budget {
    const char* name;
    double fraction;  // 0: unlimited
  };
  const Budget budgets[] = {
      {"1%", 0.01}, {"5%", 0.05}, {"25%", 0.25}, {"100%", 1.0}, {"unlimited", 0}};
  for (const char* order_name : {"z", "shuffled"}) {
    auto order = std::string(order_name) == "z" ? zorder : shuffled;
    for (const Budget& b : budgets) {
      for (int threads : {1, 2}) {
        // Thread scaling is measured with Z-order only.
        if (threads == 2 && std::string(order_name) != "z") continue;
        const std::string name = absl::StrFormat("Gather/layout:%s/order:%s/cache:%s/threads:%d",
                                                 subj.name, order_name, b.name, threads);
        const std::string path = subj.path;
        const double fraction = b.fraction;
        benchmark::RegisterBenchmark(
            name.c_str(),
            [path, recv, order, fraction, threads](benchmark::State& state) {
              RunResult last;
              for (auto _ : state) {
                auto r = ColdPass(path, *recv, *order, fraction, threads);
                if (!r.ok()) {
                  state.SkipWithError(std::string(r.status().message()).c_str());
                  return;
                }
                state.SetIterationTime(r->seconds);
                last = *r;
              }
              Report(state, last);
            })
            ->UseManualTime()
            ->Iterations(1)
            ->Unit(benchmark::kMillisecond);
      }
    }
  }
}

// Thread scaling without I/O: the whole database decoded in the cache first (a warm pass), then
// passes over all receivers (Z-order) with `threads` Readers. CPU bound: measures contention.
void RegisterWarm(const Subject& subj, std::shared_ptr<const std::vector<Receiver>> recv) {
  auto zorder = std::make_shared<std::vector<uint32_t>>(ZOrder(*recv));
  for (int threads : {1, 2}) {
    const std::string name =
        absl::StrFormat("GatherWarm/layout:%s/order:z/threads:%d", subj.name, threads);
    const std::string path = subj.path;
    benchmark::RegisterBenchmark(
        name.c_str(),
        [path, recv, zorder, threads](benchmark::State& state) {
          DatabaseOptions o;
          o.cache_bytes = uint64_t{1} << 40;
          auto db = Database::Open(path, o);
          if (!db.ok()) {
            state.SkipWithError(std::string(db.status().message()).c_str());
            return;
          }
          std::vector<std::unique_ptr<Reader>> readers;
          for (int t = 0; t < threads; ++t) readers.push_back(std::move(*(*db)->NewReader()));
          {
            Gathered g;
            for (uint32_t i : *zorder) (void)readers[0]->Gather((*recv)[i], Cut{}, &g);
          }
          RunResult last;
          for (auto _ : state) {
            std::vector<QueryStats> stats(threads);
            std::vector<double> cpu(threads, 0.0);
            std::atomic<size_t> next{0};
            const auto t0 = std::chrono::steady_clock::now();
            auto work = [&](int t) {
              const double c0 = ThreadCpuSeconds();
              Gathered g;
              for (;;) {
                const size_t b = next.fetch_add(256);
                if (b >= zorder->size()) break;
                const size_t e = std::min(zorder->size(), b + 256);
                for (size_t k = b; k < e; ++k) {
                  (void)readers[t]->Gather((*recv)[(*zorder)[k]], Cut{}, &g, &stats[t]);
                }
              }
              cpu[t] = ThreadCpuSeconds() - c0;
            };
            std::vector<std::thread> pool;
            for (int t = 1; t < threads; ++t) pool.emplace_back(work, t);
            work(0);
            for (auto& th : pool) th.join();
            last = RunResult{};
            last.seconds =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            for (const QueryStats& s : stats) last.stats.Add(s);
            for (double c : cpu) last.cpu_seconds += c;
            last.cache_bytes = o.cache_bytes;
            last.file_bytes = (*db)->FileBytes();
            state.SetIterationTime(last.seconds);
          }
          Report(state, last);
        })
        ->UseManualTime()
        ->Iterations(3)
        ->Unit(benchmark::kMillisecond);
  }
}

// Instructions per warm gather: the cache holds every page the receivers need, so callgrind sees
// the traversal alone. Prints a checksum of the results so that two builds can be compared.
int ProfileWarmGathers(const std::string& path, const std::vector<Receiver>& recv, uint64_t n) {
  DatabaseOptions o;
  o.cache_bytes = uint64_t{1} << 40;
  auto db = Database::Open(path, o);
  if (!db.ok()) {
    std::fprintf(stderr, "%s\n", std::string(db.status().message()).c_str());
    return 1;
  }
  auto reader = (*db)->NewReader();
  if (!reader.ok()) return 1;
  const std::vector<uint32_t> order = ZOrder(recv);
  n = std::min<uint64_t>(n, order.size());
  Gathered g;
  for (uint32_t i : order) {
    if (!(*reader)->Gather(recv[i], Cut{}, &g).ok()) return 1;
  }
  uint64_t elems = 0, nodes = 0, ids = 0;
  double sum = 0;
  QueryStats stats;
  CALLGRIND_START_INSTRUMENTATION;
  for (uint64_t k = 0; k < n; ++k) {
    if (!(*reader)->Gather(recv[order[k]], Cut{}, &g, &stats).ok()) return 1;
    elems += g.size();
    for (const Cluster& c : g.clusters) sum += c.sh_area[0] + c.sh_power[2][8] + c.bounds.lo.x;
    for (uint64_t id : g.surfel_ids) ids += id;
  }
  CALLGRIND_STOP_INSTRUMENTATION;
  nodes = stats.nodes_visited;
  std::printf("profiled %llu warm gathers: %.1f nodes, %.1f elements per gather; checksums %.9g %llu\n",
              static_cast<unsigned long long>(n), static_cast<double>(nodes) / double(n),
              static_cast<double>(elems) / double(n), sum, static_cast<unsigned long long>(ids));
  return 0;
}

absl::StatusOr<std::string> EnsureDatabase(Layout layout) {
  const std::string dir = absl::StrFormat("%s/%s-%d-p%d-l%d", g_flags.work_dir, LayoutName(layout),
                                          g_flags.points, g_flags.page_size, g_flags.leaf_size);
  if (Database::Open(dir).ok()) return dir;
  std::filesystem::create_directories(g_flags.work_dir);
  std::vector<Surfel> surfels = testing::RandomSceneSurfels(g_flags.points, 2024);
  VectorSurfelSource source(surfels);
  BuildOptions b;
  b.layout = layout;
  b.page_size = g_flags.page_size;
  b.leaf_size = g_flags.leaf_size;
  b.memory_bytes = uint64_t{512} << 20;
  std::fprintf(stderr, "building %s (%llu points, layout %s)...\n", dir.c_str(),
               static_cast<unsigned long long>(g_flags.points), LayoutName(layout));
  auto stats = BuildDatabase(source, dir, b);
  if (!stats.ok()) return stats.status();
  return dir;
}

bool ParseFlag(const char* arg, const char* name, std::string* out) {
  const size_t n = std::strlen(name);
  if (std::strncmp(arg, name, n) == 0 && arg[n] == '=') {
    *out = arg + n + 1;
    return true;
  }
  return false;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  using pbgi::g_flags;
  std::vector<char*> rest;
  for (int i = 0; i < argc; ++i) {
    std::string v;
    if (pbgi::ParseFlag(argv[i], "--db", &v)) {
      g_flags.db = v;
    } else if (pbgi::ParseFlag(argv[i], "--work_dir", &v)) {
      g_flags.work_dir = v;
    } else if (pbgi::ParseFlag(argv[i], "--points", &v)) {
      g_flags.points = std::strtoull(v.c_str(), nullptr, 10);
    } else if (pbgi::ParseFlag(argv[i], "--receivers", &v)) {
      g_flags.receivers = std::strtoull(v.c_str(), nullptr, 10);
    } else if (pbgi::ParseFlag(argv[i], "--page_size", &v)) {
      g_flags.page_size = static_cast<uint32_t>(std::strtoul(v.c_str(), nullptr, 10));
    } else if (pbgi::ParseFlag(argv[i], "--reader_share", &v)) {
      g_flags.reader_share = std::strtod(v.c_str(), nullptr);
    } else if (pbgi::ParseFlag(argv[i], "--profile_gathers", &v)) {
      g_flags.profile_gathers = std::strtoull(v.c_str(), nullptr, 10);
    } else if (pbgi::ParseFlag(argv[i], "--leaf_size", &v)) {
      g_flags.leaf_size = static_cast<uint32_t>(std::strtoul(v.c_str(), nullptr, 10));
    } else {
      rest.push_back(argv[i]);
    }
  }
  int rest_argc = static_cast<int>(rest.size());
  benchmark::Initialize(&rest_argc, rest.data());
  if (benchmark::ReportUnrecognizedArguments(rest_argc, rest.data())) return 1;

  std::vector<pbgi::Subject> subjects;
  if (!g_flags.db.empty()) {
    auto db = pbgi::Database::Open(g_flags.db);
    if (!db.ok()) {
      std::fprintf(stderr, "%s\n", std::string(db.status().message()).c_str());
      return 1;
    }
    subjects.push_back({(*db)->meta().layout, g_flags.db});
  } else {
    for (pbgi::Layout l : {pbgi::Layout::kCoherent, pbgi::Layout::kPostOrder,
                           pbgi::Layout::kBreadthFirst, pbgi::Layout::kShuffled}) {
      auto path = pbgi::EnsureDatabase(l);
      if (!path.ok()) {
        std::fprintf(stderr, "%s\n", std::string(path.status().message()).c_str());
        return 1;
      }
      subjects.push_back({pbgi::LayoutName(l), *path});
    }
  }
  // The same receivers for every layout (same scene, so the same surfels in the same order).
  auto recv = std::make_shared<const std::vector<pbgi::Receiver>>(
      pbgi::MakeReceivers(subjects[0].path, g_flags.receivers));
  if (recv->empty()) {
    std::fprintf(stderr, "no receivers (empty database?)\n");
    return 1;
  }
  if (g_flags.profile_gathers > 0) {
    return pbgi::ProfileWarmGathers(subjects[0].path, *recv, g_flags.profile_gathers);
  }
  for (const auto& s : subjects) pbgi::Register(s, recv);
  pbgi::RegisterWarm(subjects[0], recv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
