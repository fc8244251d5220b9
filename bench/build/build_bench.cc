// End-to-end builds of generated clouds: the out-of-core builder (spilling sort, streaming
// octree, coherent pages, LMDB) side by side with an in-memory build of the same cloud
// (std::sort + recursion, no budget, same page writer), in the same run.
//
//   build_bench [--points=N[,N...]] [--memory=BYTES] [--tmp=DIR] [benchmark flags]
//   build_bench --points=N --write-ply=FILE   (writes the generated cloud as binary PLY)
// Default sizes: 1M and 4M points; memory default: a quarter of the cloud's sort records, so
// the sort spills. Counters: points/s, seconds per pass, peak RSS (VmHWM, reset per run),
// bytes/point, runs spilled.
#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "base/proc.h"
#include "benchmark/benchmark.h"
#include "build/builder.h"
#include "build/external_sort.h"
#include "build/node_packer.h"
#include "build/octree_builder.h"
#include "build/sort_record.h"
#include "pbgi/build.h"
#include "pbgi/ply.h"
#include "pbgi/sh.h"
#include "pbgi/store.h"
#include "store/page_io.h"
#include "tree/format.h"
#include "tree/morton.h"

namespace pbgi {
namespace {

std::vector<int64_t> g_sizes = {1 << 20, 4 << 20};
int64_t g_memory = 0;  // 0: a quarter of the sort records
std::string g_tmp;

uint64_t Mix(uint64_t z) {
  z += 0x9e3779b97f4a7c15ull;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}
float U01(uint64_t h) { return float(h >> 40) * (1.0f / float(1 << 24)); }

// A surface-like scene in constant memory: 64 spheres over a ground plane, surfel i a pure
// function of i (so Rewind() is free and the cloud is the same in every run).
class GeneratedSource final : public SurfelSource {
 public:
  explicit GeneratedSource(uint64_t n) : n_(n) {}
  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    size_t k = static_cast<size_t>(std::min<uint64_t>(out.size(), n_ - i_));
    for (size_t j = 0; j < k; ++j) out[j] = Make(i_ + j);
    i_ += k;
    return k;
  }
  absl::Status Rewind() override {
    i_ = 0;
    return absl::OkStatus();
  }
  int64_t KnownCount() const override { return static_cast<int64_t>(n_); }

  static Surfel Make(uint64_t i) {
    uint64_t h1 = Mix(i), h2 = Mix(h1), h3 = Mix(h2);
    Surfel s;
    if (i % 4 == 0) {
      s.position = glm::vec3(100 * U01(h1) - 50, 100 * U01(h2) - 50, 0.0f);
      s.normal = glm::vec3(0, 0, 1);
      s.radius = 0.05f;
    } else {
      const uint64_t sphere = h3 % 64;
      glm::vec3 c(float(sphere % 8) * 12 - 42, float(sphere / 8) * 12 - 42, 4.0f);
      const float z = 2 * U01(h1) - 1, phi = 6.2831853f * U01(h2);
      const float r = std::sqrt(std::max(0.0f, 1 - z * z));
      glm::vec3 d(r * std::cos(phi), r * std::sin(phi), z);
      s.position = c + 3.0f * d;
      s.normal = d;
      s.radius = 0.02f;
    }
    s.radiance = glm::vec3(U01(h3), 0.5f, 1.0f - U01(h3));
    return s;
  }

 private:
  uint64_t n_;
  uint64_t i_ = 0;
};

// Returns freed heap to the system (earlier benchmarks in this process) and restarts VmHWM at
// the current RSS, which it returns.
uint64_t ResetPeakRss() {
  malloc_trim(0);
  std::ofstream f("/proc/self/clear_refs");
  f << "5";
  f.close();
  return internal::CurrentRssBytes();
}

std::string TmpDir() {
  std::string base = g_tmp.empty() ? std::filesystem::temp_directory_path().string() : g_tmp;
  std::string d = base + "/pbgi_build_bench_" + std::to_string(getpid());
  std::filesystem::create_directories(d);
  return d;
}

uint64_t MemoryFor(uint64_t n) {
  if (g_memory > 0) return static_cast<uint64_t>(g_memory);
  return std::max<uint64_t>(uint64_t{32} << 20, n * internal::kSortBytesPerRecord / 4);
}

void BM_BuildOutOfCore(benchmark::State& state) {
  const uint64_t n = static_cast<uint64_t>(state.range(0));
  const std::string dir = TmpDir();
  BuildOptions o;
  o.memory_bytes = MemoryFor(n);
  o.tmp_dir = dir;
  BuildStats st;
  uint64_t before = 0;
  for (auto _ : state) {
    before = ResetPeakRss();
    GeneratedSource src(n);
    auto r = BuildDatabase(src, dir + "/db", o);
    if (!r.ok()) {
      state.SkipWithError(std::string(r.status().message()).c_str());
      break;
    }
    st = *r;
  }
  state.counters["points_per_s"] =
      benchmark::Counter(double(n) * state.iterations(), benchmark::Counter::kIsRate);
  state.counters["s_sort"] = st.seconds_sort;
  state.counters["s_merge_octree"] = st.seconds_merge;
  state.counters["s_commit"] = st.seconds_finish;
  state.counters["runs"] = double(st.runs_spilled);
  state.counters["budget_MiB"] = double(o.memory_bytes) / (1 << 20);
  state.counters["peak_rss_MiB"] = double(st.peak_rss_bytes) / (1 << 20);
  state.counters["rss_before_MiB"] = double(before) / (1 << 20);
  state.counters["bytes_per_point"] = double(st.bytes_on_disk) / double(n);
  state.counters["node_fill"] = st.node_page_fill;
  std::filesystem::remove_all(dir);
}

// The baseline: everything in memory, std::sort on the keys, recursive subdivision.
struct InMemoryBuilder {
  const std::vector<internal::SortRecord>& recs;
  uint32_t leaf_size;
  internal::NodePacker* packer;
  uint64_t nodes = 0;

  // Builds the subtree over recs[lo, hi) at `depth`; fills `out` and its aggregate.
  absl::Status Build(uint64_t lo, uint64_t hi, uint32_t depth, internal::ClosedNode* out,
                     internal::NodeAggregate* agg) {
    ++nodes;
    internal::NodeRecordCommon& c = out->node.rec.common;
    const bool leaf = hi - lo <= leaf_size || depth == internal::kMaxOctreeDepth;
    if (leaf) {
      for (uint64_t i = lo; i < hi; ++i) agg->AddPoint(recs[i], true);
    } else {
      std::vector<internal::ClosedNode> kids;
      const int shift = 3 * (20 - int(depth));
      for (uint64_t i = lo; i < hi;) {
        const uint64_t oct = (recs[i].key >> shift) & 7;
        uint64_t j = i;
        while (j < hi && ((recs[j].key >> shift) & 7) == oct) ++j;
        kids.emplace_back();
        internal::NodeAggregate ka;
        absl::Status s = Build(i, j, depth + 1, &kids.back(), &ka);
        if (!s.ok()) return s;
        agg->Add(ka);
        i = j;
      }
      absl::Status s = packer->CloseInterior(absl::MakeSpan(kids), out);
      if (!s.ok()) return s;
    }
    for (int k = 0; k < 3; ++k) {
      c.lo[k] = agg->bounds.lo[k];
      c.hi[k] = agg->bounds.hi[k];
    }
    c.flags = leaf ? internal::kNodeFlagLeaf : 0;
    if (leaf) c.children = internal::kNoNodeRef;
    c.first_point = lo;
    c.point_count = hi - lo;
    c.area = float(agg->area);
    c.depth = depth;
    for (int k = 0; k < 9; ++k) c.sh_area[k] = float(agg->sh_area[k]);
    for (int ch = 0; ch < 3; ++ch) {
      for (int k = 0; k < 9; ++k) out->node.rec.sh_power[ch][k] = float(agg->sh_power[ch][k]);
    }
    return absl::OkStatus();
  }
};

void BM_BuildInMemory(benchmark::State& state) {
  const uint64_t n = static_cast<uint64_t>(state.range(0));
  const std::string dir = TmpDir();
  double t_sort = 0, t_tree = 0;
  uint64_t peak = 0;
  for (auto _ : state) {
    ResetPeakRss();
    auto t0 = std::chrono::steady_clock::now();
    GeneratedSource src(n);
    std::vector<Surfel> all(n);
    (void)src.Next(absl::MakeSpan(all));
    Bounds b;
    for (const Surfel& s : all) b.Extend(s.position);
    internal::MortonQuantizer q(b);
    std::vector<internal::SortRecord> recs(n);
    for (uint64_t i = 0; i < n; ++i) {
      Surfel s = all[i];
      s.normal = glm::normalize(s.normal);
      recs[i] = internal::MakeSortRecord(q.Key(s.position), s);
    }
    std::vector<Surfel>().swap(all);
    std::stable_sort(
        recs.begin(), recs.end(),
        [](const internal::SortRecord& a, const internal::SortRecord& c) { return a.key < c.key; });
    auto t1 = std::chrono::steady_clock::now();
    auto w = PageWriter::Create(dir + "/db");
    if (!w.ok()) {
      state.SkipWithError("PageWriter::Create failed");
      break;
    }
    internal::StoreWriterSink sink(w->get());
    const internal::PositionGrid grid = internal::GridOfCube(internal::MortonCube(b));
    internal::NodePacker packer(Layout::kCoherent, Channels::kRadiance, &sink, 1, grid);
    internal::PointPageWriter points(Channels::kRadiance, &sink, grid);
    for (auto& r : recs) (void)points.Add(r, &r);
    (void)points.Flush();
    InMemoryBuilder builder{recs, 16, &packer};
    internal::ClosedNode root;
    internal::NodeAggregate agg;
    absl::Status s = builder.Build(0, n, 0, &root, &agg);
    auto ref = s.ok() ? packer.Finish(std::move(root)) : absl::StatusOr<uint64_t>(s);
    if (!ref.ok()) {
      state.SkipWithError(std::string(ref.status().message()).c_str());
      break;
    }
    StoreMeta meta;
    meta.point_count = n;
    meta.node_count = builder.nodes;
    meta.node_pages = packer.pages();
    meta.point_pages = points.pages();
    meta.root = *ref;
    meta.bounds = b;
    if (!(*w)->Finish(meta).ok()) {
      state.SkipWithError("Finish failed");
      break;
    }
    auto t2 = std::chrono::steady_clock::now();
    t_sort = std::chrono::duration<double>(t1 - t0).count();
    t_tree = std::chrono::duration<double>(t2 - t1).count();
    peak = internal::PeakRssBytes();
  }
  state.counters["points_per_s"] =
      benchmark::Counter(double(n) * state.iterations(), benchmark::Counter::kIsRate);
  state.counters["s_sort"] = t_sort;
  state.counters["s_tree_pages"] = t_tree;
  state.counters["peak_rss_MiB"] = double(peak) / (1 << 20);
  std::filesystem::remove_all(dir);
}

void Register() {
  for (int64_t n : g_sizes) {
    benchmark::RegisterBenchmark("BM_BuildOutOfCore", BM_BuildOutOfCore)
        ->Arg(n)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime()
        ->Iterations(1);
    benchmark::RegisterBenchmark("BM_BuildInMemory", BM_BuildInMemory)
        ->Arg(n)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime()
        ->Iterations(1);
  }
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  std::vector<char*> rest;
  for (int i = 0; i < argc; ++i) {
    std::string a = argv[i];
    if (a.rfind("--points=", 0) == 0) {
      pbgi::g_sizes.clear();
      std::string list = a.substr(9);
      size_t p = 0;
      while (p <= list.size()) {
        size_t q = list.find(',', p);
        if (q == std::string::npos) q = list.size();
        pbgi::g_sizes.push_back(std::stoll(list.substr(p, q - p)));
        p = q + 1;
      }
    } else if (a.rfind("--memory=", 0) == 0) {
      std::string v = a.substr(9);
      double mult = 1;
      char last = v.empty() ? 0 : v.back();
      if (last == 'M' || last == 'm') mult = 1 << 20;
      if (last == 'G' || last == 'g') mult = 1 << 30;
      if (mult != 1) v.pop_back();
      pbgi::g_memory = static_cast<int64_t>(std::stod(v) * mult);
    } else if (a.rfind("--write-ply=", 0) == 0) {
      // Writes the generated cloud of the first --points size as a binary PLY and exits.
      const uint64_t n = static_cast<uint64_t>(pbgi::g_sizes.front());
      auto w = pbgi::PlyWriter::Create(a.substr(12));
      if (!w.ok()) {
        std::fprintf(stderr, "%s\n", std::string(w.status().message()).c_str());
        return 1;
      }
      pbgi::GeneratedSource src(n);
      std::vector<pbgi::Surfel> buf(1 << 16);
      for (;;) {
        size_t k = *src.Next(absl::MakeSpan(buf));
        if (k == 0) break;
        if (!(*w)->Write(absl::MakeConstSpan(buf).subspan(0, k)).ok()) return 1;
      }
      return (*w)->Close().ok() ? 0 : 1;
    } else if (a.rfind("--tmp=", 0) == 0) {
      pbgi::g_tmp = a.substr(6);
    } else {
      rest.push_back(argv[i]);
    }
  }
  int n = static_cast<int>(rest.size());
  benchmark::Initialize(&n, rest.data());
  pbgi::Register();
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
