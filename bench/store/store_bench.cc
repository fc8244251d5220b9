// Page store throughput against raw LMDB, same bytes, same binary (issue 2, "Benchmark").
//
//   Write: PageWriter::Append (MDB_APPEND | MDB_RESERVE, header + CRC-32C + zero padding written
//          in place) vs raw mdb_put(MDB_APPEND) of the same finished page bytes; same batches,
//          same map size, same final meta record, with and without the final fsync.
//   Read:  ReadTxn::Get in random page order, with and without checksum verification, vs raw
//          mdb_get; every variant then reads every byte of the page (XOR of its words), as a
//          consumer would, so that a zero-copy get is not measured as free.
//   Cold:  one pass over a store evicted from the page cache (posix_fadvise DONTNEED), in page
//          order and in random order, with and without kernel read-ahead (MDB_NORDAHEAD).
//
// After the runs, a table gives store/raw throughput ratios and the bytes on disk per page byte
// (the waste of power-of-two page sizes). Scratch stores go to $PBGI_BENCH_TMPDIR (default
// /tmp). Sizes: --store_mib=N (default 64) bytes written or read per iteration.
#include <fcntl.h>
#include <lmdb.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "benchmark/benchmark.h"
#include "pbgi/store.h"
#include "store/crc32c.h"
#include "store/store_internal.h"

namespace pbgi {
namespace {

uint64_t g_store_bytes = uint64_t{64} << 20;

std::string ScratchRoot() {
  const char* env = std::getenv("PBGI_BENCH_TMPDIR");
  static const std::string root =
      std::string(env ? env : "/tmp") + "/pbgi_store_bench_" + std::to_string(getpid());
  std::filesystem::create_directories(root);
  return root;
}

uint64_t PagesFor(uint32_t page_size) { return std::max<uint64_t>(16, g_store_bytes / page_size); }

std::vector<uint8_t> Payload(uint32_t page_size, uint64_t page_no) {
  std::vector<uint8_t> p(page_size - sizeof(PageHeader));
  uint64_t x = page_no * 0x9E3779B97F4A7C15ull + 1;
  for (size_t i = 0; i < p.size(); ++i) {
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    p[i] = static_cast<uint8_t>(x);
  }
  return p;
}

// A full page as the store lays it out, for the raw writer.
std::vector<uint8_t> FullPage(uint32_t page_size, uint64_t page_no,
                              const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> page(page_size, 0);
  PageHeader h{};
  h.kind = static_cast<uint16_t>(PageKind::kPoint);
  h.format = kStoreFormatVersion;
  h.record_count = 1;
  h.payload_bytes = static_cast<uint32_t>(payload.size());
  h.page_no = page_no;
  std::memcpy(page.data(), &h, sizeof(h));
  std::memcpy(page.data() + sizeof(h), payload.data(), payload.size());
  h.checksum = internal::PageChecksum(page.data(), page_size);
  std::memcpy(page.data(), &h.checksum, 4);
  return page;
}

// A handful of distinct pages, cycled through, so the source bytes stay in cache for both
// writers alike.
struct Source {
  std::vector<std::vector<uint8_t>> payloads, pages;
  explicit Source(uint32_t page_size) {
    for (uint64_t i = 0; i < 8; ++i) {
      payloads.push_back(Payload(page_size, i));
      pages.push_back(FullPage(page_size, i, payloads.back()));
    }
  }
};

uint64_t FileSize(const std::string& p) {
  std::error_code ec;
  const auto n = std::filesystem::file_size(p, ec);
  return ec ? 0 : n;
}

constexpr uint64_t kBatchBytes = uint64_t{64} << 20;

void CheckOk(benchmark::State& state, const absl::Status& s) {
  if (!s.ok()) state.SkipWithError(s.ToString().c_str());
}

// --------------------------------------------------------------------------------------------
// Write

void BM_StoreWrite(benchmark::State& state) {
  const auto page_size = static_cast<uint32_t>(state.range(0));
  const bool sync = state.range(1) != 0;
  const uint64_t pages = PagesFor(page_size);
  Source src(page_size);
  const std::string path = ScratchRoot() + "/write_store";
  StoreOptions opt;
  opt.page_size = page_size;
  opt.initial_map_size = pages * (page_size + 4096) * 2 + (16 << 20);
  opt.batch_bytes = kBatchBytes;
  opt.sync = sync;
  uint64_t disk = 0;
  for (auto _ : state) {
    auto w = PageWriter::Create(path, opt);
    if (!w.ok()) {
      CheckOk(state, w.status());
      break;
    }
    for (uint64_t i = 0; i < pages; ++i) {
      absl::Status s = (*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                                    src.payloads[i % src.payloads.size()]);
      if (!s.ok()) {
        CheckOk(state, s);
        break;
      }
    }
    StoreMeta m;
    m.point_count = pages;
    CheckOk(state, (*w)->Finish(m));
    state.PauseTiming();
    disk = FileSize(path + "/data.mdb");
    std::filesystem::remove_all(path);
    state.ResumeTiming();
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * pages * page_size));
  state.counters["disk_per_byte"] = static_cast<double>(disk) / (pages * page_size);
  state.counters["bytes_per_iter"] = static_cast<double>(pages * page_size);
}

void BM_RawWrite(benchmark::State& state) {
  const auto page_size = static_cast<uint32_t>(state.range(0));
  const bool sync = state.range(1) != 0;
  const uint64_t pages = PagesFor(page_size);
  Source src(page_size);
  const std::string file = ScratchRoot() + "/write_raw.mdb";
  const uint64_t map_size = pages * (page_size + 4096) * 2 + (16 << 20);
  uint64_t disk = 0;
  for (auto _ : state) {
    MDB_env* env;
    MDB_txn* txn;
    MDB_dbi dbi, meta;
    mdb_env_create(&env);
    mdb_env_set_maxdbs(env, 4);
    mdb_env_set_mapsize(env, map_size);
    int rc = mdb_env_open(env, file.c_str(), MDB_NOSUBDIR | MDB_NOSYNC, 0644);
    rc = rc ? rc : mdb_txn_begin(env, nullptr, 0, &txn);
    rc = rc ? rc : mdb_dbi_open(txn, "points", MDB_CREATE, &dbi);
    rc = rc ? rc : mdb_dbi_open(txn, "meta", MDB_CREATE, &meta);
    rc = rc ? rc : mdb_txn_commit(txn);
    uint64_t batch = 0;
    txn = nullptr;
    for (uint64_t i = 0; i < pages && rc == 0; ++i) {
      if (txn == nullptr) rc = mdb_txn_begin(env, nullptr, 0, &txn);
      uint8_t key_bytes[8];
      internal::EncodeKey(i, key_bytes);
      MDB_val key{8, key_bytes};
      MDB_val val{page_size, src.pages[i % src.pages.size()].data()};
      rc = rc ? rc : mdb_put(txn, dbi, &key, &val, MDB_APPEND);
      batch += page_size;
      if (rc == 0 && batch >= kBatchBytes) {
        rc = mdb_txn_commit(txn);
        txn = nullptr;
        batch = 0;
      }
    }
    if (rc == 0 && txn != nullptr) rc = mdb_txn_commit(txn);
    if (rc == 0 && sync) rc = mdb_env_sync(env, 1);
    char meta_bytes[128] = {};
    MDB_val mk{4, const_cast<char*>("meta")}, mv{sizeof(meta_bytes), meta_bytes};
    rc = rc ? rc : mdb_txn_begin(env, nullptr, 0, &txn);
    rc = rc ? rc : mdb_put(txn, meta, &mk, &mv, 0);
    rc = rc ? rc : mdb_txn_commit(txn);
    if (rc == 0 && sync) rc = mdb_env_sync(env, 1);
    mdb_env_close(env);
    if (rc != 0) {
      state.SkipWithError(mdb_strerror(rc));
      break;
    }
    state.PauseTiming();
    disk = FileSize(file);
    std::filesystem::remove(file);
    std::filesystem::remove(file + "-lock");
    state.ResumeTiming();
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * pages * page_size));
  state.counters["disk_per_byte"] = static_cast<double>(disk) / (pages * page_size);
  state.counters["bytes_per_iter"] = static_cast<double>(pages * page_size);
}

// --------------------------------------------------------------------------------------------
// Read

// One store per page size, built on first use; the previous one is removed.
struct ReadFixture {
  uint32_t page_size = 0;
  uint64_t pages = 0;
  std::string path;
  std::vector<uint64_t> order;  // random permutation of page numbers
};

const ReadFixture& StoreFor(uint32_t page_size) {
  static ReadFixture f;
  if (f.page_size == page_size) return f;
  if (!f.path.empty()) std::filesystem::remove_all(f.path);
  f.page_size = page_size;
  f.pages = PagesFor(page_size);
  f.path = ScratchRoot() + "/read_" + std::to_string(page_size);
  StoreOptions opt;
  opt.page_size = page_size;
  opt.sync = false;
  auto w = PageWriter::Create(f.path, opt);
  Source src(page_size);
  for (uint64_t i = 0; w.ok() && i < f.pages; ++i) {
    (void)(*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                       src.payloads[i % src.payloads.size()]);
  }
  StoreMeta m;
  m.point_count = f.pages;
  if (w.ok()) (void)(*w)->Finish(m);
  f.order.resize(f.pages);
  std::iota(f.order.begin(), f.order.end(), 0);
  std::shuffle(f.order.begin(), f.order.end(), std::mt19937_64(42));
  return f;
}

// Reads every byte, as a consumer of the page would.
inline uint64_t Consume(const void* p, size_t n) {
  const auto* w = static_cast<const uint64_t*>(p);
  uint64_t x = 0;
  for (size_t i = 0; i < n / 8; ++i) x ^= w[i];
  return x;
}

void BM_StoreRead(benchmark::State& state) {
  const auto page_size = static_cast<uint32_t>(state.range(0));
  const ReadFixture& f = StoreFor(page_size);
  StoreOptions opt;
  opt.verify_checksums = state.range(1) != 0;
  auto store = PageStore::Open(f.path, opt);
  if (!store.ok()) {
    CheckOk(state, store.status());
    return;
  }
  auto txn = (*store)->BeginRead();
  size_t k = 0;
  uint64_t sink = 0;
  for (auto _ : state) {
    auto v = txn->Get(Section::kPoints, f.order[k]);
    if (!v.ok()) {
      CheckOk(state, v.status());
      break;
    }
    sink ^= Consume(v->header, page_size);
    if (++k == f.order.size()) k = 0;
  }
  benchmark::DoNotOptimize(sink);
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * page_size));
}

void BM_RawRead(benchmark::State& state) {
  const auto page_size = static_cast<uint32_t>(state.range(0));
  const bool crc = state.range(1) != 0;
  const ReadFixture& f = StoreFor(page_size);
  MDB_env* env;
  MDB_txn* txn;
  MDB_dbi dbi;
  mdb_env_create(&env);
  mdb_env_set_maxdbs(env, 4);
  const std::string file = f.path + "/data.mdb";
  int rc = mdb_env_open(env, file.c_str(),
                        MDB_NOSUBDIR | MDB_RDONLY | MDB_NOLOCK | MDB_NOTLS | MDB_NORDAHEAD, 0644);
  rc = rc ? rc : mdb_txn_begin(env, nullptr, MDB_RDONLY, &txn);
  rc = rc ? rc : mdb_dbi_open(txn, "points", 0, &dbi);
  if (rc != 0) {
    state.SkipWithError(mdb_strerror(rc));
    mdb_env_close(env);
    return;
  }
  size_t k = 0;
  uint64_t sink = 0;
  for (auto _ : state) {
    uint8_t key_bytes[8];
    internal::EncodeKey(f.order[k], key_bytes);
    MDB_val key{8, key_bytes}, val;
    if (mdb_get(txn, dbi, &key, &val) != 0) {
      state.SkipWithError("mdb_get failed");
      break;
    }
    if (crc) sink += internal::Crc32c(0, static_cast<uint8_t*>(val.mv_data) + 4, val.mv_size - 4);
    sink ^= Consume(val.mv_data, val.mv_size);
    if (++k == f.order.size()) k = 0;
  }
  benchmark::DoNotOptimize(sink);
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * page_size));
  mdb_txn_abort(txn);
  mdb_env_close(env);
}

// One pass over a store that is not in the page cache. range(1): 1 = page order, 0 = random;
// range(2): read-ahead on (1) or MDB_NORDAHEAD (0).
void BM_StoreColdPass(benchmark::State& state) {
  const auto page_size = static_cast<uint32_t>(state.range(0));
  const bool sequential = state.range(1) != 0;
  const ReadFixture& f = StoreFor(page_size);
  const std::string file = f.path + "/data.mdb";
  StoreOptions opt;
  opt.read_ahead = state.range(2) != 0;
  uint64_t sink = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const int fd = open(file.c_str(), O_RDONLY);
    if (fd >= 0) {
      fdatasync(fd);
      posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
      close(fd);
    }
    state.ResumeTiming();
    auto store = PageStore::Open(f.path, opt);
    if (!store.ok()) {
      CheckOk(state, store.status());
      break;
    }
    auto txn = (*store)->BeginRead();
    for (uint64_t i = 0; i < f.pages; ++i) {
      auto v = txn->Get(Section::kPoints, sequential ? i : f.order[i]);
      if (!v.ok()) {
        CheckOk(state, v.status());
        break;
      }
      sink ^= Consume(v->header, page_size);
    }
  }
  benchmark::DoNotOptimize(sink);
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * f.pages * page_size));
}

// CRC-32C speed over one 64 KiB page. range(0): 1 = hardware (SSE4.2), 0 = portable.
void BM_Crc32c(benchmark::State& state) {
  if (state.range(0) != 0 && !internal::Crc32cHardwareAvailable()) {
    state.SkipWithError("no SSE4.2 on this CPU");
    return;
  }
  std::vector<uint8_t> buf(kDefaultPageSize, 0x5a);
  uint32_t sink = 0;
  for (auto _ : state) {
    sink += state.range(0) ? internal::Crc32cHardware(sink, buf.data(), buf.size())
                           : internal::Crc32cPortable(sink, buf.data(), buf.size());
  }
  benchmark::DoNotOptimize(sink);
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * buf.size()));
}
BENCHMARK(BM_Crc32c)->ArgName("hw")->Arg(1)->Arg(0);

// Page sizes: k*4096-16 (efficient) and the naive 2^n.
void PageSizes(benchmark::internal::Benchmark* b, std::vector<int64_t> extra) {
  for (int64_t k : {1, 4, 16, 64, 256}) {
    for (int64_t ps : {k * 4096 - 16, k * 4096}) {
      std::vector<int64_t> args = {ps};
      for (int64_t e : extra) {
        args.push_back(e);
        b->Args(args);
        args.pop_back();
      }
    }
  }
}

BENCHMARK(BM_StoreWrite)
    ->Apply([](benchmark::internal::Benchmark* b) {
      PageSizes(b, {0, 1});
    })
    ->ArgNames({"page", "sync"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_RawWrite)
    ->Apply([](benchmark::internal::Benchmark* b) {
      PageSizes(b, {0, 1});
    })
    ->ArgNames({"page", "sync"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_StoreRead)
    ->Apply([](benchmark::internal::Benchmark* b) {
      PageSizes(b, {0, 1});
    })
    ->ArgNames({"page", "verify"});
BENCHMARK(BM_RawRead)
    ->Apply([](benchmark::internal::Benchmark* b) {
      PageSizes(b, {0, 1});
    })
    ->ArgNames({"page", "crc"});
BENCHMARK(BM_StoreColdPass)
    ->ArgsProduct({{4096 - 16, 16 * 4096 - 16, 256 * 4096 - 16}, {1, 0}, {1, 0}})
    ->ArgNames({"page", "seq", "readahead"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Collects bytes/s per benchmark and prints the store/raw ratios at the end.
class RatioReporter : public benchmark::ConsoleReporter {
 public:
  RatioReporter() : ConsoleReporter(OO_Tabular) {}
  void ReportRuns(const std::vector<Run>& runs) override {
    ConsoleReporter::ReportRuns(runs);
    // With --benchmark_repetitions the median wins over single runs.
    for (const Run& r : runs) {
      if (r.error_occurred) continue;
      const bool median = r.run_type == Run::RT_Aggregate && r.aggregate_name == "median";
      if (r.run_type != Run::RT_Iteration && !median) continue;
      const std::string name = r.run_name.str();
      if (!median && medians_.count(name) != 0) continue;
      if (median) medians_.insert(name);
      auto it = r.counters.find("bytes_per_second");
      if (it != r.counters.end()) rate_[name] = it->second.value;
      auto d = r.counters.find("disk_per_byte");
      if (d != r.counters.end()) disk_[name] = d->second.value;
      // Throughput per CPU second: the machine may be shared, and a writer that waits for a
      // core is not slower code.
      auto b = r.counters.find("bytes_per_iter");
      const double cpu = r.GetAdjustedCPUTime() / benchmark::GetTimeUnitMultiplier(r.time_unit);
      if (b != r.counters.end() && cpu > 0) cpu_rate_[name] = b->second.value / cpu;
    }
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    auto get = [](const std::map<std::string, double>& m, const std::string& name) {
      auto it = m.find(name);
      return it == m.end() ? 0.0 : it->second / (1 << 20);
    };
    auto ratio = [](double a, double b) { return b > 0 ? 100 * a / b : 0.0; };
    std::printf(
        "\nMiB/s, store vs raw LMDB (ratio = store/raw). Write: 64 MiB per store, real time and "
        "per CPU second.\nRead: random pages, hot cache, every byte consumed; 'chk' = store "
        "verify on vs raw + CRC-32C, 'nochk' = verify off vs raw.\n");
    std::printf("%-8s %-6s | %-24s | %-24s | %-24s | %-24s | %-24s | %s\n", "page", "kind",
                "write (real)", "write+fsync (real)", "write (per CPU-s)", "read chk", "read nochk",
                "disk/B");
    for (int64_t k : {1, 4, 16, 64, 256}) {
      for (int64_t ps : {k * 4096 - 16, k * 4096}) {
        const std::string p = "/page:" + std::to_string(ps);
        const std::string w0 = p + "/sync:0/real_time", w1 = p + "/sync:1/real_time";
        const double v[10] = {get(rate_, "BM_StoreWrite" + w0),
                              get(rate_, "BM_RawWrite" + w0),
                              get(rate_, "BM_StoreWrite" + w1),
                              get(rate_, "BM_RawWrite" + w1),
                              get(cpu_rate_, "BM_StoreWrite" + w0),
                              get(cpu_rate_, "BM_RawWrite" + w0),
                              get(rate_, "BM_StoreRead" + p + "/verify:1"),
                              get(rate_, "BM_RawRead" + p + "/crc:1"),
                              get(rate_, "BM_StoreRead" + p + "/verify:0"),
                              get(rate_, "BM_RawRead" + p + "/crc:0")};
        std::printf("%-8lld %-6s", static_cast<long long>(ps), (ps % 4096) ? "k4K-16" : "2^n");
        for (int i = 0; i < 10; i += 2) {
          std::printf(" | %7.0f %7.0f %6.0f%%", v[i], v[i + 1], ratio(v[i], v[i + 1]));
        }
        auto d = disk_.find("BM_StoreWrite" + w0);
        std::printf(" | %.3f\n", d == disk_.end() ? 0.0 : d->second);
      }
    }
  }

 private:
  std::map<std::string, double> rate_, disk_, cpu_rate_;
  std::set<std::string> medians_;
};

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  std::vector<char*> args;
  for (int i = 0; i < argc; ++i) {
    if (std::strncmp(argv[i], "--store_mib=", 12) == 0) {
      pbgi::g_store_bytes = std::strtoull(argv[i] + 12, nullptr, 10) << 20;
    } else {
      args.push_back(argv[i]);
    }
  }
  int n = static_cast<int>(args.size());
  benchmark::Initialize(&n, args.data());
  pbgi::RatioReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  std::filesystem::remove_all(pbgi::ScratchRoot());
  return 0;
}
