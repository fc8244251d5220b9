// Regressions of issue 17, "Damaged files never crash": a byte changed in LMDB's own meta,
// branch or leaf pages (which the page checksums do not cover) made verify crash (SIGSEGV),
// shade crash once, and info, verify and shade abort on an LMDB assertion; a meta record
// crafted with a valid checksum (no points, NaN or inverted bounds, SH order 3) was shaded as
// zeros.
//
// The byte-flip harness runs what `pbgi info`, `pbgi verify` and `pbgi shade` run, in a forked
// child per damaged file, and classifies each flip: every tool either reports the damage or
// gives exactly the undamaged answer; a signal (crash, abort, the alarm of a hang) or a
// different answer with success fails the test. The suite runs a sample; by hand:
//   PBGI_FLIP_STRIDE=1 PBGI_FLIP_MASKS=3 store_damage_regression_test --gtest_filter='*Flip*'
// flips every byte three ways (docs/reliability.md has the figures).
#include <fcntl.h>
#include <lmdb.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/store.h"
#include "pbgi/testing.h"
#include "store/meta_codec.h"
#include "tests/common/child_process.h"
#include "tests/store/store_test_util.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;
using testing_common::RunInChild;
using testing_store::ScratchDir;

constexpr uint32_t kLmdbPage = 4096;

std::vector<uint8_t> ReadBytes(const std::string& file) {
  std::ifstream in(file, std::ios::binary);
  return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)), {});
}
void WriteBytes(const std::string& file, const std::vector<uint8_t>& b) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

// A small database: `points` surfels of the random test scene. Page size 1024 keeps node and
// point pages inside LMDB's leaves (several leaf pages and a branch page); 4080 puts each page
// in an overflow run of its own.
void BuildSmall(const std::string& path, uint32_t page_size, size_t points) {
  const std::vector<Surfel> surfels = testing::RandomSceneSurfels(points, 17);
  VectorSurfelSource source(surfels);
  BuildOptions o;
  o.page_size = page_size;
  // A radiance sibling group of 8 nodes needs 1760 bytes.
  o.channels = page_size < 1760 ? Channels::kOcclusion : Channels::kRadiance;
  o.leaf_size = 8;
  o.memory_bytes = 64 << 20;
  auto stats = BuildDatabase(source, path, o);
  ASSERT_TRUE(stats.ok()) << stats.status();
}

std::vector<Receiver> Receivers() {
  std::vector<Receiver> r = testing::RandomReceivers(6, 5);
  r.push_back({{0.5f, 0.5f, 0.5f}, {0.0f, 0.0f, 1.0f}});
  return r;
}

// What the three tools say about a store directory, one line per tool: "ok ..." with what they
// print (info: the meta record; verify: the counts; shade: the exact bits of every result), or
// "error <message>".
std::string RunTools(const std::string& path) {
  std::string out;
  {  // pbgi info
    auto store = PageStore::Open(path);
    if (!store.ok()) {
      out += absl::StrCat("info error ", store.status().message(), "\n");
    } else {
      const StoreMeta& m = (*store)->meta();
      out += absl::StrFormat("info ok %d %d %d %d %d %s %d\n", m.point_count, m.node_count,
                             m.node_pages, m.point_pages, m.root, m.layout, m.stats.size());
    }
  }
  {  // pbgi verify
    auto store = PageStore::Open(path);
    absl::Status s = store.status();
    if (s.ok()) {
      auto report = CheckAllPages(**store);
      s = report.ok() ? report->first_error : report.status();
      if (s.ok()) s = VerifyTree(**store);
    }
    out += s.ok() ? std::string("verify ok\n") : absl::StrCat("verify error ", s.message(), "\n");
  }
  {  // pbgi shade
    std::string shade = "shade ok";
    auto db = Database::Open(path);
    absl::Status s = db.status();
    std::unique_ptr<Reader> reader;
    if (s.ok()) {
      auto r = (*db)->NewReader();
      s = r.status();
      if (s.ok()) reader = std::move(*r);
    }
    MicroBuffer mb;
    RasterOptions ro;
    ro.resolution = 8;
    Gathered g;
    for (const Receiver& rc : Receivers()) {
      if (!s.ok()) break;
      s = reader->Gather(rc, Cut{}, &g);
      ShadeResult res;
      if (s.ok()) s = Shade(g, ShadeReceiver{rc.position, rc.normal, rc.normal}, ro, &mb, &res);
      if (s.ok()) {
        uint32_t bits[4];
        std::memcpy(&bits[0], &res.occlusion, 4);
        std::memcpy(&bits[1], &res.irradiance.x, 4);
        std::memcpy(&bits[2], &res.irradiance.y, 4);
        std::memcpy(&bits[3], &res.irradiance.z, 4);
        shade += absl::StrFormat(" %08x%08x%08x%08x", bits[0], bits[1], bits[2], bits[3]);
      }
    }
    out += s.ok() ? shade + "\n" : absl::StrCat("shade error ", s.message(), "\n");
  }
  return out;
}

std::map<std::string, std::string> Lines(const std::string& report) {
  std::map<std::string, std::string> m;
  size_t at = 0;
  while (at < report.size()) {
    const size_t nl = report.find('\n', at);
    const std::string line = report.substr(at, nl - at);
    m[line.substr(0, line.find(' '))] = line;
    if (nl == std::string::npos) break;
    at = nl + 1;
  }
  return m;
}

// ---------------------------------------------------------------------------------------------
// Targeted damage of LMDB's pages, each of which crashed or aborted before.

struct LmdbPageInfo {
  uint64_t pgno;
  uint16_t flags;
  uint16_t lower, upper;
};

std::vector<LmdbPageInfo> TreePages(const std::vector<uint8_t>& file, uint16_t want_flags) {
  std::vector<LmdbPageInfo> out;
  for (uint64_t p = 2; (p + 1) * kLmdbPage <= file.size(); ++p) {
    const uint8_t* b = file.data() + p * kLmdbPage;
    LmdbPageInfo i;
    std::memcpy(&i.pgno, b, 8);
    std::memcpy(&i.flags, b + 10, 2);
    std::memcpy(&i.lower, b + 12, 2);
    std::memcpy(&i.upper, b + 14, 2);
    if (i.pgno == p && i.flags == want_flags) out.push_back(i);
  }
  return out;
}

// Runs the three tools on `path` in a child and checks that each one reported the damage.
void ExpectAllToolsReport(const std::string& path, const std::string& what) {
  const testing_common::ChildResult r = RunInChild([&] { return RunTools(path); }, 0, 60);
  ASSERT_TRUE(r.exited) << what << ": the tools died of signal " << r.signal << " after:\n"
                        << r.report;
  const auto lines = Lines(r.report);
  for (const char* tool : {"info", "verify", "shade"}) {
    ASSERT_TRUE(lines.count(tool)) << r.report;
    EXPECT_THAT(lines.at(tool), HasSubstr(std::string(tool) + " error")) << what;
    EXPECT_THAT(lines.at(tool), HasSubstr("corrupt")) << what;
    EXPECT_THAT(lines.at(tool), HasSubstr(path)) << what;
  }
}

class LmdbDamageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = dir_.Sub("db");
    BuildSmall(path_, 1024, 3000);
    file_ = path_ + "/data.mdb";
    good_ = ReadBytes(file_);
    const auto lines = Lines(RunTools(path_));
    ASSERT_THAT(lines.at("verify"), HasSubstr("verify ok"));
    ASSERT_THAT(lines.at("shade"), HasSubstr("shade ok"));
  }
  ScratchDir dir_;
  std::string path_, file_;
  std::vector<uint8_t> good_;
};

TEST_F(LmdbDamageTest, BranchPageWithOneKeyIsCorruptNotAnAssertion) {
  const auto branches = TreePages(good_, 0x01);
  ASSERT_FALSE(branches.empty()) << "the test database needs a branch page";
  std::vector<uint8_t> bad = good_;
  const uint16_t lower = 16 + 2;  // NUMKEYS = 1: mdb.c asserts NUMKEYS(mp) > 1
  std::memcpy(bad.data() + branches[0].pgno * kLmdbPage + 12, &lower, 2);
  WriteBytes(file_, bad);
  ExpectAllToolsReport(path_, "a branch page with one key");
  EXPECT_THAT(Lines(RunInChild([&] { return RunTools(path_); }).report).at("verify"),
              HasSubstr(absl::StrFormat("LMDB page %d", branches[0].pgno)));
}

TEST_F(LmdbDamageTest, NodeOffsetOutsideItsPageIsCorruptNotASegfault) {
  const auto leaves = TreePages(good_, 0x02);
  ASSERT_GE(leaves.size(), 3u);
  for (const uint16_t off : {uint16_t{0xfffe}, uint16_t{4094}, uint16_t{2}}) {
    std::vector<uint8_t> bad = good_;
    const LmdbPageInfo& leaf = leaves[leaves.size() / 2];
    std::memcpy(bad.data() + leaf.pgno * kLmdbPage + 16, &off, 2);
    WriteBytes(file_, bad);
    ExpectAllToolsReport(path_, absl::StrCat("node offset ", off));
  }
}

TEST_F(LmdbDamageTest, ChildPageNumberOutsideTheFileIsCorrupt) {
  const auto branches = TreePages(good_, 0x01);
  ASSERT_FALSE(branches.empty());
  const uint8_t* b = good_.data() + branches[0].pgno * kLmdbPage;
  uint16_t off;
  std::memcpy(&off, b + 16 + 2, 2);  // node 1
  std::vector<uint8_t> bad = good_;
  const uint16_t hi = 0x7fff;  // child page number << 16
  std::memcpy(bad.data() + branches[0].pgno * kLmdbPage + off + 2, &hi, 2);
  WriteBytes(file_, bad);
  ExpectAllToolsReport(path_, "a child page past the end");
}

TEST_F(LmdbDamageTest, KeysOutOfOrderAreCorrupt) {
  const auto leaves = TreePages(good_, 0x02);
  ASSERT_GE(leaves.size(), 3u);
  // Swap the offsets of the first two nodes of a leaf: same nodes, keys out of order.
  std::vector<uint8_t> bad = good_;
  uint8_t* p = bad.data() + leaves[leaves.size() / 2].pgno * kLmdbPage + 16;
  std::swap(p[0], p[2]);
  std::swap(p[1], p[3]);
  WriteBytes(file_, bad);
  ExpectAllToolsReport(path_, "keys out of order");
}

TEST_F(LmdbDamageTest, MetaPagePointingIntoAnOverflowRunIsCorrupt) {
  // The main tree's root (meta page 0 and 1, offset 16 + 24 + 48 + 40) set to a data page.
  for (const uint64_t root :
       {uint64_t{1}, uint64_t{good_.size() / kLmdbPage - 1}, uint64_t{1} << 40}) {
    std::vector<uint8_t> bad = good_;
    for (int m = 0; m < 2; ++m) std::memcpy(bad.data() + m * kLmdbPage + 128, &root, 8);
    WriteBytes(file_, bad);
    ExpectAllToolsReport(path_, absl::StrCat("main root ", root));
  }
}

TEST(LmdbOverflowDamageTest, OverflowRunPastTheEndIsCorrupt) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  BuildSmall(path, 4080, 600);
  const std::string file = path + "/data.mdb";
  const std::vector<uint8_t> good = ReadBytes(file);
  const auto leaves = TreePages(good, 0x02);
  ASSERT_FALSE(leaves.empty());
  // Every F_BIGDATA entry of the first leaves: its overflow page number pushed past the end.
  int damaged = 0;
  for (const LmdbPageInfo& leaf : leaves) {
    const uint8_t* b = good.data() + leaf.pgno * kLmdbPage;
    const int n = (leaf.lower - 16) / 2;
    for (int i = 0; i < n && damaged < 6; ++i) {
      uint16_t off, nflags, ksize;
      std::memcpy(&off, b + 16 + 2 * i, 2);
      std::memcpy(&nflags, b + off + 4, 2);
      std::memcpy(&ksize, b + off + 6, 2);
      if ((nflags & 1) == 0) continue;
      std::vector<uint8_t> bad = good;
      const uint64_t past = good.size() / kLmdbPage + static_cast<uint64_t>(i) * 1000;
      std::memcpy(bad.data() + leaf.pgno * kLmdbPage + off + 8 + ksize, &past, 8);
      WriteBytes(file, bad);
      ExpectAllToolsReport(path, absl::StrCat("overflow run at page ", past));
      ++damaged;
    }
  }
  EXPECT_GT(damaged, 0);
}

// ---------------------------------------------------------------------------------------------
// Meta records crafted with a valid checksum.

void RewriteMeta(const std::string& path, const StoreMeta& m) {
  MDB_env* env;
  ASSERT_EQ(mdb_env_create(&env), 0);
  mdb_env_set_maxdbs(env, 4);
  ASSERT_EQ(mdb_env_open(env, (path + "/data.mdb").c_str(), MDB_NOSUBDIR, 0644), 0);
  MDB_txn* txn;
  ASSERT_EQ(mdb_txn_begin(env, nullptr, 0, &txn), 0);
  MDB_dbi dbi;
  ASSERT_EQ(mdb_dbi_open(txn, "meta", 0, &dbi), 0);
  const std::string rec = internal::EncodeMeta(m, true);
  MDB_val k{4, const_cast<char*>("meta")}, v{rec.size(), const_cast<char*>(rec.data())};
  ASSERT_EQ(mdb_put(txn, dbi, &k, &v, 0), 0);
  ASSERT_EQ(mdb_txn_commit(txn), 0);
  mdb_env_close(env);
  std::filesystem::remove(path + "/data.mdb-lock");
}

TEST(CraftedMetaTest, RecordsWithAValidChecksumThatNoDatabaseHoldsAreRefusedAtOpen) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  BuildSmall(path, 4080, 600);
  const std::vector<uint8_t> good = ReadBytes(path + "/data.mdb");
  StoreMeta original;
  {
    auto store = PageStore::Open(path);
    ASSERT_TRUE(store.ok());
    original = (*store)->meta();
  }
  struct Case {
    const char* name;
    void (*edit)(StoreMeta*);
    bool store_refuses;  // PageStore::Open itself (every tool), not only Database::Open/verify
    const char* says;
  };
  const Case cases[] = {
      {"no points", [](StoreMeta* m) { m->point_count = 0; }, false, "holds no points"},
      {"no nodes", [](StoreMeta* m) { m->node_count = 0; }, false, "nodes in"},
      {"NaN bounds", [](StoreMeta* m) { m->bounds.lo.y = std::nanf(""); }, true, "NaN"},
      {"inverted bounds", [](StoreMeta* m) { std::swap(m->bounds.lo.x, m->bounds.hi.x); }, true,
       "inverted"},
      {"infinite bounds",
       [](StoreMeta* m) { m->bounds.hi.z = std::numeric_limits<float>::infinity(); }, true,
       "not finite"},
      {"SH order 3", [](StoreMeta* m) { m->sh_order = 3; }, true, "SH order 3"},
      {"root past the node pages", [](StoreMeta* m) { m->root = (m->node_pages + 3) << 16; }, false,
       "root"},
      {"point pages", [](StoreMeta* m) { m->point_pages += 1; }, false, "point pages"},
      {"depth 40", [](StoreMeta* m) { m->max_depth = 40; }, true, "deep"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    WriteBytes(path + "/data.mdb", good);
    StoreMeta m = original;
    c.edit(&m);
    RewriteMeta(path, m);
    auto store = PageStore::Open(path);
    EXPECT_EQ(store.ok(), !c.store_refuses) << store.status();
    if (!store.ok()) {
      EXPECT_THAT(store.status().message(), HasSubstr(c.says));
    }
    if (store.ok()) {
      absl::Status v = VerifyTree(**store);
      EXPECT_FALSE(v.ok());
      EXPECT_THAT(v.message(), HasSubstr(c.says));
    }
    auto db = Database::Open(path);
    ASSERT_FALSE(db.ok()) << "shaded as zeros";
    EXPECT_EQ(db.status().code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(db.status().message(), HasSubstr(c.says));
    EXPECT_THAT(db.status().message(), HasSubstr(path));
  }
}

// ---------------------------------------------------------------------------------------------
// The byte-flip harness.

uint64_t EnvOr(const char* name, uint64_t fallback) {
  const char* v = std::getenv(name);
  return v != nullptr && v[0] != '\0' ? std::strtoull(v, nullptr, 10) : fallback;
}

struct FlipCounts {
  uint64_t flips = 0;
  uint64_t detected = 0;       // some tool reported the damage, every other one was exact
  uint64_t harmless = 0;       // every tool exact (bytes nothing reads: padding, free space, ...)
  uint64_t verify_missed = 0;  // verify passed but another tool reported damage
  uint64_t crashed = 0, wrong = 0;
  // Per kind of LMDB page the flipped byte lies in: flips, detected.
  std::map<std::string, std::pair<uint64_t, uint64_t>> regions;
  std::vector<std::string> failures;
};

// What each 4 KiB page of a store file is, by LMDB's header: "LMDB meta", "LMDB branch",
// "LMDB leaf" (which also holds our pages when they fit inline), "overflow run" (our pages, one
// run each, its first 16 bytes LMDB's header) or "free" (pages no tree uses).
std::vector<std::string> PageRegions(const std::vector<uint8_t>& file) {
  std::vector<std::string> kind(file.size() / kLmdbPage + 1, "free");
  for (uint64_t p = 0; p < kind.size(); ++p) {
    if (p < 2) {
      kind[p] = "LMDB meta";
      continue;
    }
    if ((p + 1) * kLmdbPage > file.size() || kind[p] != "free") continue;
    const uint8_t* b = file.data() + p * kLmdbPage;
    uint64_t own;
    uint16_t flags;
    uint32_t count;
    std::memcpy(&own, b, 8);
    std::memcpy(&flags, b + 10, 2);
    std::memcpy(&count, b + 12, 4);
    if (own != p) continue;
    if (flags == 0x01) kind[p] = "LMDB branch";
    if (flags == 0x02) kind[p] = "LMDB leaf";
    if (flags == 0x04) {
      for (uint64_t q = p; q < p + count && q < kind.size(); ++q) kind[q] = "overflow run";
    }
  }
  return kind;
}

// Sorts one damaged store's tool report into `c` against the undamaged `reference`.
void Classify(const std::string& where, const testing_common::ChildResult& r,
              const std::map<std::string, std::string>& reference, FlipCounts* c) {
  const auto got = Lines(r.report);
  if (!r.exited || got.size() != 3) {
    ++c->crashed;
    c->failures.push_back(absl::StrFormat("%s: signal %d after\n%s", where, r.signal, r.report));
    return;
  }
  bool any_error = false, wrong = false;
  for (const auto& [tool, line] : got) {
    if (line.rfind(tool + " error", 0) == 0) {
      any_error = true;
    } else if (line != reference.at(tool)) {
      wrong = true;
    }
  }
  if (wrong) {
    ++c->wrong;
    c->failures.push_back(
        absl::StrFormat("%s: a different answer with success:\n%s", where, r.report));
  } else if (any_error) {
    ++c->detected;
    if (got.at("verify") == "verify ok") {
      ++c->verify_missed;
      c->failures.push_back(
          absl::StrFormat("%s: verify passed, another tool did not:\n%s", where, r.report));
    }
  } else {
    ++c->harmless;
  }
}

FlipCounts FlipBytes(const std::string& path, uint64_t stride, uint64_t masks, uint64_t phase) {
  const std::string file = path + "/data.mdb";
  const std::vector<uint8_t> good = ReadBytes(file);
  const auto reference = Lines(RunTools(path));
  const std::vector<std::string> regions = PageRegions(good);
  FlipCounts c;
  const int fd = open(file.c_str(), O_WRONLY);
  if (fd < 0) return c;
  for (uint64_t at = phase % stride; at < good.size(); at += stride) {
    for (uint64_t k = 0; k < masks; ++k) {
      const uint8_t mask = k == 0 ? static_cast<uint8_t>(testing_store::SplitMix(at) % 255 + 1)
                                  : (k == 1 ? uint8_t{0x01} : uint8_t{0x80});
      const uint8_t flipped = good[at] ^ mask;
      if (pwrite(fd, &flipped, 1, static_cast<off_t>(at)) != 1) break;
      ++c.flips;
      const testing_common::ChildResult r = RunInChild([&] { return RunTools(path); }, 0, 30);
      const uint64_t detected_before = c.detected;
      Classify(absl::StrFormat("byte %d ^ 0x%02x", at, mask), r, reference, &c);
      auto& region = c.regions[regions[at / kLmdbPage]];
      ++region.first;
      region.second += c.detected - detected_before;
      if (pwrite(fd, &good[at], 1, static_cast<off_t>(at)) != 1) break;
    }
  }
  close(fd);
  return c;
}

void FlipTest(uint32_t page_size, size_t points, uint64_t default_stride) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  BuildSmall(path, page_size, points);
  const uint64_t stride = EnvOr("PBGI_FLIP_STRIDE", default_stride);
  const uint64_t masks = EnvOr("PBGI_FLIP_MASKS", 1);
  const uint64_t bytes = std::filesystem::file_size(path + "/data.mdb");
  const FlipCounts c = FlipBytes(path, stride, masks, EnvOr("PBGI_FLIP_PHASE", 0));
  std::printf(
      "byte flips, page size %u, %llu-byte file, every %llu. byte x %llu masks: %llu flips, "
      "%llu detected (%llu of them by shade or info only), %llu harmless, %llu crashed or hung, "
      "%llu wrong\n",
      page_size, static_cast<unsigned long long>(bytes), static_cast<unsigned long long>(stride),
      static_cast<unsigned long long>(masks), static_cast<unsigned long long>(c.flips),
      static_cast<unsigned long long>(c.detected), static_cast<unsigned long long>(c.verify_missed),
      static_cast<unsigned long long>(c.harmless), static_cast<unsigned long long>(c.crashed),
      static_cast<unsigned long long>(c.wrong));
  for (const auto& [region, n] : c.regions) {
    std::printf("  %s pages: %llu flips, %llu detected\n", region.c_str(),
                static_cast<unsigned long long>(n.first),
                static_cast<unsigned long long>(n.second));
  }
  EXPECT_GT(c.flips, 100u);
  EXPECT_EQ(c.crashed, 0u);
  EXPECT_EQ(c.wrong, 0u);
  EXPECT_EQ(c.verify_missed, 0u) << "verify passed a store that another tool found damaged";
  for (size_t i = 0; i < std::min<size_t>(c.failures.size(), 5); ++i)
    ADD_FAILURE() << c.failures[i];
}

TEST(ByteFlipTest, InlinePagesNeverCrashOrLie) { FlipTest(1024, 1500, 229); }
TEST(ByteFlipTest, OverflowPagesNeverCrashOrLie) { FlipTest(4080, 600, 199); }

// ---------------------------------------------------------------------------------------------
// The crafted-meta sweep: every field of the meta record set to hostile values, each record
// written with a valid checksum. `info` prints whatever the record says (so it is only required
// not to crash); verify and shade either refuse the record or give exactly the undamaged
// answer, and verify never passes a record that shade refuses or shades differently.

struct MetaCase {
  std::string name;
  StoreMeta meta;
};

std::vector<MetaCase> HostileMetas(const StoreMeta& m) {
  std::vector<MetaCase> out;
  auto add = [&](const std::string& name, auto edit) {
    MetaCase c{name, m};
    edit(c.meta);
    out.push_back(std::move(c));
  };
  auto u64s = [](uint64_t v) {
    return std::vector<uint64_t>{0,
                                 1,
                                 v - 1,
                                 v + 1,
                                 v * 2,
                                 v / 2,
                                 uint64_t{1} << 32,
                                 (uint64_t{1} << 32) + v,
                                 uint64_t{1} << 63,
                                 ~uint64_t{0}};
  };
  auto u32s = [](uint32_t v) {
    return std::vector<uint32_t>{0, 1, v - 1, v + 1, v * 2, v / 2, 1u << 31, ~0u};
  };
  const struct {
    const char* name;
    uint64_t StoreMeta::*field;
  } u64_fields[] = {{"point_count", &StoreMeta::point_count},
                    {"node_count", &StoreMeta::node_count},
                    {"node_pages", &StoreMeta::node_pages},
                    {"point_pages", &StoreMeta::point_pages},
                    {"root", &StoreMeta::root}};
  for (const auto& f : u64_fields) {
    for (uint64_t v : u64s(m.*f.field)) {
      add(absl::StrFormat("%s=%d", f.name, v), [&](StoreMeta& x) { x.*f.field = v; });
    }
  }
  const struct {
    const char* name;
    uint32_t StoreMeta::*field;
  } u32_fields[] = {{"version", &StoreMeta::version},  // (the magic is the encoder's own)
                    {"page_size", &StoreMeta::page_size},
                    {"sh_order", &StoreMeta::sh_order},
                    {"leaf_size", &StoreMeta::leaf_size},
                    {"max_depth", &StoreMeta::max_depth}};
  for (const auto& f : u32_fields) {
    for (uint32_t v : u32s(m.*f.field)) {
      add(absl::StrFormat("%s=%d", f.name, v), [&](StoreMeta& x) { x.*f.field = v; });
    }
  }
  add("channels=occlusion", [](StoreMeta& x) { x.channels = Channels::kOcclusion; });
  const float floats[] = {std::nanf(""),
                          std::numeric_limits<float>::infinity(),
                          -std::numeric_limits<float>::infinity(),
                          0.0f,
                          -0.0f,
                          1e-40f,
                          1e30f,
                          -1e30f};
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      const float orig = side == 0 ? m.bounds.lo[axis] : m.bounds.hi[axis];
      std::vector<float> vs(std::begin(floats), std::end(floats));
      vs.push_back(orig * 2.0f);
      vs.push_back(orig - 1.0f);
      vs.push_back(std::nextafter(orig, side == 0 ? 1e30f : -1e30f));  // a hair inside
      for (float v : vs) {
        add(absl::StrFormat("bounds.%s[%d]=%g", side == 0 ? "lo" : "hi", axis, v),
            [&](StoreMeta& x) { (side == 0 ? x.bounds.lo : x.bounds.hi)[axis] = v; });
      }
    }
    add(absl::StrFormat("bounds swapped on axis %d", axis),
        [&](StoreMeta& x) { std::swap(x.bounds.lo[axis], x.bounds.hi[axis]); });
  }
  add("empty bounds", [](StoreMeta& x) { x.bounds = Bounds{}; });
  for (const std::string& layout :
       {std::string(), std::string("zorder"), std::string("no-such-layout"),
        std::string(70000, 'x'), std::string("coherent\0", 9)}) {
    add(absl::StrFormat("layout of %d bytes '%s'", layout.size(),
                        absl::CHexEscape(layout.substr(0, 16))),
        [&](StoreMeta& x) { x.layout = layout; });
  }
  add("no stats", [](StoreMeta& x) { x.stats.clear(); });
  add("a 1 MiB stat", [](StoreMeta& x) { x.stats["huge"] = std::string(1 << 20, 'y'); });
  add("10,000 stats", [](StoreMeta& x) {
    for (int i = 0; i < 10000; ++i) x.stats[absl::StrCat("k", i)] = "v";
  });
  return out;
}

void CraftedMetaSweep(uint32_t page_size, size_t points) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  BuildSmall(path, page_size, points);
  const std::vector<uint8_t> good = ReadBytes(path + "/data.mdb");
  StoreMeta original;
  {
    auto store = PageStore::Open(path);
    ASSERT_TRUE(store.ok());
    original = (*store)->meta();
  }
  const auto reference = Lines(RunTools(path));
  FlipCounts c;
  std::vector<std::string> accepted;
  for (const MetaCase& mc : HostileMetas(original)) {
    WriteBytes(path + "/data.mdb", good);
    RewriteMeta(path, mc.meta);
    ++c.flips;
    const testing_common::ChildResult r = RunInChild([&] { return RunTools(path); }, 0, 30);
    const auto got = Lines(r.report);
    if (!r.exited || got.size() != 3) {
      ++c.crashed;
      c.failures.push_back(absl::StrFormat("%s: signal %d after\n%s", mc.name, r.signal, r.report));
      continue;
    }
    const bool verify_ok = got.at("verify") == "verify ok";
    const bool shade_ok = got.at("shade").rfind("shade ok", 0) == 0;
    if (shade_ok && got.at("shade") != reference.at("shade")) {
      ++c.wrong;
      c.failures.push_back(absl::StrFormat("%s: shaded differently:\n%s", mc.name, r.report));
    } else if (verify_ok && !shade_ok) {
      ++c.verify_missed;
      c.failures.push_back(
          absl::StrFormat("%s: verify passed, shade did not:\n%s", mc.name, r.report));
    } else if (!verify_ok || !shade_ok || got.at("info").rfind("info error", 0) == 0) {
      ++c.detected;
    } else {
      ++c.harmless;
      accepted.push_back(mc.name);
    }
  }
  std::printf(
      "crafted meta records, page size %u: %llu records, %llu refused, %llu accepted "
      "(verify and shade exact), %llu crashed or hung, %llu wrong, %llu passed by verify "
      "only\n",
      page_size, static_cast<unsigned long long>(c.flips),
      static_cast<unsigned long long>(c.detected), static_cast<unsigned long long>(c.harmless),
      static_cast<unsigned long long>(c.crashed), static_cast<unsigned long long>(c.wrong),
      static_cast<unsigned long long>(c.verify_missed));
  std::printf("  accepted: %s\n", absl::StrJoin(accepted, "; ").c_str());
  EXPECT_EQ(c.crashed, 0u);
  EXPECT_EQ(c.wrong, 0u);
  EXPECT_EQ(c.verify_missed, 0u);
  for (size_t i = 0; i < std::min<size_t>(c.failures.size(), 5); ++i)
    ADD_FAILURE() << c.failures[i];
}

TEST(CraftedMetaTest, HostileValuesOfEveryFieldNeverCrashOrLieInline) {
  CraftedMetaSweep(1024, 1500);
}
TEST(CraftedMetaTest, HostileValuesOfEveryFieldNeverCrashOrLieOverflow) {
  CraftedMetaSweep(4080, 600);
}

}  // namespace
}  // namespace pbgi
