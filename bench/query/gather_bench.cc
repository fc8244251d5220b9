// I/O-pattern study of Gather (docs/design.md, "Query"; Kontkanen et al. 2011, section 5): time per
// gather, nodes visited, hit rates per cache level, pages read per 1000 receivers, for
// receivers in Z-order vs shuffled, node layouts, cache budgets from 1% to 100% of the
// database, and 1 or 2 threads. Every Gather/ run is cold: a fresh Database (empty caches)
// after posix_fadvise(POSIX_FADV_DONTNEED) has dropped data.mdb from the OS page cache.
// GatherWarm/, Control/ and GatherWarmScaling/ measure thread scaling without I/O, against a
// pure-compute control loop that gives the machine's own 2-thread ceiling (docs/query.md).
//
//   gather_bench [--db=PATH] [--points=N] [--receivers=N] [--page_size=BYTES]
//                [--leaf_size=N] [--reader_share=F] [--work_dir=DIR]
//                [--schedule=ranges|blocks] [--block=N] [--cache_base=BYTES] [benchmark flags]
//   gather_bench [--db=PATH] --profile_gathers=N [--profile_alternate=B]
//                (under valgrind --tool=callgrind --instr-atstart=no: instructions of N warm
//                gathers, nothing else; with B, in the order one of two threads taking blocks
//                of B in turn sees them)
//   gather_bench [--db=PATH] --profile_threads=T [--schedule=...]   (the same: one warm pass
//                over every receiver with T threads)
// --db studies an existing database (one layout: its own); otherwise the benchmark builds one
// database per layout from a random scene under --work_dir (kept and reused across runs).
// --schedule and --block choose how warm passes deal receivers to threads (see Schedule).
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
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"
#include "valgrind/callgrind.h"

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
  // > 0: profile in AlternateBlocks(Z-order, N) order instead (what each of two threads sees).
  uint64_t profile_alternate = 0;
  // > 0: profile one warm pass over all receivers with this many threads (--schedule).
  int profile_threads = 0;
  // > 0: the cache budgets (1%, 5%, ...) are fractions of this many bytes instead of the
  // database file's size: compare formats of different file sizes at the same cache bytes.
  uint64_t cache_base = 0;
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
  const uint64_t base = g_flags.cache_base > 0 ? g_flags.cache_base : res.file_bytes;
  o.cache_bytes =
      cache_fraction > 0 ? static_cast<uint64_t>(cache_fraction * base) : (uint64_t{1} << 40);
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
  struct alignas(64) PaddedStats {  // one thread's counters, on cache lines of their own
    QueryStats q;
  };
  std::vector<PaddedStats> stats(threads);
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
        if (!readers[t]->Gather(recv[order[k]], Cut{}, &g, &stats[t].q).ok()) failed = true;
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
  for (const PaddedStats& s : stats) res.stats.Add(s.q);
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

// ---------------------------------------------------------------------------------------------
// Thread scaling without I/O (issue 4's goal: 2 threads at least 1.8x the throughput of 1).

// Wall time of a parallel pass and the CPU time of its threads.
struct PassTime {
  double wall = 0;
  double cpu = 0;  // summed over the threads
};

// Runs fn(t) for t in [0, threads) on `threads` threads (t = 0 on the calling one), released
// together once all exist, so thread start-up is not timed; wall time runs from the release to
// the last finish.
template <typename Fn>
PassTime RunThreads(int threads, Fn fn) {
  struct alignas(64) Cpu {
    double seconds = 0;
  };
  std::vector<Cpu> cpu(threads);
  std::atomic<int> ready{0};
  std::atomic<bool> go{false};
  auto body = [&](int t) {
    ready.fetch_add(1);
    while (!go.load(std::memory_order_acquire)) std::this_thread::yield();
    const double c0 = ThreadCpuSeconds();
    fn(t);
    cpu[t].seconds = ThreadCpuSeconds() - c0;
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(body, t);
  while (ready.load() < threads - 1) std::this_thread::yield();
  const auto t0 = std::chrono::steady_clock::now();
  go.store(true, std::memory_order_release);
  body(0);
  for (auto& th : pool) th.join();
  PassTime p;
  p.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (const Cpu& c : cpu) p.cpu += c.seconds;
  return p;
}

// The control: a pure-compute loop (xorshift and multiply-add chains, registers only, no shared
// data, no memory traffic), `units` rounds of it per thread. throughput(2) / throughput(1) of
// this loop is what two threads of this machine give at best: the ceiling for any CPU-bound
// code, the gather included. kChains = 1 is one dependent chain (latency bound: two SMT
// siblings would still both run at full speed); kChains = 8 keeps the integer and FP units
// busy (throughput bound: SMT siblings would share them and give well under 2x).
template <int kChains>
uint64_t ComputeUnit(uint64_t seed) {
  uint64_t x[kChains];
  double f[kChains];
  for (int c = 0; c < kChains; ++c) x[c] = (seed + 0x9e3779b97f4a7c15ull * c) | 1, f[c] = 1.0;
  for (int i = 0; i < 4096 / kChains; ++i) {
    for (int c = 0; c < kChains; ++c) {
      x[c] ^= x[c] << 13;
      x[c] ^= x[c] >> 7;
      x[c] ^= x[c] << 17;
      f[c] = f[c] * 0.999999 + static_cast<double>(x[c] & 0xff) * 1e-9;
    }
  }
  uint64_t r = 0;
  for (int c = 0; c < kChains; ++c) r += x[c] + static_cast<uint64_t>(f[c] * 1e6);
  return r;
}
template <int kChains>
PassTime ControlPass(int threads, uint64_t units_per_thread) {
  return RunThreads(threads, [units_per_thread](int t) {
    uint64_t acc = 0;
    for (uint64_t u = 0; u < units_per_thread; ++u) acc += ComputeUnit<kChains>(u * 2 + t + acc);
    benchmark::DoNotOptimize(acc);
  });
}
// About 0.15 s of one thread for each loop on this machine.
constexpr uint64_t kControlUnits = 20000;

// How the receivers of a pass are dealt out to the threads.
// - kBlocks: blocks of `block` receivers taken in turn from one counter (the cold runs' way):
//   each thread's consecutive blocks are two blocks apart in Z-order, so each loses the
//   coherence between neighbouring blocks (callgrind, 1 MiB private last level: +10% misses),
//   but both work on neighbouring regions and share more in L3 (callgrind, shared 32 MiB L3:
//   70.0 vs 71.4 misses per gather for kRanges).
// - kRanges: one contiguous range of the Z-order per thread, each taken in blocks from its own
//   counter, as a renderer gives each thread its own tiles; a thread whose range runs out takes
//   blocks from the others' (so neither idles while work is left).
// Measured on the 2-core machine, the two come out the same within its noise (docs/query.md).
enum class Schedule { kBlocks, kRanges };
Schedule g_schedule = Schedule::kBlocks;  // --schedule=blocks|ranges (warm runs)
size_t g_block = 256;                     // --block

class Scheduler {
 public:
  Scheduler(size_t n, int threads, size_t block, Schedule schedule)
      : count_(schedule == Schedule::kRanges ? threads : 1),
        ranges_(new Range[count_]),
        block_(block) {
    for (int i = 0; i < count_; ++i) {
      ranges_[i].next.store(n * i / count_, std::memory_order_relaxed);
      ranges_[i].end = n * (i + 1) / count_;
    }
  }
  // The next block [*b, *e) for thread t; false when every receiver has been dealt out.
  bool Next(int t, size_t* b, size_t* e) {
    for (int k = 0; k < count_; ++k) {
      Range& r = ranges_[(t + k) % count_];
      if (r.next.load(std::memory_order_relaxed) >= r.end) continue;
      const size_t x = r.next.fetch_add(block_, std::memory_order_relaxed);
      if (x < r.end) {
        *b = x;
        *e = std::min(r.end, x + block_);
        return true;
      }
    }
    return false;
  }

 private:
  struct alignas(64) Range {
    std::atomic<size_t> next{0};
    size_t end = 0;
  };
  const int count_;
  std::unique_ptr<Range[]> ranges_;
  const size_t block_;
};

// A database decoded whole in the cache and one warm Reader (and Gathered) per thread: every
// Reader has gathered every receiver once, in its own thread, so a timed pass reads no page
// from the store and asks the shared cache for none (shared_lookups_per_1000 says so).
struct WarmSetup {
  std::unique_ptr<Database> db;
  std::vector<std::unique_ptr<Reader>> readers;
  // Each thread's result buffer, on cache lines of its own (a vector's end pointer moves at
  // every element a gather emits).
  struct alignas(64) PaddedGathered {
    Gathered g;
  };
  std::vector<std::unique_ptr<PaddedGathered>> gathered;
  // Per-thread counters, each on cache lines of its own.
  struct alignas(64) Stats {
    QueryStats q;
  };
  std::vector<Stats> stats;
};
absl::StatusOr<WarmSetup> MakeWarm(const std::string& path, const std::vector<Receiver>& recv,
                                   int threads) {
  WarmSetup w;
  DatabaseOptions o;
  o.cache_bytes = uint64_t{1} << 40;
  auto db = Database::Open(path, o);
  if (!db.ok()) return db.status();
  w.db = std::move(*db);
  for (int t = 0; t < threads; ++t) {
    auto r = w.db->NewReader();
    if (!r.ok()) return r.status();
    w.readers.push_back(std::move(*r));
    w.gathered.push_back(std::make_unique<WarmSetup::PaddedGathered>());
  }
  w.stats.resize(threads);
  std::atomic<bool> failed{false};
  RunThreads(threads, [&](int t) {
    for (const Receiver& r : recv) {
      if (!w.readers[t]->Gather(r, Cut{}, &w.gathered[t]->g).ok()) failed = true;
    }
  });
  if (failed) return absl::InternalError("a warm-up gather failed");
  return w;
}

// One timed pass over all receivers in `order` with the first `threads` warm Readers; threads
// take blocks of `block` receivers in turn (as a renderer's tile scheduler would).
absl::StatusOr<RunResult> WarmPass(WarmSetup& w, const std::vector<Receiver>& recv,
                                   const std::vector<uint32_t>& order, int threads, size_t block,
                                   Schedule schedule) {
  for (auto& s : w.stats) s.q.Clear();
  Scheduler scheduler(order.size(), threads, block, schedule);
  std::atomic<bool> failed{false};
  const PassTime pt = RunThreads(threads, [&](int t) {
    Reader& reader = *w.readers[t];
    Gathered* g = &w.gathered[t]->g;
    QueryStats* stats = &w.stats[t].q;
    size_t b, e;
    while (scheduler.Next(t, &b, &e)) {
      for (size_t k = b; k < e; ++k) {
        if (!reader.Gather(recv[order[k]], Cut{}, g, stats).ok()) failed = true;
      }
    }
  });
  if (failed) return absl::InternalError("a gather failed");
  RunResult r;
  r.seconds = pt.wall;
  r.cpu_seconds = pt.cpu;
  for (int t = 0; t < threads; ++t) r.stats.Add(w.stats[t].q);
  r.cache_bytes = w.db->options().cache_bytes;
  r.file_bytes = w.db->FileBytes();
  return r;
}

void ReportWarm(benchmark::State& state, const RunResult& r, int threads) {
  Report(state, r);
  const QueryStats& s = r.stats;
  const double n = static_cast<double>(std::max<uint64_t>(1, s.queries));
  // Reader misses are the shared cache's lookups: 0 when every Reader is warm.
  state.counters["shared_lookups_per_1000"] =
      static_cast<double>(s.TotalPagesTouched() - s.TotalReaderHits()) * 1000.0 / n;
  // Share of the wall time that the threads were on a CPU: below 1, the machine was busy.
  state.counters["cpu_util"] = r.cpu_seconds / (threads * r.seconds);
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n == 0 ? 0 : (n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]));
}

void RegisterWarm(const Subject& subj, std::shared_ptr<const std::vector<Receiver>> recv) {
  auto zorder = std::make_shared<std::vector<uint32_t>>(ZOrder(*recv));
  const std::string path = subj.path;
  // Each iteration is one pass; the counters are those of all passes together.
  for (int threads : {1, 2}) {
    const std::string name =
        absl::StrFormat("GatherWarm/layout:%s/order:z/threads:%d", subj.name, threads);
    benchmark::RegisterBenchmark(
        name.c_str(),
        [path, recv, zorder, threads](benchmark::State& state) {
          auto w = MakeWarm(path, *recv, threads);
          if (!w.ok()) {
            state.SkipWithError(std::string(w.status().message()).c_str());
            return;
          }
          RunResult all;
          for (auto _ : state) {
            auto r = WarmPass(*w, *recv, *zorder, threads, g_block, g_schedule);
            if (!r.ok()) {
              state.SkipWithError(std::string(r.status().message()).c_str());
              return;
            }
            state.SetIterationTime(r->seconds);
            all.seconds += r->seconds;
            all.cpu_seconds += r->cpu_seconds;
            all.stats.Add(r->stats);
            all.cache_bytes = r->cache_bytes;
            all.file_bytes = r->file_bytes;
          }
          ReportWarm(state, all, threads);
        })
        ->UseManualTime()
        ->Iterations(3)
        ->Unit(benchmark::kMillisecond);
  }
  // The control loops alone, 1 and 2 threads (each thread does kControlUnits).
  for (int chains : {1, 8}) {
    for (int threads : {1, 2}) {
      benchmark::RegisterBenchmark(
          absl::StrFormat("Control/%s/threads:%d", chains == 1 ? "latency" : "throughput", threads)
              .c_str(),
          [threads, chains](benchmark::State& state) {
            PassTime all;
            for (auto _ : state) {
              const PassTime p = chains == 1 ? ControlPass<1>(threads, kControlUnits)
                                             : ControlPass<8>(threads, kControlUnits);
              state.SetIterationTime(p.wall);
              all.wall += p.wall;
              all.cpu += p.cpu;
            }
            const double units = static_cast<double>(state.iterations() * threads * kControlUnits);
            state.counters["units_per_s"] = units / all.wall;
            state.counters["cpu_us_per_unit"] = all.cpu * 1e6 / units;
            state.counters["cpu_util"] = all.cpu / (threads * all.wall);
          })
          ->UseManualTime()
          ->Iterations(3)
          ->Unit(benchmark::kMillisecond);
    }
  }
  // 1 vs 2 threads under the same conditions. Each iteration runs, back to back, the control
  // loops and warm gather passes with 1 and 2 threads (and 2 threads with the other schedule).
  // The machine is shared, so any pass may lose its CPU to someone else's build for a while:
  // the *_best figures take the fastest pass of each kind over the iterations (the least
  // disturbed one; a pass can only be slowed, never sped up, by other load), the others the
  // median over iterations of each iteration's figures. fraction_of_ceiling = gather_ratio /
  // control_ratio: the gather's scaling as a share of what the machine gave.
  benchmark::RegisterBenchmark(
      absl::StrFormat("GatherWarmScaling/layout:%s/order:z", subj.name).c_str(),
      [path, recv, zorder](benchmark::State& state) {
        auto w = MakeWarm(path, *recv, 2);
        if (!w.ok()) {
          state.SkipWithError(std::string(w.status().message()).c_str());
          return;
        }
        const double n = static_cast<double>(zorder->size());
        const Schedule other =
            g_schedule == Schedule::kRanges ? Schedule::kBlocks : Schedule::kRanges;
        // Per kind of pass, every iteration's pass.
        enum Kind { kC1, kC2, kT1, kT2, kG1, kG2, kG2Other, kKinds };
        std::vector<PassTime> passes[kKinds];
        auto gather = [&](int threads, Schedule sched) -> absl::StatusOr<PassTime> {
          auto r = WarmPass(*w, *recv, *zorder, threads, g_block, sched);
          if (!r.ok()) return r.status();
          return PassTime{r->seconds, r->cpu_seconds};
        };
        for (auto _ : state) {
          PassTime p[kKinds];
          p[kC1] = ControlPass<1>(1, kControlUnits);
          p[kC2] = ControlPass<1>(2, kControlUnits);
          auto g1 = gather(1, g_schedule);
          auto g2 = gather(2, g_schedule);
          auto g2o = gather(2, other);
          p[kT1] = ControlPass<8>(1, kControlUnits);
          p[kT2] = ControlPass<8>(2, kControlUnits);
          if (!g1.ok() || !g2.ok() || !g2o.ok()) {
            state.SkipWithError("a gather failed");
            return;
          }
          p[kG1] = *g1, p[kG2] = *g2, p[kG2Other] = *g2o;
          double total = 0;
          for (int k = 0; k < kKinds; ++k) {
            passes[k].push_back(p[k]);
            total += p[k].wall;
          }
          state.SetIterationTime(total);
          auto util = [](const PassTime& x, int threads) { return x.cpu / (threads * x.wall); };
          // One line per iteration: how the machine's load moved the figures.
          std::fprintf(stderr,
                       "scaling: control %.3fx (util %.2f), throughput control %.3fx (util "
                       "%.2f); gather %.3fx (util %.2f) %.0f / %.0f gathers/s, cpu %.2f / %.2f "
                       "us/gather; %s schedule %.3fx (util %.2f), cpu %.2f us/gather\n",
                       2 * p[kC1].wall / p[kC2].wall, util(p[kC2], 2),
                       2 * p[kT1].wall / p[kT2].wall, util(p[kT2], 2), p[kG1].wall / p[kG2].wall,
                       util(p[kG2], 2), n / p[kG1].wall, n / p[kG2].wall, p[kG1].cpu * 1e6 / n,
                       p[kG2].cpu * 1e6 / n, other == Schedule::kRanges ? "ranges" : "blocks",
                       p[kG1].wall / p[kG2Other].wall, util(p[kG2Other], 2),
                       p[kG2Other].cpu * 1e6 / n);
        }
        auto best = [&](Kind k) {
          return std::min_element(
                     passes[k].begin(), passes[k].end(),
                     [](const PassTime& a, const PassTime& b) { return a.wall < b.wall; })
              ->wall;
        };
        auto median = [&](auto f) {
          std::vector<double> v;
          for (size_t i = 0; i < passes[0].size(); ++i) v.push_back(f(i));
          return Median(v);
        };
        auto wall = [&](Kind k, size_t i) { return passes[k][i].wall; };
        auto cpu = [&](Kind k, size_t i) { return passes[k][i].cpu; };
        const double control_best = 2 * best(kC1) / best(kC2);
        const double gather_best = best(kG1) / best(kG2);
        state.counters["control_ratio_best"] = control_best;
        state.counters["control_throughput_ratio_best"] = 2 * best(kT1) / best(kT2);
        state.counters["gather_ratio_best"] = gather_best;
        state.counters["gather_ratio_other_schedule_best"] = best(kG1) / best(kG2Other);
        state.counters["fraction_of_ceiling_best"] = gather_best / control_best;
        state.counters["gathers_per_s_1_best"] = n / best(kG1);
        state.counters["gathers_per_s_2_best"] = n / best(kG2);
        state.counters["control_ratio"] =
            median([&](size_t i) { return 2 * wall(kC1, i) / wall(kC2, i); });
        state.counters["gather_ratio"] =
            median([&](size_t i) { return wall(kG1, i) / wall(kG2, i); });
        state.counters["fraction_of_ceiling"] = median([&](size_t i) {
          return (wall(kG1, i) / wall(kG2, i)) / (2 * wall(kC1, i) / wall(kC2, i));
        });
        state.counters["cpu_us_per_gather_1"] =
            median([&](size_t i) { return cpu(kG1, i) * 1e6 / n; });
        state.counters["cpu_us_per_gather_2"] =
            median([&](size_t i) { return cpu(kG2, i) * 1e6 / n; });
        state.counters["cpu_us_per_gather_2_other_schedule"] =
            median([&](size_t i) { return cpu(kG2Other, i) * 1e6 / n; });
        state.counters["cpu_util_2"] =
            median([&](size_t i) { return cpu(kG2, i) / (2 * wall(kG2, i)); });
      })
      ->UseManualTime()
      ->Iterations(10)
      ->Unit(benchmark::kMillisecond);
}

// The order in which one of two threads that take blocks of `block` receivers in turn sees them:
// blocks 0, 2, 4, ... then 1, 3, 5, ... of `order`. One thread gathering in this order pays what
// each of two threads pays for the coherence lost between the blocks it skips.
std::vector<uint32_t> AlternateBlocks(const std::vector<uint32_t>& order, size_t block) {
  std::vector<uint32_t> out;
  out.reserve(order.size());
  for (size_t parity = 0; parity < 2; ++parity) {
    for (size_t b = parity * block; b < order.size(); b += 2 * block) {
      for (size_t k = b; k < std::min(order.size(), b + block); ++k) out.push_back(order[k]);
    }
  }
  return out;
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
  const std::vector<uint32_t> order = g_flags.profile_alternate > 0
                                          ? AlternateBlocks(ZOrder(recv), g_flags.profile_alternate)
                                          : ZOrder(recv);
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
  std::printf(
      "profiled %llu warm gathers: %.1f nodes, %.1f elements per gather; checksums %.9g %llu\n",
      static_cast<unsigned long long>(n), static_cast<double>(nodes) / double(n),
      static_cast<double>(elems) / double(n), sum, static_cast<unsigned long long>(ids));
  return 0;
}

// The same with `threads` warm Readers gathering every receiver once in Z-order, dealt out by
// --schedule: callgrind simulates one cache for the whole process, so with a last level of the
// machine's L3 (--LL=33554432,16,64) it counts what two threads sharing it miss.
int ProfileWarmThreads(const std::string& path, const std::vector<Receiver>& recv, int threads) {
  auto w = MakeWarm(path, recv, threads);
  if (!w.ok()) return 1;
  const std::vector<uint32_t> order = ZOrder(recv);
  CALLGRIND_START_INSTRUMENTATION;
  auto r = WarmPass(*w, recv, order, threads, g_block, g_schedule);
  CALLGRIND_STOP_INSTRUMENTATION;
  if (!r.ok()) return 1;
  std::printf("profiled %llu warm gathers in %d threads: %.1f nodes per gather\n",
              static_cast<unsigned long long>(r->stats.queries), threads,
              static_cast<double>(r->stats.nodes_visited) / double(r->stats.queries));
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
    } else if (pbgi::ParseFlag(argv[i], "--profile_threads", &v)) {
      g_flags.profile_threads = std::atoi(v.c_str());
    } else if (pbgi::ParseFlag(argv[i], "--profile_alternate", &v)) {
      g_flags.profile_alternate = std::strtoull(v.c_str(), nullptr, 10);
    } else if (pbgi::ParseFlag(argv[i], "--profile_gathers", &v)) {
      g_flags.profile_gathers = std::strtoull(v.c_str(), nullptr, 10);
    } else if (pbgi::ParseFlag(argv[i], "--schedule", &v)) {
      pbgi::g_schedule = v == "ranges" ? pbgi::Schedule::kRanges : pbgi::Schedule::kBlocks;
    } else if (pbgi::ParseFlag(argv[i], "--block", &v)) {
      pbgi::g_block = std::max<size_t>(1, std::strtoull(v.c_str(), nullptr, 10));
    } else if (pbgi::ParseFlag(argv[i], "--cache_base", &v)) {
      g_flags.cache_base = std::strtoull(v.c_str(), nullptr, 10);
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
  if (g_flags.profile_threads > 0) {
    return pbgi::ProfileWarmThreads(subjects[0].path, *recv, g_flags.profile_threads);
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
