// PageStore / PageWriter / ReadTxn / CheckAllPages in one process: round trips, zero-copy views,
// damaged and foreign files, map growth and map limits.
#include <fcntl.h>
#include <lmdb.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/store.h"
#include "store/meta_codec.h"
#include "tests/common/child_process.h"
#include "tests/store/store_test_util.h"

namespace pbgi {
namespace {

// Whether this build runs under AddressSanitizer or ThreadSanitizer (g++ defines these; clang
// answers __has_feature).
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif
#else
constexpr bool kSanitized = false;
#endif

using ::testing::AnyOf;
using ::testing::HasSubstr;
using testing_store::PagePayload;
using testing_store::PayloadSizeFor;
using testing_store::ScratchDir;

uint32_t RecordsFor(uint64_t page_no) { return static_cast<uint32_t>(page_no % 100 + 1); }

// Writes `nodes` node pages and `points` point pages (interleaved, as a builder does), returns
// the meta record given to Finish.
StoreMeta WriteStore(const std::string& path, const StoreOptions& opt, uint64_t nodes,
                     uint64_t points, uint64_t seed = 0) {
  auto w = PageWriter::Create(path, opt);
  EXPECT_TRUE(w.ok()) << w.status();
  if (!w.ok()) return {};
  StoreMeta meta;
  const size_t cap = (*w)->payload_capacity();
  for (uint64_t i = 0; i < std::max(nodes, points); ++i) {
    if (i < points) {
      auto p = PagePayload(Section::kPoints, i, PayloadSizeFor(i, cap), seed);
      absl::Status s = (*w)->Append(Section::kPoints, i, PageKind::kPoint, RecordsFor(i), p);
      EXPECT_TRUE(s.ok()) << s;
      meta.point_count += RecordsFor(i);
    }
    if (i < nodes) {
      auto p = PagePayload(Section::kNodes, i, PayloadSizeFor(i + 1, cap), seed);
      absl::Status s = (*w)->Append(Section::kNodes, i, PageKind::kNode, RecordsFor(i), p);
      EXPECT_TRUE(s.ok()) << s;
      meta.node_count += RecordsFor(i);
    }
  }
  meta.layout = "test";
  meta.stats["seed"] = std::to_string(seed);
  absl::Status s = (*w)->Finish(meta);
  EXPECT_TRUE(s.ok()) << s;
  return meta;
}

// Expects every page of the store to hold exactly what WriteStore wrote.
void ExpectContents(const PageStore& store, uint64_t nodes, uint64_t points, uint64_t seed = 0) {
  auto txn = store.BeginRead();
  ASSERT_TRUE(txn.ok()) << txn.status();
  const size_t cap = store.meta().page_size - sizeof(PageHeader);
  for (Section s : {Section::kNodes, Section::kPoints}) {
    const uint64_t n = s == Section::kNodes ? nodes : points;
    for (uint64_t i = 0; i < n; ++i) {
      auto v = txn->Get(s, i);
      ASSERT_TRUE(v.ok()) << v.status();
      const size_t size = PayloadSizeFor(s == Section::kNodes ? i + 1 : i, cap);
      const auto expected = PagePayload(s, i, size, seed);
      ASSERT_EQ(v->header->page_no, i);
      ASSERT_EQ(v->header->record_count, RecordsFor(i));
      ASSERT_EQ(v->header->kind,
                static_cast<uint16_t>(s == Section::kNodes ? PageKind::kNode : PageKind::kPoint));
      ASSERT_EQ(v->payload.size(), size);
      ASSERT_TRUE(std::equal(v->payload.begin(), v->payload.end(), expected.begin()))
          << SectionName(s) << " page " << i;
    }
    EXPECT_EQ(txn->Get(s, n).status().code(), absl::StatusCode::kNotFound);
  }
}

std::string DataFile(const std::string& store) { return store + "/data.mdb"; }

std::vector<char> ReadFile(const std::string& p) {
  std::ifstream in(p, std::ios::binary);
  return std::vector<char>(std::istreambuf_iterator<char>(in), {});
}
void WriteFile(const std::string& p, const std::vector<char>& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

TEST(PageStoreTest, RoundTripManyPagesOfSeveralSizes) {
  ScratchDir dir;
  struct Case {
    uint32_t page_size;
    uint64_t nodes, points;
  };
  for (Case c : {Case{EfficientPageSize(1), 300, 700}, Case{4096, 200, 333},
                 Case{EfficientPageSize(3), 150, 250}, Case{kDefaultPageSize, 40, 90},
                 Case{104, 1000, 3000}, Case{EfficientPageSize(256), 3, 9}}) {
    SCOPED_TRACE(c.page_size);
    const std::string path = dir.Sub("s" + std::to_string(c.page_size));
    StoreOptions opt;
    opt.page_size = c.page_size;
    opt.batch_bytes = 1 << 20;  // several batches per store
    const StoreMeta written = WriteStore(path, opt, c.nodes, c.points, c.page_size);
    auto store = PageStore::Open(path);
    ASSERT_TRUE(store.ok()) << store.status();
    const StoreMeta& m = (*store)->meta();
    EXPECT_EQ(m.page_size, c.page_size);
    EXPECT_EQ(m.node_pages, c.nodes);
    EXPECT_EQ(m.point_pages, c.points);
    EXPECT_EQ(m.node_count, written.node_count);
    EXPECT_EQ(m.point_count, written.point_count);
    EXPECT_EQ(m.layout, "test");
    EXPECT_EQ(m.stats.at("seed"), std::to_string(c.page_size));
    EXPECT_GE((*store)->FileBytes(), (c.nodes + c.points) * c.page_size);
    ExpectContents(**store, c.nodes, c.points, c.page_size);
    auto report = CheckAllPages(**store);
    ASSERT_TRUE(report.ok()) << report.status();
    EXPECT_TRUE(report->ok()) << report->first_error;
    EXPECT_EQ(report->nodes.pages, c.nodes);
    EXPECT_EQ(report->points.pages, c.points);
    EXPECT_EQ(report->nodes.records, written.node_count);
    EXPECT_EQ(report->points.records, written.point_count);
    EXPECT_EQ(report->points.last_page_no, c.points - 1);
    EXPECT_EQ(report->bad_pages, 0u);
    // The same bytes when pages are copied out of the file (inline values in LMDB's leaves
    // included, at 104 bytes).
    StoreOptions copy;
    copy.copy_pages = true;
    auto copied = PageStore::Open(path, copy);
    ASSERT_TRUE(copied.ok()) << copied.status();
    ExpectContents(**copied, c.nodes, c.points, c.page_size);
  }
}

// The address ranges of this process's mappings of `file`.
std::vector<std::pair<uintptr_t, uintptr_t>> MappingsOf(const std::string& file) {
  std::vector<std::pair<uintptr_t, uintptr_t>> out;
  std::ifstream maps("/proc/self/maps");
  std::string line;
  const std::string name = std::filesystem::canonical(file).string();
  while (std::getline(maps, line)) {
    if (line.size() < name.size() || line.compare(line.size() - name.size(), name.size(), name))
      continue;
    std::istringstream is(line);
    std::string range;
    is >> range;
    const size_t dash = range.find('-');
    out.emplace_back(std::stoull(range.substr(0, dash), nullptr, 16),
                     std::stoull(range.substr(dash + 1), nullptr, 16));
  }
  return out;
}

TEST(PageStoreTest, ViewsPointIntoTheMapAndStayStableWhileTheTxnLives) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  StoreOptions opt;
  opt.page_size = EfficientPageSize(2);
  WriteStore(path, opt, 10, 200);
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  const auto maps = MappingsOf(DataFile(path));
  ASSERT_FALSE(maps.empty());
  auto txn = (*store)->BeginRead();
  ASSERT_TRUE(txn.ok());
  auto first = txn->Get(Section::kPoints, 5);
  ASSERT_TRUE(first.ok());
  const auto addr = reinterpret_cast<uintptr_t>(first->header);
  bool inside = false;
  for (auto [lo, hi] : maps) inside |= addr >= lo && addr + opt.page_size <= hi;
  EXPECT_TRUE(inside) << "the view is a copy, not a pointer into data.mdb's map";
  const std::vector<uint8_t> copy(first->payload.begin(), first->payload.end());
  for (uint64_t i = 0; i < 200; ++i) ASSERT_TRUE(txn->Get(Section::kPoints, i).ok());
  for (uint64_t i = 0; i < 10; ++i) ASSERT_TRUE(txn->Get(Section::kNodes, i).ok());
  // Same bytes, same place: nothing was copied or moved under the first view.
  EXPECT_TRUE(std::equal(copy.begin(), copy.end(), first->payload.begin()));
  auto again = txn->Get(Section::kPoints, 5);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->header, first->header);
  // After Reset the transaction refuses reads until Renew.
  txn->Reset();
  EXPECT_EQ(txn->Get(Section::kPoints, 5).status().code(), absl::StatusCode::kFailedPrecondition);
  ASSERT_TRUE(txn->Renew().ok());
  auto renewed = txn->Get(Section::kPoints, 5);
  ASSERT_TRUE(renewed.ok());
  EXPECT_TRUE(std::equal(copy.begin(), copy.end(), renewed->payload.begin()));
}

TEST(PageStoreTest, ReopenAfterClose) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  WriteStore(path, {}, 5, 17, 9);
  for (int round = 0; round < 3; ++round) {
    auto store = PageStore::Open(path);
    ASSERT_TRUE(store.ok()) << store.status();
    ExpectContents(**store, 5, 17, 9);
  }
  // Rewriting in place replaces the store.
  WriteStore(path, {}, 2, 3, 10);
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  EXPECT_EQ((*store)->meta().point_pages, 3u);
  ExpectContents(**store, 2, 3, 10);
}

TEST(PageStoreTest, FlippedByteIsDataLossNamingThatPage) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  StoreOptions opt;
  opt.page_size = EfficientPageSize(1);
  const std::string marker = "<<PBGI-MARKER-PAGE-37>>";
  {
    auto w = PageWriter::Create(path, opt);
    ASSERT_TRUE(w.ok());
    for (uint64_t i = 0; i < 80; ++i) {
      std::vector<uint8_t> p = PagePayload(Section::kPoints, i, 1000);
      if (i == 37) std::memcpy(p.data() + 400, marker.data(), marker.size());
      ASSERT_TRUE((*w)->Append(Section::kPoints, i, PageKind::kPoint, 1, p).ok());
    }
    StoreMeta m;
    m.point_count = 80;
    ASSERT_TRUE((*w)->Finish(m).ok());
  }
  std::vector<char> bytes = ReadFile(DataFile(path));
  auto it = std::search(bytes.begin(), bytes.end(), marker.begin(), marker.end());
  ASSERT_NE(it, bytes.end());
  ASSERT_EQ(std::search(it + 1, bytes.end(), marker.begin(), marker.end()), bytes.end());
  it[7] ^= 0x10;
  WriteFile(DataFile(path), bytes);

  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  auto txn = (*store)->BeginRead();
  ASSERT_TRUE(txn.ok());
  auto bad = txn->Get(Section::kPoints, 37);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(bad.status().message(), HasSubstr("points page 37"));
  EXPECT_THAT(bad.status().message(), HasSubstr("checksum"));
  EXPECT_THAT(bad.status().message(), HasSubstr(path));
  EXPECT_TRUE(txn->Get(Section::kPoints, 36).ok());
  EXPECT_TRUE(txn->Get(Section::kPoints, 38).ok());

  auto report = CheckAllPages(**store);
  ASSERT_TRUE(report.ok());
  EXPECT_FALSE(report->ok());
  EXPECT_EQ(report->bad_pages, 1u);
  EXPECT_EQ(report->points.pages, 80u);
  EXPECT_THAT(report->first_error.message(), HasSubstr("points page 37"));

  // With verification off (benchmarks), the damaged bytes come back unchecked.
  StoreOptions fast;
  fast.verify_checksums = false;
  auto unchecked = PageStore::Open(path, fast);
  ASSERT_TRUE(unchecked.ok());
  auto utxn = (*unchecked)->BeginRead();
  ASSERT_TRUE(utxn.ok());
  EXPECT_TRUE(utxn->Get(Section::kPoints, 37).ok());

  // Pages copied out of the file (copy_pages) are checked the same way.
  StoreOptions copy;
  copy.copy_pages = true;
  auto copied = PageStore::Open(path, copy);
  ASSERT_TRUE(copied.ok());
  auto ctxn = (*copied)->BeginRead();
  ASSERT_TRUE(ctxn.ok());
  auto cbad = ctxn->Get(Section::kPoints, 37);
  ASSERT_FALSE(cbad.ok());
  EXPECT_EQ(cbad.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(cbad.status().message(), HasSubstr("points page 37"));
  EXPECT_THAT(cbad.status().message(), HasSubstr("checksum"));
  EXPECT_TRUE(ctxn->Get(Section::kPoints, 38).ok());
}

TEST(PageStoreTest, TruncatedFileIsRefused) {
  ScratchDir dir;
  const std::string good = dir.Sub("good");
  WriteStore(good, {}, 10, 40);
  const std::vector<char> bytes = ReadFile(DataFile(good));
  ASSERT_GT(bytes.size(), 40u * kDefaultPageSize);
  for (size_t keep : {bytes.size() / 2, size_t{3 * 4096}, size_t{8192}, size_t{100}, size_t{0}}) {
    SCOPED_TRACE(keep);
    const std::string path = dir.Sub("cut" + std::to_string(keep));
    std::filesystem::create_directories(path);
    WriteFile(DataFile(path), std::vector<char>(bytes.begin(), bytes.begin() + keep));
    auto store = PageStore::Open(path);
    ASSERT_FALSE(store.ok());
    EXPECT_EQ(store.status().code(), absl::StatusCode::kDataLoss) << store.status();
    EXPECT_THAT(store.status().message(), HasSubstr(path));
    EXPECT_THAT(store.status().message(), AnyOf(HasSubstr("truncated"), HasSubstr("not an LMDB")));
  }
  const std::string half = dir.Sub("cut" + std::to_string(bytes.size() / 2));
  EXPECT_THAT(PageStore::Open(half).status().message(), HasSubstr("truncated"));
}

TEST(PageStoreTest, GarbageFileIsRefused) {
  ScratchDir dir;
  const std::string path = dir.Sub("garbage");
  std::filesystem::create_directories(path);
  std::vector<char> junk(1 << 20);
  for (size_t i = 0; i < junk.size(); ++i) {
    junk[i] = static_cast<char>(testing_store::SplitMix(i));
  }
  WriteFile(DataFile(path), junk);
  auto store = PageStore::Open(path);
  ASSERT_FALSE(store.ok());
  EXPECT_EQ(store.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(store.status().message(), HasSubstr("not an LMDB file"));
  EXPECT_THAT(store.status().message(), HasSubstr(path));
}

TEST(PageStoreTest, MissingPathOrNonStoreIsRefused) {
  ScratchDir dir;
  auto missing = PageStore::Open(dir.Sub("nope"));
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(missing.status().message(), HasSubstr("does not exist"));

  std::filesystem::create_directories(dir.Sub("empty"));
  auto empty = PageStore::Open(dir.Sub("empty"));
  EXPECT_EQ(empty.status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(empty.status().message(), HasSubstr("not a store"));

  WriteFile(dir.Sub("file"), {'x'});
  auto file = PageStore::Open(dir.Sub("file"));
  EXPECT_EQ(file.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(file.status().message(), HasSubstr("not a store"));
}

// Makes an LMDB file at `path`/data.mdb with raw LMDB calls; `meta_record` empty means no meta
// key, and `with_meta_db` false means no meta section at all.
void MakeRawStore(const std::string& path, bool with_meta_db, const std::string& meta_record) {
  std::filesystem::create_directories(path);
  MDB_env* env;
  ASSERT_EQ(mdb_env_create(&env), 0);
  mdb_env_set_maxdbs(env, 4);
  ASSERT_EQ(mdb_env_open(env, DataFile(path).c_str(), MDB_NOSUBDIR, 0644), 0);
  MDB_txn* txn;
  ASSERT_EQ(mdb_txn_begin(env, nullptr, 0, &txn), 0);
  MDB_dbi dbi;
  ASSERT_EQ(mdb_dbi_open(txn, "nodes", MDB_CREATE, &dbi), 0);
  ASSERT_EQ(mdb_dbi_open(txn, "points", MDB_CREATE, &dbi), 0);
  if (with_meta_db) {
    ASSERT_EQ(mdb_dbi_open(txn, "meta", MDB_CREATE, &dbi), 0);
    if (!meta_record.empty()) {
      MDB_val k{4, const_cast<char*>("meta")};
      MDB_val v{meta_record.size(), const_cast<char*>(meta_record.data())};
      ASSERT_EQ(mdb_put(txn, dbi, &k, &v, 0), 0);
    }
  }
  ASSERT_EQ(mdb_txn_commit(txn), 0);
  mdb_env_close(env);
}

TEST(PageStoreTest, StoreWithoutMetaOrWithIncompleteMetaIsRefused) {
  ScratchDir dir;
  MakeRawStore(dir.Sub("nometa_db"), false, "");
  auto a = PageStore::Open(dir.Sub("nometa_db"));
  EXPECT_EQ(a.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(a.status().message(), HasSubstr("no meta section"));

  MakeRawStore(dir.Sub("nometa_key"), true, "");
  auto b = PageStore::Open(dir.Sub("nometa_key"));
  EXPECT_EQ(b.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(b.status().message(), HasSubstr("incomplete: the build did not finish"));

  MakeRawStore(dir.Sub("incomplete"), true, internal::EncodeMeta(StoreMeta{}, false));
  auto c = PageStore::Open(dir.Sub("incomplete"));
  EXPECT_EQ(c.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(c.status().message(), HasSubstr("incomplete: the build did not finish"));

  // The same record marked complete opens: the refusals above are about the marker.
  MakeRawStore(dir.Sub("complete"), true, internal::EncodeMeta(StoreMeta{}, true));
  EXPECT_TRUE(PageStore::Open(dir.Sub("complete")).ok());
}

TEST(PageStoreTest, FutureVersionIsRefusedWithBothNumbers) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  WriteStore(path, {}, 1, 1);
  {
    MDB_env* env;
    ASSERT_EQ(mdb_env_create(&env), 0);
    mdb_env_set_maxdbs(env, 4);
    ASSERT_EQ(mdb_env_open(env, DataFile(path).c_str(), MDB_NOSUBDIR, 0644), 0);
    MDB_txn* txn;
    ASSERT_EQ(mdb_txn_begin(env, nullptr, 0, &txn), 0);
    MDB_dbi dbi;
    ASSERT_EQ(mdb_dbi_open(txn, "meta", 0, &dbi), 0);
    MDB_val k{4, const_cast<char*>("meta")}, v;
    ASSERT_EQ(mdb_get(txn, dbi, &k, &v), 0);
    std::string rec(static_cast<char*>(v.mv_data), v.mv_size);
    const uint32_t future = 42;
    std::memcpy(&rec[8], &future, 4);
    MDB_val nv{rec.size(), rec.data()};
    ASSERT_EQ(mdb_put(txn, dbi, &k, &nv, 0), 0);
    ASSERT_EQ(mdb_txn_commit(txn), 0);
    mdb_env_close(env);
    std::filesystem::remove(DataFile(path) + "-lock");
  }
  auto store = PageStore::Open(path);
  ASSERT_FALSE(store.ok());
  EXPECT_EQ(store.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(store.status().message(), HasSubstr("version 42"));
  EXPECT_THAT(store.status().message(), HasSubstr("up to " + std::to_string(kStoreFormatVersion)));
}

TEST(PageStoreTest, AbandonedRebuildLeavesThePreviousStore) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  WriteStore(path, {}, 4, 8, 1);
  {
    auto w = PageWriter::Create(path, {});
    ASSERT_TRUE(w.ok());
    for (uint64_t i = 0; i < 20; ++i) {
      ASSERT_TRUE((*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                               PagePayload(Section::kPoints, i, 100, 2))
                      .ok());
    }
    // Destroyed without Finish().
  }
  EXPECT_FALSE(std::filesystem::exists(path + "/data.mdb.tmp"));
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  EXPECT_EQ((*store)->meta().point_pages, 8u);
  ExpectContents(**store, 4, 8, 1);

  // Without a previous store, an abandoned build leaves nothing that opens.
  {
    auto w = PageWriter::Create(dir.Sub("fresh"), {});
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE((*w)->Append(Section::kNodes, 0, PageKind::kNode, 1, {}).ok());
  }
  EXPECT_FALSE(PageStore::Open(dir.Sub("fresh")).ok());
}

void GrowTest(uint64_t batch_bytes) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  StoreOptions opt;
  opt.initial_map_size = 1 << 20;
  opt.batch_bytes = batch_bytes;
  opt.page_size = kDefaultPageSize;
  const uint64_t pages = (uint64_t{64} << 20) / kDefaultPageSize + 1;  // just over 64 MiB
  WriteStore(path, opt, 3, pages, 5);
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  EXPECT_GE((*store)->FileBytes(), uint64_t{64} << 20);
  ExpectContents(**store, 3, pages, 5);
  auto report = CheckAllPages(**store);
  ASSERT_TRUE(report.ok());
  EXPECT_TRUE(report->ok()) << report->first_error;
  EXPECT_EQ(report->points.pages, pages);
}

TEST(PageStoreTest, MapGrowsFrom1MiBTo64MiBInOneBatch) { GrowTest(uint64_t{256} << 20); }
TEST(PageStoreTest, MapGrowsFrom1MiBTo64MiBInSmallBatches) { GrowTest(uint64_t{3} << 20); }

// Map growth mid-batch writes the batch twice (GrowAndReplay), holding it twice in memory; the
// writer grows the map between batches instead (docs/design.md, "Memory plan"), so the peak RSS
// of writing a store stays within about one write batch, however often the map doubles.
TEST(PageStoreTest, MapGrowsBetweenBatchesWithinOneBatchOfMemory) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  constexpr uint64_t kBatch = uint64_t{8} << 20;
  const testing_common::ChildResult child = testing_common::RunInChild([&] {
    StoreOptions opt;
    opt.initial_map_size = 1 << 20;  // doubles 7 times
    opt.batch_bytes = kBatch;
    opt.page_size = kDefaultPageSize;
    opt.sync = false;
    auto w = PageWriter::Create(path, opt);
    if (!w.ok()) return std::string(w.status().ToString());
    const std::vector<uint8_t> payload =
        PagePayload(Section::kPoints, 1, (*w)->payload_capacity(), 3);
    { std::ofstream("/proc/self/clear_refs") << "5"; }  // VmHWM restarts at VmRSS
    const uint64_t before = internal::CurrentRssBytes();
    absl::Status s;
    const uint64_t pages = (uint64_t{96} << 20) / kDefaultPageSize;
    for (uint64_t i = 0; i < pages && s.ok(); ++i) {
      s = (*w)->Append(Section::kPoints, i, PageKind::kPoint, 1, payload);
    }
    if (s.ok()) s = (*w)->Finish(StoreMeta{});
    if (!s.ok()) return std::string(s.ToString());
    return absl::StrFormat("%d %d %d", (*w)->batch_replays(), before, internal::PeakRssBytes());
  });
  ASSERT_TRUE(child.exited) << child.report;
  uint64_t replays = 0, before = 0, peak = 0;
  ASSERT_EQ(std::sscanf(child.report.c_str(), "%lu %lu %lu", &replays, &before, &peak), 3)
      << child.report;
  EXPECT_EQ(replays, 0u);
  ASSERT_GT(before, 0u) << "no /proc/self/status";
  // The batch's dirty pages, LMDB's few tree pages and the payload; not two batches. Not under
  // a sanitizer, whose shadow memory and quarantine are in the RSS (124 MB here under ASan):
  // the default suite measures the program itself.
  if (!kSanitized) {
    EXPECT_LT(peak - before, kBatch + (uint64_t{3} << 20))
        << "peak RSS " << peak << " bytes, " << before << " before writing";
  }
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
}

TEST(PageStoreTest, MaxMapSizeIsResourceExhausted) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  StoreOptions opt;
  opt.initial_map_size = 1 << 20;
  opt.max_map_size = 4 << 20;
  opt.batch_bytes = 1 << 20;
  auto w = PageWriter::Create(path, opt);
  ASSERT_TRUE(w.ok());
  absl::Status s;
  uint64_t i = 0;
  for (; i < 256 && s.ok(); ++i) {
    s = (*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                     PagePayload(Section::kPoints, i, 1000));
  }
  ASSERT_FALSE(s.ok()) << "wrote 16 MiB into a map limited to 4 MiB";
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(s.message(), HasSubstr("max_map_size"));
  EXPECT_THAT(s.message(), HasSubstr(path));
  EXPECT_LT(i, 70u);  // about 4 MiB of 64 KiB pages
  // The writer stays failed.
  EXPECT_EQ((*w)->Append(Section::kPoints, 1000, PageKind::kPoint, 1, {}).code(),
            absl::StatusCode::kResourceExhausted);
  EXPECT_FALSE((*w)->Finish(StoreMeta{}).ok());
  w->reset();
  EXPECT_FALSE(PageStore::Open(path).ok());
}

TEST(PageStoreTest, FileSizeLimitIsAnErrorNotACrash) {
  // ENOSPC cannot be provoked without a small file system; RLIMIT_FSIZE makes writes fail the
  // same way (EFBIG, or a short write), in a child process so the limit stays there.
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  const testing_common::ChildResult child = testing_common::RunInChild(
      [&] {
        StoreOptions opt;
        opt.batch_bytes = 1 << 20;
        auto w = PageWriter::Create(path, opt);
        if (!w.ok()) return std::string(w.status().ToString());
        absl::Status s;
        for (uint64_t i = 0; i < 128 && s.ok(); ++i) {
          s = (*w)->Append(Section::kPoints, i, PageKind::kPoint, 1, {});
        }
        if (s.ok()) s = (*w)->Finish(StoreMeta{});
        return s.ToString();
      },
      /*file_size_limit=*/2 << 20);
  ASSERT_TRUE(child.exited) << "the writer crashed (signal " << child.signal << ")";
  const std::string& got = child.report;
  // LMDB sees a short write (EIO) or EFBIG; either way the writer names the limit.
  EXPECT_THAT(got, HasSubstr("RESOURCE_EXHAUSTED"));
  EXPECT_THAT(got, HasSubstr("file too large"));
  EXPECT_THAT(got, HasSubstr(path));
}

TEST(PageStoreTest, AppendRefusesBadInput) {
  ScratchDir dir;
  StoreOptions opt;
  opt.page_size = 256;
  auto w = PageWriter::Create(dir.Sub("store"), opt);
  ASSERT_TRUE(w.ok());
  std::vector<uint8_t> big(257 - sizeof(PageHeader));
  EXPECT_EQ((*w)->Append(Section::kNodes, 0, PageKind::kNode, 1, big).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ((*w)->Append(Section::kNodes, 0, PageKind::kPoint, 1, {}).code(),
            absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE((*w)->Append(Section::kNodes, 5, PageKind::kNode, 1, {}).ok());
  absl::Status s = (*w)->Append(Section::kNodes, 5, PageKind::kNode, 1, {});
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("increasing"));
  // The other section has its own order.
  EXPECT_TRUE((*w)->Append(Section::kPoints, 0, PageKind::kPoint, 1, {}).ok());
  StoreMeta m;
  m.node_pages = 7;
  s = (*w)->Finish(m);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("node_pages"));
  EXPECT_EQ(PageWriter::Create(dir.Sub("x"), StoreOptions{.page_size = 16}).status().code(),
            absl::StatusCode::kInvalidArgument);
  absl::Status odd = PageWriter::Create(dir.Sub("y"), StoreOptions{.page_size = 100}).status();
  EXPECT_EQ(odd.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(odd.message(), HasSubstr("multiple of 8"));
}

TEST(PageStoreTest, CheckAllPagesComparesCountsWithTheMetaRecord) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  auto w = PageWriter::Create(path, {});
  ASSERT_TRUE(w.ok());
  ASSERT_TRUE((*w)->Append(Section::kPoints, 0, PageKind::kPoint, 10, {}).ok());
  ASSERT_TRUE((*w)->Append(Section::kPoints, 2, PageKind::kPoint, 10, {}).ok());
  StoreMeta m;
  m.point_count = 21;
  ASSERT_TRUE((*w)->Finish(m).ok());
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok());
  auto report = CheckAllPages(**store);
  ASSERT_TRUE(report.ok());
  EXPECT_FALSE(report->ok());
  EXPECT_EQ(report->bad_pages, 0u);
  EXPECT_EQ(report->points.records, 20u);
  EXPECT_THAT(report->first_error.message(), HasSubstr("points pages 1 to 1 are missing"));
}

// The --cache promise (docs/store.md): reading every page of a store through the map leaves
// it all resident in this process; with copy_pages only LMDB's B-tree pages are, and the bytes
// are the same.
TEST(PageStoreTest, CopyPagesKeepsTheMapOutOfResidentMemory) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  StoreOptions opt;
  opt.page_size = EfficientPageSize(4);
  opt.sync = false;
  constexpr uint64_t kPages = 640;  // per section: 2 x 640 x 16 KiB = 20 MiB
  WriteStore(path, opt, kPages, kPages);
  const double store_bytes = 2.0 * kPages * opt.page_size;

  StoreOptions mapped;
  auto m = PageStore::Open(path, mapped);
  ASSERT_TRUE(m.ok()) << m.status();
  ExpectContents(**m, kPages, kPages);
  auto m_rss = (*m)->MapResidentBytes();
  ASSERT_TRUE(m_rss.ok()) << m_rss.status();
  // The probe sees what the map costs: the pages that verification read are resident.
  EXPECT_GT(static_cast<double>(*m_rss), 0.9 * store_bytes);

  StoreOptions copy;
  copy.copy_pages = true;
  copy.trim_map_every = 0;  // never trim: what the B-tree walks leave resident
  auto c = PageStore::Open(path, copy);
  ASSERT_TRUE(c.ok()) << c.status();
  ExpectContents(**c, kPages, kPages);
  auto c_rss = (*c)->MapResidentBytes();
  ASSERT_TRUE(c_rss.ok()) << c_rss.status();
  EXPECT_LT(static_cast<double>(*c_rss), 0.05 * store_bytes)
      << "resident map bytes after copying every page out of a "
      << static_cast<uint64_t>(store_bytes) << "-byte store";
  std::printf("map resident after reading %.1f MB: mapped %.2f MB, copy_pages %.3f MB\n",
              store_bytes / 1e6, static_cast<double>(*m_rss) / 1e6,
              static_cast<double>(*c_rss) / 1e6);
  EXPECT_GT(*c_rss, 0u) << "the B-tree walks touch the map";
}

// trim_map_every drops the B-tree pages that reads faulted into the map: with a trim after every
// read nothing of the map stays resident, and the pages still read correctly afterwards.
TEST(PageStoreTest, TrimmingTheMapLeavesNothingResident) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  StoreOptions opt;
  opt.page_size = EfficientPageSize(1);
  opt.sync = false;
  constexpr uint64_t kPages = 300;
  WriteStore(path, opt, kPages, kPages);
  for (uint32_t every : {1u, 5u}) {
    SCOPED_TRACE(every);
    StoreOptions copy;
    copy.copy_pages = true;
    copy.trim_map_every = every;
    auto c = PageStore::Open(path, copy);
    ASSERT_TRUE(c.ok()) << c.status();
    {
      auto txn = (*c)->BeginRead();
      ASSERT_TRUE(txn.ok()) << txn.status();
      for (Section s : {Section::kNodes, Section::kPoints}) {
        for (uint64_t i = 0; i < kPages; ++i) {  // 2 x 300 reads: a multiple of both
          auto v = txn->Get(s, i);
          ASSERT_TRUE(v.ok()) << v.status();
          ASSERT_EQ(v->header->page_no, i);
        }
      }
    }
    auto rss = (*c)->MapResidentBytes();
    ASSERT_TRUE(rss.ok()) << rss.status();
    EXPECT_EQ(*rss, 0u);
    ExpectContents(**c, kPages, kPages);  // trimmed pages fault back in intact
  }
}

}  // namespace
}  // namespace pbgi
