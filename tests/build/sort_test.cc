// Morton keys, the radix sort and the external sort (spills, multi-pass merges, stability).
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <random>
#include <vector>

#include "build/external_sort.h"
#include "gtest/gtest.h"
#include "tests/build/test_clouds.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

uint64_t NaiveMorton(uint32_t x, uint32_t y, uint32_t z) {
  uint64_t k = 0;
  for (int b = 0; b < 21; ++b) {
    k |= uint64_t((x >> b) & 1) << (3 * b);
    k |= uint64_t((y >> b) & 1) << (3 * b + 1);
    k |= uint64_t((z >> b) & 1) << (3 * b + 2);
  }
  return k;
}

TEST(MortonTest, EncodeMatchesBitByBitInterleave) {
  std::mt19937_64 rng(1);
  for (int i = 0; i < 10000; ++i) {
    uint32_t x = rng() & 0x1fffff, y = rng() & 0x1fffff, z = rng() & 0x1fffff;
    ASSERT_EQ(MortonEncode(x, y, z), NaiveMorton(x, y, z));
  }
  EXPECT_EQ(MortonEncode(0x1fffff, 0x1fffff, 0x1fffff), (uint64_t{1} << 63) - 1);
}

TEST(MortonTest, PrefixIsTheCellAtThatDepth) {
  uint64_t k = MortonEncode(0x1fffff, 0, 0x100000);
  EXPECT_EQ(KeyPrefix(k, 0), 0u);
  EXPECT_EQ(KeyPrefix(k, 1), 0b101u);  // top bits: x=1, y=0, z=1
  EXPECT_EQ(KeyPrefix(k, 21), k);
}

TEST(MortonTest, BoundsCornersAreInsideAndOrdered) {
  Bounds b;
  b.Extend(glm::vec3(-2, 5, 1e-3f));
  b.Extend(glm::vec3(3, 6, 2));
  MortonQuantizer q(b);
  // The lower corner maps near cell 0 and the upper corner (included) to a valid key.
  uint64_t lo = q.Key(b.lo), hi = q.Key(b.hi);
  EXPECT_LT(lo, hi);
  EXPECT_LT(hi, uint64_t{1} << 63);
  // Along one axis keys grow with the coordinate.
  uint64_t prev = 0;
  for (int i = 0; i <= 100; ++i) {
    uint64_t k = q.Key(glm::vec3(-2.0f + 5.0f * i / 100.0f, 5, 1));
    EXPECT_GE(k, prev);
    prev = k;
  }
}

TEST(MortonTest, FarFromOriginStillSeparatesPoints) {
  Bounds b;
  b.Extend(glm::vec3(1e6f, 1e6f, 1e6f));
  b.Extend(glm::vec3(1e6f + 1.0f, 1e6f + 1.0f, 1e6f + 1.0f));
  MortonQuantizer q(b);
  EXPECT_NE(q.Key(b.lo), q.Key(b.hi));
  EXPECT_NE(q.Key(glm::vec3(1e6f + 0.25f, 1e6f, 1e6f)), q.Key(glm::vec3(1e6f + 0.5f, 1e6f, 1e6f)));
}

TEST(RadixSortTest, MatchesStableSortWithDuplicates) {
  std::mt19937_64 rng(7);
  // Which bits vary: passes whose digit is the same for every key are skipped, so include
  // ranges narrower than a digit, gaps, and all 64 bits.
  const std::vector<std::pair<uint64_t, uint64_t>> masks = {
      {0x7fffffffffffffffull, 0x7f000000000000ffull},
      {0xffffffffffffffffull, 0xff00000000000000ull},
      {0x1full, 0x3ull},
      {0xf0000000000000f0ull, 0x0ull},
      {0x0000ffff00000000ull, 0x0000010000000000ull},
      {0xffffffffffffffffull, 0xffull},  // a bucket of most keys, split down to the last digit
      {0x0ull, 0x0ull}};
  for (size_t n : {0, 1, 2, 17, 5000, 100000}) {
    for (const auto& [mask_a, mask_b] : masks) {
      std::vector<KeyIndex> a(n), s(n);
      for (size_t i = 0; i < n; ++i) {
        // Few distinct high bits, many duplicates.
        uint64_t k = (rng() >> (mask_a == ~uint64_t{0} ? 0 : 1)) & (i % 3 == 0 ? mask_a : mask_b);
        a[i] = {k | 0x0101000000000000ull, i};  // constant bits above, between and below
      }
      std::vector<KeyIndex> want = a;
      std::stable_sort(want.begin(), want.end(),
                       [](const KeyIndex& x, const KeyIndex& y) { return x.key < y.key; });
      KeyIndex* got = RadixSortKeyIndex(absl::MakeSpan(a), absl::MakeSpan(s));
      for (size_t i = 0; i < n; ++i) {
        ASSERT_EQ(got[i].key, want[i].key) << i << " mask " << std::hex << mask_a;
        ASSERT_EQ(got[i].index, want[i].index) << i << " mask " << std::hex << mask_a;
      }
    }
  }
}

std::vector<SortRecord> RandomRecords(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<SortRecord> v(n);
  for (size_t i = 0; i < n; ++i) {
    v[i] = SortRecord{};
    v[i].key = rng() % 997;               // heavy duplication: stability matters
    v[i].radius = static_cast<float>(i);  // remembers the input position
  }
  return v;
}

std::vector<SortRecord> Drain(ExternalSorter& s) {
  std::vector<SortRecord> out, buf(333);
  for (;;) {
    auto n = s.Next(absl::MakeSpan(buf));
    EXPECT_TRUE(n.ok()) << n.status();
    if (!n.ok() || *n == 0) break;
    out.insert(out.end(), buf.begin(), buf.begin() + *n);
  }
  return out;
}

void ExpectStablySorted(const std::vector<SortRecord>& in, const std::vector<SortRecord>& out) {
  std::vector<SortRecord> want = in;
  std::stable_sort(want.begin(), want.end(),
                   [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
  ASSERT_EQ(out.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i) {
    ASSERT_EQ(out[i].key, want[i].key) << i;
    ASSERT_EQ(out[i].radius, want[i].radius) << i;
  }
}

TEST(ExternalSortTest, FitsInMemoryWithoutSpilling) {
  testing_build::ScratchDir dir("sort_fit");
  auto in = RandomRecords(5000, 3);
  ExternalSorter s({dir.path(), 10000, 1 << 20});
  for (const auto& r : in) ASSERT_TRUE(s.Add(r).ok());
  ASSERT_TRUE(s.FinishInput().ok());
  EXPECT_EQ(s.runs_spilled(), 0u);
  EXPECT_EQ(s.spill_bytes(), 0u);
  ExpectStablySorted(in, Drain(s));
}

TEST(ExternalSortTest, SpillsManyRunsAndMergesInSeveralPasses) {
  testing_build::ScratchDir dir("sort_spill");
  auto in = RandomRecords(20000, 4);
  // 100 records per run -> 200 runs; 128 KiB of merge buffers -> fan-in 2 -> several passes.
  ExternalSorter s({dir.path(), 100, 128 << 10});
  for (const auto& r : in) ASSERT_TRUE(s.Add(r).ok());
  ASSERT_TRUE(s.FinishInput().ok());
  EXPECT_EQ(s.runs_spilled(), 200u);
  EXPECT_GE(s.merge_passes(), 5u);
  // Run files are unlinked at creation: nothing is visible in the directory.
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  ExpectStablySorted(in, Drain(s));
}

TEST(ExternalSortTest, SingleMergePassWhenBuffersSuffice) {
  testing_build::ScratchDir dir("sort_onepass");
  auto in = RandomRecords(10000, 5);
  ExternalSorter s({dir.path(), 1000, 64 << 20});
  for (const auto& r : in) ASSERT_TRUE(s.Add(r).ok());
  ASSERT_TRUE(s.FinishInput().ok());
  EXPECT_EQ(s.runs_spilled(), 10u);
  EXPECT_EQ(s.merge_passes(), 0u);
  ExpectStablySorted(in, Drain(s));
}

// The merge's read buffers stay within merge_bytes, and a large merge_bytes does not become
// resident read buffers of a few runs: a run reads at most 8 MiB at a time (docs/design.md,
// "Memory plan"), so the rest of the budget is not held through the whole merge.
TEST(ExternalSortTest, MergeBuffersStayWithinTheirShareAnd8MiBARun) {
  testing_build::ScratchDir dir("sort_merge_bytes");
  auto in = RandomRecords(3000, 6);
  for (uint64_t merge_bytes : {uint64_t{64} << 10, uint64_t{6} << 20, uint64_t{1} << 30}) {
    SCOPED_TRACE(merge_bytes);
    ExternalSorter s({dir.path(), 1000, merge_bytes});
    for (const auto& r : in) ASSERT_TRUE(s.Add(r).ok());
    ASSERT_TRUE(s.FinishInput().ok());
    EXPECT_EQ(s.runs_spilled(), 3u);
    const uint64_t resident = s.merge_resident_bytes();
    EXPECT_GT(resident, 0u);
    EXPECT_LE(resident, std::max<uint64_t>(merge_bytes, 3 * 64 * sizeof(SortRecord)));
    EXPECT_LE(resident, 3 * (uint64_t{8} << 20));
    ExpectStablySorted(in, Drain(s));
  }
}

TEST(ExternalSortTest, MissingTmpDirIsAClearError) {
  ExternalSorter s({"/nonexistent/pbgi/tmp", 10, 1 << 20});
  absl::Status st;
  for (int i = 0; i < 20 && st.ok(); ++i) st = s.Add(SortRecord{});
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("/nonexistent/pbgi/tmp"), std::string::npos) << st;
}

// The background sort thread and the merge thread (Options::threads > 1) change nothing in the
// output: the same records in the same order as one thread, for runs merged in one pass, in
// several passes, and with no spill; NextBlock and Next agree.
TEST(ExternalSortTest, ThreadsGiveTheSameOrderAsOneThread) {
  testing_build::ScratchDir dir("sort_threads");
  auto in = RandomRecords(30000, 9);
  struct Case {
    uint64_t run_capacity, merge_bytes;
  };
  for (Case c : {Case{100, 128 << 10}, Case{1000, 64 << 20}, Case{50000, 1 << 20}}) {
    std::vector<SortRecord> want;
    for (int threads : {1, 2, 3}) {
      SCOPED_TRACE(::testing::Message() << "run " << c.run_capacity << " threads " << threads);
      ExternalSorter s({dir.path(), c.run_capacity, c.merge_bytes, threads});
      // Half through Add, half through Reserve/Commit.
      size_t i = 0;
      for (; i < in.size() / 2; ++i) ASSERT_TRUE(s.Add(in[i]).ok());
      while (i < in.size()) {
        auto slots = s.Reserve(777);
        ASSERT_TRUE(slots.ok()) << slots.status();
        const size_t k = std::min(slots->size(), in.size() - i);
        std::copy(in.begin() + i, in.begin() + i + k, slots->begin());
        s.Commit(k);
        i += k;
      }
      ASSERT_TRUE(s.FinishInput().ok());
      EXPECT_EQ(s.runs_spilled(), c.run_capacity >= in.size() ? 0u : in.size() / c.run_capacity);
      std::vector<SortRecord> got;
      if (threads == 2) {
        got = Drain(s);
      } else {
        for (;;) {
          auto block = s.NextBlock();
          ASSERT_TRUE(block.ok()) << block.status();
          if (block->empty()) break;
          got.insert(got.end(), block->begin(), block->end());
        }
      }
      ExpectStablySorted(in, got);
      if (threads == 1) {
        want = got;
      } else {
        ASSERT_EQ(got.size(), want.size());
        EXPECT_EQ(0, std::memcmp(got.data(), want.data(), got.size() * sizeof(SortRecord)));
      }
      EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
    }
  }
}

// An error on the sort thread (the run file cannot be created) reaches the caller with the
// directory's name, at the latest from FinishInput; nothing hangs.
TEST(ExternalSortTest, SpillErrorOnTheSortThreadIsReported) {
  ExternalSorter s({"/nonexistent/pbgi/tmp", 10, 1 << 20, 2});
  absl::Status st;
  for (int i = 0; i < 50 && st.ok(); ++i) st = s.Add(SortRecord{});
  if (st.ok()) st = s.FinishInput();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("/nonexistent/pbgi/tmp"), std::string::npos) << st;
}

}  // namespace
}  // namespace pbgi::internal
