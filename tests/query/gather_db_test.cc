// Gather over real LMDB databases built by BuildDatabase, through the test harness
// (pbgi/testing.h): the cut against brute force for every layout and several leaf and page
// sizes, a tiny cache, eight threads, and a corrupt page on disk.
#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>
#include <thread>
#include <tuple>
#include <vector>

#include "absl/strings/str_format.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"

namespace pbgi {
namespace {

using testing::TempDatabase;

std::vector<Receiver> Receivers(const std::vector<Surfel>& surfels, size_t n, uint64_t seed) {
  std::vector<Receiver> r = testing::RandomReceivers(n / 2, seed);
  for (size_t i = 0; r.size() < n; ++i) {
    const Surfel& s = surfels[(i * 7919 + seed) % surfels.size()];
    r.push_back({s.position + 1e-4f * s.normal, s.normal});
  }
  return r;
}

std::vector<std::tuple<uint64_t, uint64_t, int>> Digest(const Gathered& g) {
  std::vector<std::tuple<uint64_t, uint64_t, int>> d;
  for (const Cluster& c : g.clusters) d.emplace_back(c.first_point, c.point_count, 0);
  for (uint64_t id : g.surfel_ids) d.emplace_back(id, 1, 1);
  return d;
}

struct DbConfig {
  Layout layout;
  uint32_t leaf_size;
  uint32_t page_size;
  Channels channels;
};

class GatherDbTest : public ::testing::TestWithParam<DbConfig> {};

TEST_P(GatherDbTest, CutIsValidAgainstBruteForce) {
  const DbConfig cfg = GetParam();
  BuildOptions b;
  b.layout = cfg.layout;
  b.leaf_size = cfg.leaf_size;
  b.page_size = cfg.page_size;
  b.channels = cfg.channels;
  b.memory_bytes = 64 << 20;
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(2500, 31), b);
  ASSERT_TRUE(t.ok()) << t.status();
  const std::vector<Surfel>& surfels = (*t)->surfels();
  ASSERT_EQ(surfels.size(), 2500u);
  auto reader = (*t)->db().NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();
  Gathered coarse, fine, exact;
  const Cut coarse_cut{0.2f}, fine_cut{0.02f, 0.6f}, exact_cut{0.0f};
  Cut fine_same_distance = coarse_cut;
  fine_same_distance.max_solid_angle = 0.02f;
  size_t clusters = 0;
  for (const Receiver& r : Receivers(surfels, 400, 17)) {
    absl::Status s = (*reader)->Gather(r, coarse_cut, &coarse);
    ASSERT_TRUE(s.ok()) << s;
    ASSERT_TRUE((s = testing::CheckValidCut(coarse, surfels, r, coarse_cut)).ok()) << s;
    ASSERT_TRUE((s = (*reader)->Gather(r, fine_same_distance, &fine)).ok()) << s;
    ASSERT_TRUE((s = testing::CheckValidCut(fine, surfels, r, fine_same_distance)).ok()) << s;
    ASSERT_TRUE((s = testing::CheckFinerCutNotSmaller(coarse, fine, surfels, r, coarse_cut,
                                                      fine_same_distance))
                    .ok())
        << s;
    ASSERT_TRUE((s = (*reader)->Gather(r, fine_cut, &fine)).ok()) << s;
    ASSERT_TRUE((s = testing::CheckValidCut(fine, surfels, r, fine_cut)).ok()) << s;
    ASSERT_TRUE((s = (*reader)->Gather(r, exact_cut, &exact)).ok()) << s;
    EXPECT_TRUE(exact.clusters.empty());
    std::vector<uint64_t> ids = exact.surfel_ids;
    std::sort(ids.begin(), ids.end());
    ASSERT_EQ(ids, testing::SurfelsInFront(surfels, r, exact_cut));
    clusters += coarse.clusters.size();
  }
  EXPECT_GT(clusters, 400u);
}

INSTANTIATE_TEST_SUITE_P(
    LayoutsLeafAndPageSizes, GatherDbTest,
    ::testing::Values(DbConfig{Layout::kCoherent, 16, EfficientPageSize(1), Channels::kRadiance},
                      DbConfig{Layout::kCoherent, 4, EfficientPageSize(2), Channels::kOcclusion},
                      DbConfig{Layout::kPostOrder, 16, EfficientPageSize(1), Channels::kRadiance},
                      DbConfig{Layout::kPostOrder, 8, EfficientPageSize(4), Channels::kOcclusion},
                      DbConfig{Layout::kBreadthFirst, 16, EfficientPageSize(1),
                               Channels::kRadiance},
                      DbConfig{Layout::kBreadthFirst, 2, EfficientPageSize(2), Channels::kRadiance},
                      DbConfig{Layout::kShuffled, 16, EfficientPageSize(1), Channels::kRadiance},
                      DbConfig{Layout::kShuffled, 32, EfficientPageSize(2), Channels::kOcclusion}),
    [](const ::testing::TestParamInfo<DbConfig>& info) {
      std::string layout = LayoutName(info.param.layout);
      layout.erase(std::remove(layout.begin(), layout.end(), '-'), layout.end());
      return absl::StrFormat("%s_leaf%d_page%d_%s", layout, info.param.leaf_size,
                             info.param.page_size,
                             HasRadiance(info.param.channels) ? "radiance" : "occlusion");
    });

// A database with two-sided surfels: Gather returns them with their flag (the harness compares
// each gathered surfel with the store's), the cut is valid against brute force, and the store
// holds as many two-sided surfels as went in.
TEST(GatherDb, TwoSidedSurfelsGatherWithTheirFlag) {
  std::vector<Surfel> in = testing::RandomSceneSurfels(2500, 43);
  size_t two_sided = 0;
  for (size_t i = 0; i < in.size(); ++i) {
    in[i].two_sided = i % 2 == 0;
    two_sided += in[i].two_sided ? 1 : 0;
  }
  BuildOptions b;
  b.memory_bytes = 64 << 20;
  auto t = TempDatabase::Create(in, b);
  ASSERT_TRUE(t.ok()) << t.status();
  const std::vector<Surfel>& surfels = (*t)->surfels();
  size_t stored = 0;
  for (const Surfel& s : surfels) stored += s.two_sided ? 1 : 0;
  EXPECT_EQ(stored, two_sided);
  auto reader = (*t)->db().NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();
  Gathered g;
  size_t gathered_two_sided = 0;
  for (const Cut& cut : {Cut{0.2f}, Cut{0.02f, 0.3f}, Cut{0.0f}}) {
    for (const Receiver& r : Receivers(surfels, 100, 5)) {
      absl::Status s = (*reader)->Gather(r, cut, &g);
      ASSERT_TRUE(s.ok()) << s;
      ASSERT_TRUE((s = testing::CheckValidCut(g, surfels, r, cut)).ok()) << s;
      for (const Surfel& sf : g.surfels) gathered_two_sided += sf.two_sided ? 1 : 0;
    }
  }
  EXPECT_GT(gathered_two_sided, 1000u);
}

// The cells that Gather reports: a cluster's cell holds its bounds, a leaf's cell holds its
// surfels, and the cells of one cut do not overlap (they tile the space the cut covers).
TEST(GatherDb, CellsHoldTheirContentAndDoNotOverlap) {
  BuildOptions b;
  b.leaf_size = 8;
  b.memory_bytes = 64 << 20;
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(2500, 31), b);
  ASSERT_TRUE(t.ok()) << t.status();
  const std::vector<Surfel>& surfels = (*t)->surfels();
  auto reader = (*t)->db().NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();
  Gathered g;
  for (const Receiver& r : Receivers(surfels, 60, 3)) {
    ASSERT_TRUE((*reader)->Gather(r, Cut{0.03f}, &g).ok());
    ASSERT_EQ(g.surfel_leaf.size(), g.surfels.size());
    std::vector<Bounds> cells;
    auto holds = [](const Bounds& cell, const glm::vec3& lo, const glm::vec3& hi) {
      const float tol = 1e-5f * glm::length(cell.hi - cell.lo);
      return glm::all(glm::greaterThanEqual(lo, cell.lo - tol)) &&
             glm::all(glm::lessThanEqual(hi, cell.hi + tol));
    };
    for (const Cluster& c : g.clusters) {
      ASSERT_FALSE(c.cell.Empty());
      EXPECT_TRUE(holds(c.cell, c.bounds.lo, c.bounds.hi)) << "cluster at depth " << c.depth;
      cells.push_back(c.cell);
    }
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      ASSERT_LT(g.surfel_leaf[i], g.leaf_cells.size());
      const Bounds& cell = g.leaf_cells[g.surfel_leaf[i]];
      EXPECT_TRUE(holds(cell, g.surfels[i].position, g.surfels[i].position));
    }
    cells.insert(cells.end(), g.leaf_cells.begin(), g.leaf_cells.end());
    for (size_t i = 0; i < cells.size(); ++i) {
      for (size_t j = i + 1; j < cells.size(); ++j) {
        const glm::vec3 lo = glm::max(cells[i].lo, cells[j].lo);
        const glm::vec3 hi = glm::min(cells[i].hi, cells[j].hi);
        const glm::vec3 ext = glm::max(cells[i].hi - cells[i].lo, cells[j].hi - cells[j].lo);
        const bool overlap = glm::all(glm::greaterThan(hi - lo, 1e-4f * ext));
        ASSERT_FALSE(overlap) << "cells " << i << " and " << j << " of " << cells.size();
      }
    }
  }
}

TEST(GatherDb, TinyCacheAndEightThreadsMatchOneThread) {
  BuildOptions b;
  b.page_size = EfficientPageSize(1);
  b.leaf_size = 8;
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(5000, 41), b);
  ASSERT_TRUE(t.ok()) << t.status();
  const std::vector<Receiver> receivers = Receivers((*t)->surfels(), 300, 3);
  std::vector<std::vector<std::tuple<uint64_t, uint64_t, int>>> expected;
  {
    auto reader = (*t)->db().NewReader();
    Gathered g;
    for (const Receiver& r : receivers) {
      ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g).ok());
      expected.push_back(Digest(g));
    }
  }
  // A second Database on the same files with a cache of three pages: thrashes, answers alike.
  DatabaseOptions tiny;
  tiny.cache_bytes = 3 * 4096;
  tiny.reader_cache_bytes = 1;
  auto small = Database::Open((*t)->path(), tiny);
  ASSERT_TRUE(small.ok()) << small.status();
  std::atomic<int> mismatches{0}, errors{0};
  std::vector<std::thread> threads;
  for (int th = 0; th < 8; ++th) {
    threads.emplace_back([&, th] {
      Database& db = th % 2 == 0 ? (*t)->db() : **small;
      auto reader = db.NewReader();
      if (!reader.ok()) {
        errors.fetch_add(1);
        return;
      }
      Gathered g;
      for (size_t k = 0; k < receivers.size(); ++k) {
        const size_t i = (k * 7 + th * 31) % receivers.size();
        if (!(*reader)->Gather(receivers[i], Cut{}, &g).ok()) errors.fetch_add(1);
        if (Digest(g) != expected[i]) mismatches.fetch_add(1);
      }
    });
  }
  for (auto& th : threads) th.join();
  EXPECT_EQ(errors.load(), 0);
  EXPECT_EQ(mismatches.load(), 0);
  EXPECT_LE((*small)->CacheUsageBytes(), 8u * 4096u);
}

// Over LMDB (copy_pages, the default): once a Reader's own LRU holds a gather's pages, the same
// gathers again never reach the shared cache or the store's pread path, in two threads at once.
TEST(GatherDb, WarmGathersInTwoThreadsMakeNoSharedCacheCalls) {
  BuildOptions b;
  b.page_size = EfficientPageSize(2);
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(8000, 45), b);
  ASSERT_TRUE(t.ok()) << t.status();
  const std::vector<Receiver> receivers = Receivers((*t)->surfels(), 200, 5);
  auto db = Database::Open((*t)->path());
  ASSERT_TRUE(db.ok()) << db.status();
  ASSERT_TRUE((*db)->options().copy_pages);
  std::vector<std::unique_ptr<Reader>> readers;
  for (int th = 0; th < 2; ++th) readers.push_back(std::move(*(*db)->NewReader()));
  auto pass = [&](std::vector<QueryStats>* stats) {
    std::vector<std::thread> threads;
    for (int th = 0; th < 2; ++th) {
      threads.emplace_back([&, th] {
        Gathered g;
        for (const Receiver& r : receivers) {
          EXPECT_TRUE(readers[th]->Gather(r, Cut{}, &g, &(*stats)[th]).ok());
        }
      });
    }
    for (auto& th : threads) th.join();
  };
  std::vector<QueryStats> cold(2), warm(2);
  pass(&cold);
  const uint64_t calls = (*db)->SharedCacheCalls();
  const uint64_t pages_read = (*db)->TotalStats().shared.pages_read;
  EXPECT_GT(calls, 0u);
  EXPECT_GT(pages_read, 0u);
  pass(&warm);
  EXPECT_EQ((*db)->SharedCacheCalls() - calls, 0u);
  EXPECT_EQ((*db)->TotalStats().shared.pages_read - pages_read, 0u);
  for (int th = 0; th < 2; ++th) {
    EXPECT_EQ(warm[th].queries, receivers.size());
    EXPECT_EQ(warm[th].pages_read, 0u);
    EXPECT_EQ(warm[th].TotalReaderHits(), warm[th].TotalPagesTouched());
    EXPECT_EQ(warm[th].nodes_visited, cold[th].nodes_visited);
  }
}

// The --cache promise: gathering over a database many times bigger than the cache leaves only
// LMDB's B-tree pages of the map resident (pages are copied out of the file into the cache),
// while reading through the map (copy_pages = false, the old way) leaves every page it read.
TEST(GatherDb, CacheBoundsTheResidentMapOfABiggerDatabase) {
  BuildOptions b;
  b.page_size = EfficientPageSize(4);
  b.memory_bytes = 64 << 20;
  // More than ten times the cache on disk (compressed compact pages: ~30 bytes per point).
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(100000, 47), b);
  ASSERT_TRUE(t.ok()) << t.status();
  std::vector<Receiver> receivers;
  for (size_t i = 0; i < (*t)->surfels().size(); i += 67) {
    const Surfel& s = (*t)->surfels()[i];
    receivers.push_back({s.position + 1e-4f * s.normal, s.normal});
  }
  const std::vector<uint32_t> order = ZOrder(receivers);
  uint64_t resident[2] = {0, 0};
  for (bool copy : {true, false}) {
    DatabaseOptions o;
    o.cache_bytes = 256 << 10;
    o.copy_pages = copy;
    auto db = Database::Open((*t)->path(), o);
    ASSERT_TRUE(db.ok()) << db.status();
    const double file = static_cast<double>((*db)->FileBytes());
    ASSERT_GT(file, 10.0 * o.cache_bytes);
    auto reader = (*db)->NewReader();
    ASSERT_TRUE(reader.ok());
    QueryStats stats;
    absl::Status s = (*reader)->GatherBatch(
        receivers, Cut{}, order, [](size_t, const Gathered&) { return absl::OkStatus(); }, &stats);
    ASSERT_TRUE(s.ok()) << s;
    // The receivers cover the scene: most of the database went through the small cache.
    ASSERT_GT(static_cast<double>(stats.bytes_read), 0.6 * file);
    auto rss = (*db)->MapResidentBytes();
    ASSERT_TRUE(rss.ok()) << rss.status();
    resident[copy ? 0 : 1] = *rss;
    if (copy) {
      // At most the B-tree pages (with the kernel's fault-around) of the reads since the map
      // was last trimmed (StoreOptions::trim_map_every); PageStoreTest checks the trim itself.
      EXPECT_LT(static_cast<double>(*rss), 0.10 * file)
          << "map pages resident after reading " << stats.bytes_read << " bytes of a " << file
          << "-byte database";
    } else {
      EXPECT_GT(static_cast<double>(*rss), 0.5 * file);
    }
    EXPECT_LE((*db)->CacheUsageBytes(), o.cache_bytes);
  }
  std::printf("map resident: copy_pages %.3f MB, through the map %.2f MB\n", resident[0] / 1e6,
              resident[1] / 1e6);
}

// Flips one byte inside a node page in data.mdb: the gather reports that page and the store.
TEST(GatherDb, CorruptPageOnDiskIsAnErrorNamingIt) {
  BuildOptions b;
  b.page_size = EfficientPageSize(1);
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(3000, 43), b);
  ASSERT_TRUE(t.ok()) << t.status();
  const std::string file = (*t)->path() + "/data.mdb";
  std::string bytes;
  {
    std::ifstream in(file, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  // A stored page is a 16-byte LMDB overflow header, then a PageHeader at a 4 KiB boundary.
  size_t victim = 0;
  uint64_t victim_page = 0;
  for (size_t off = 0; off + 4096 <= bytes.size(); off += 4096) {
    PageHeader h;
    std::memcpy(&h, bytes.data() + off + 16, sizeof(h));
    if (h.kind == static_cast<uint16_t>(PageKind::kNode) && h.format == kStoreFormatVersion &&
        h.page_no == 1 && h.record_count > 0 && h.payload_bytes > 64) {
      victim = off + 16;
      victim_page = h.page_no;
      break;
    }
  }
  ASSERT_NE(victim, 0u) << "node page 1 not found in " << file;
  bytes[victim + sizeof(PageHeader) + 8] ^= 0x5a;
  {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }
  auto db = Database::Open((*t)->path());
  ASSERT_TRUE(db.ok()) << db.status();
  auto reader = (*db)->NewReader();
  Gathered g;
  absl::Status first_error;
  for (const Receiver& r : Receivers((*t)->surfels(), 200, 5)) {
    absl::Status s = (*reader)->Gather(r, Cut{0.0f}, &g);
    if (!s.ok()) {
      first_error = s;
      break;
    }
  }
  ASSERT_FALSE(first_error.ok()) << "no gather touched the corrupt page";
  EXPECT_EQ(first_error.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(first_error.message()),
              ::testing::HasSubstr(absl::StrFormat("nodes page %d", victim_page)));
  EXPECT_THAT(std::string(first_error.message()), ::testing::HasSubstr((*t)->path()));
}

TEST(GatherDb, HarnessRemovesItsDirectory) {
  std::string path;
  {
    auto t = TempDatabase::Create(testing::RandomSceneSurfels(100, 1));
    ASSERT_TRUE(t.ok()) << t.status();
    path = (*t)->path();
    EXPECT_TRUE(std::ifstream(path + "/data.mdb").good());
  }
  EXPECT_FALSE(std::ifstream(path + "/data.mdb").good());
}

// The harness catches a broken cut: drop one element, or add a duplicate, and it complains.
TEST(GatherDb, HarnessRejectsBrokenCuts) {
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(2000, 2));
  ASSERT_TRUE(t.ok()) << t.status();
  auto reader = (*t)->db().NewReader();
  const Receiver r{{0.5f, 0.5f, -0.5f}, {0, 0, 1}};
  Gathered g;
  ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g).ok());
  ASSERT_TRUE(testing::CheckValidCut(g, (*t)->surfels(), r, Cut{}).ok());
  ASSERT_GT(g.clusters.size(), 1u);
  Gathered missing = g;
  missing.clusters.pop_back();
  EXPECT_THAT(std::string(testing::CheckValidCut(missing, (*t)->surfels(), r, Cut{}).message()),
              ::testing::HasSubstr("not represented"));
  Gathered twice = g;
  twice.clusters.push_back(g.clusters[0]);
  EXPECT_THAT(std::string(testing::CheckValidCut(twice, (*t)->surfels(), r, Cut{}).message()),
              ::testing::HasSubstr("twice"));
  // A cluster that the cut would have refined.
  EXPECT_FALSE(testing::CheckValidCut(g, (*t)->surfels(), r, Cut{1e-6f}).ok());
}

}  // namespace
}  // namespace pbgi
