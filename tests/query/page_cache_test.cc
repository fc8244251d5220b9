// The shared page cache: eviction order, pinning, charge, single flight, failed loads
// (in the manner of LevelDB's CacheTest, which records every deletion).
#include "query/page_cache.h"

#include <atomic>
#include <chrono>
#include <thread>
#include <utility>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace pbgi::internal {
namespace {

class CacheTest : public ::testing::Test {
 protected:
  // A value that records its deletion in the fixture.
  struct Value : CacheValue {
    Value(CacheTest* t, uint64_t k) : test(t), key(k) {}
    ~Value() override { test->deleted_.push_back(key); }
    CacheTest* test;
    uint64_t key;
  };

  // Looks `key` up, loading a Value of `charge` on a miss.
  absl::StatusOr<PageCache::Handle> Get(PageCache& cache, uint64_t key, uint64_t charge = 1,
                                        PageCache::Outcome* outcome = nullptr) {
    auto load = [&]() -> absl::StatusOr<PageCache::Loaded> {
      ++loads_;
      return PageCache::Loaded{std::make_unique<Value>(this, key), charge};
    };
    return cache.Lookup(key, load, outcome);
  }
  // Looks up and releases at once.
  void Touch(PageCache& cache, uint64_t key, uint64_t charge = 1) {
    ASSERT_TRUE(Get(cache, key, charge).ok());
  }
  bool Cached(PageCache& cache, uint64_t key) {
    PageCache::Outcome o;
    auto h = Get(cache, key, 1, &o);
    return h.ok() && o == PageCache::Outcome::kHit;
  }

  std::vector<uint64_t> deleted_;
  int loads_ = 0;
};

TEST_F(CacheTest, HitAfterMissAndValueIsTheLoadedOne) {
  PageCache cache(100, 0);
  PageCache::Outcome o;
  auto h = Get(cache, 7, 1, &o);
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(o, PageCache::Outcome::kLoaded);
  EXPECT_EQ(static_cast<const Value*>(h->value())->key, 7u);
  auto h2 = Get(cache, 7, 1, &o);
  ASSERT_TRUE(h2.ok());
  EXPECT_EQ(o, PageCache::Outcome::kHit);
  EXPECT_EQ(h2->value(), h->value());
  EXPECT_EQ(loads_, 1);
  auto c = cache.counters();
  EXPECT_EQ(c.hits, 1u);
  EXPECT_EQ(c.misses, 1u);
  EXPECT_EQ(c.loads, 1u);
}

// calls() counts every lookup and every unpin: what Database::SharedCacheCalls() reports.
TEST_F(CacheTest, CallsCountLookupsAndReleases) {
  PageCache cache(100, 2);
  EXPECT_EQ(cache.counters().calls(), 0u);
  {
    auto h = Get(cache, 1);
    ASSERT_TRUE(h.ok());
    EXPECT_EQ(cache.counters().calls(), 1u);  // the miss
    auto h2 = Get(cache, 1);
    ASSERT_TRUE(h2.ok());
    EXPECT_EQ(cache.counters().calls(), 2u);  // and the hit
    EXPECT_EQ(cache.counters().releases, 0u);
    PageCache::Handle moved = std::move(*h2);  // a move is not a call
    EXPECT_EQ(cache.counters().calls(), 2u);
  }
  const PageCache::Counters c = cache.counters();
  EXPECT_EQ(c.releases, 2u);
  EXPECT_EQ(c.calls(), 4u);
}

TEST_F(CacheTest, EvictsLeastRecentlyUsedFirst) {
  PageCache cache(3, 0);  // three entries of charge 1
  Touch(cache, 1);
  Touch(cache, 2);
  Touch(cache, 3);
  Touch(cache, 1);  // 2 is now the oldest
  Touch(cache, 4);
  EXPECT_THAT(deleted_, ::testing::ElementsAre(2u));
  Touch(cache, 5);
  EXPECT_THAT(deleted_, ::testing::ElementsAre(2u, 3u));
  EXPECT_EQ(cache.entries(), 3u);
  EXPECT_EQ(cache.usage(), 3u);
  EXPECT_EQ(cache.counters().evictions, 2u);
}

TEST_F(CacheTest, ChargeCountsBytesNotEntries) {
  PageCache cache(10, 0);
  Touch(cache, 1, 4);
  Touch(cache, 2, 4);
  EXPECT_EQ(cache.usage(), 8u);
  Touch(cache, 3, 4);  // 12 > 10: evict 1
  EXPECT_THAT(deleted_, ::testing::ElementsAre(1u));
  EXPECT_EQ(cache.usage(), 8u);
  Touch(cache, 4, 9);  // evicts 2 and 3
  EXPECT_THAT(deleted_, ::testing::ElementsAre(1u, 2u, 3u));
  EXPECT_EQ(cache.usage(), 9u);
}

TEST_F(CacheTest, PinnedEntriesAreNeverEvicted) {
  PageCache cache(2, 0);
  auto pinned = Get(cache, 1);
  ASSERT_TRUE(pinned.ok());
  for (uint64_t k = 10; k < 20; ++k) Touch(cache, k);
  EXPECT_THAT(deleted_, ::testing::Not(::testing::Contains(1u)));
  EXPECT_EQ(static_cast<const Value*>(pinned->value())->key, 1u);
  EXPECT_EQ(cache.pinned_usage(), 1u);
  // Over capacity while pinned: releasing the pin lets the cache get back under it.
  auto a = Get(cache, 30);
  auto b = Get(cache, 31);
  EXPECT_EQ(cache.usage(), 3u);
  pinned->Release();
  EXPECT_EQ(cache.usage(), 2u);
  EXPECT_EQ(cache.pinned_usage(), 2u);
  EXPECT_THAT(deleted_, ::testing::Contains(1u));
}

TEST_F(CacheTest, HandleMoveKeepsOnePin) {
  PageCache cache(1, 0);
  PageCache::Handle h;
  {
    auto got = Get(cache, 1);
    ASSERT_TRUE(got.ok());
    h = std::move(*got);
  }
  EXPECT_EQ(cache.pinned_usage(), 1u);
  PageCache::Handle h2 = std::move(h);
  EXPECT_FALSE(h);
  EXPECT_TRUE(h2);
  h2.Release();
  EXPECT_EQ(cache.pinned_usage(), 0u);
  EXPECT_TRUE(deleted_.empty());  // still cached, just evictable
  Touch(cache, 2);
  EXPECT_THAT(deleted_, ::testing::ElementsAre(1u));
}

TEST_F(CacheTest, FailedLoadsAreNotCached) {
  PageCache cache(10, 0);
  int calls = 0;
  auto fail = [&]() -> absl::StatusOr<PageCache::Loaded> {
    ++calls;
    return absl::DataLossError("nodes page 3 is corrupt");
  };
  auto h = cache.Lookup(3, fail);
  EXPECT_EQ(h.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(h.status().message()), ::testing::HasSubstr("page 3"));
  EXPECT_EQ(cache.entries(), 0u);
  EXPECT_EQ(cache.usage(), 0u);
  h = cache.Lookup(3, fail);
  EXPECT_FALSE(h.ok());
  EXPECT_EQ(calls, 2);  // tried again
  Touch(cache, 3);      // and a good load then succeeds
  EXPECT_TRUE(Cached(cache, 3));
  EXPECT_EQ(cache.counters().failed_loads, 2u);
}

TEST_F(CacheTest, PruneDropsOnlyUnpinned) {
  PageCache cache(10, 0);
  auto keep = Get(cache, 1);
  Touch(cache, 2);
  Touch(cache, 3);
  cache.Prune();
  EXPECT_THAT(deleted_, ::testing::UnorderedElementsAre(2u, 3u));
  EXPECT_EQ(cache.entries(), 1u);
}

TEST(MixKeyTest, NeighbouringPagesSpreadOverShards) {
  // 1024 consecutive keys over 16 shards: each gets a fair share, none more than twice it.
  std::vector<int> count(16, 0);
  for (uint64_t k = 0; k < 1024; ++k) ++count[MixKey(k) >> 60];
  for (int c : count) {
    EXPECT_GT(c, 32);
    EXPECT_LT(c, 128);
  }
}

TEST(ShardBitsTest, SmallCachesUseFewShards) {
  EXPECT_EQ(PageCache::DefaultShardBits(4 * 65536, 65536), 0);
  EXPECT_EQ(PageCache::DefaultShardBits(uint64_t{1} << 30, 65536), 4);
}

TEST_F(CacheTest, ShardedCacheKeepsItsCapacity) {
  PageCache cache(64, 2);
  for (uint64_t k = 0; k < 1000; ++k) Touch(cache, k);
  EXPECT_LE(cache.usage(), 64u);
  EXPECT_GE(cache.usage(), 40u);
}

// Two threads that miss the same page read it once: the second waits for the first's load.
TEST(SingleFlightTest, ConcurrentMissesLoadOnce) {
  PageCache cache(1 << 20, 2);
  std::atomic<int> loads{0};
  struct V : CacheValue {};
  constexpr int kThreads = 8;
  for (uint64_t key = 0; key < 20; ++key) {
    std::vector<std::thread> threads;
    std::atomic<int> ready{0};
    std::atomic<int> ok{0};
    for (int t = 0; t < kThreads; ++t) {
      threads.emplace_back([&] {
        ready.fetch_add(1);
        while (ready.load() < kThreads) std::this_thread::yield();
        auto slow_load = [&]() -> absl::StatusOr<PageCache::Loaded> {
          loads.fetch_add(1);
          std::this_thread::sleep_for(std::chrono::milliseconds(20));
          return PageCache::Loaded{std::make_unique<V>(), 100};
        };
        auto h = cache.Lookup(key, slow_load);
        if (h.ok() && h->value() != nullptr) ok.fetch_add(1);
      });
    }
    for (auto& t : threads) t.join();
    EXPECT_EQ(ok.load(), kThreads);
  }
  EXPECT_EQ(loads.load(), 20);
  auto c = cache.counters();
  EXPECT_EQ(c.misses, 20u);
  EXPECT_EQ(c.hits + c.waits, 20u * (kThreads - 1));
  EXPECT_GT(c.waits, 0u);
}

// Waiters of a failed load get its error; nothing is cached; a later lookup loads again.
TEST(SingleFlightTest, WaitersShareAFailureThatIsNotCached) {
  PageCache cache(1 << 20, 0);
  std::atomic<int> loads{0};
  std::atomic<bool> started{false};
  std::atomic<int> failures{0};
  auto failing = [&]() -> absl::StatusOr<PageCache::Loaded> {
    loads.fetch_add(1);
    started.store(true);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    return absl::DataLossError("points page 9 is corrupt");
  };
  std::thread first([&] {
    if (!cache.Lookup(9, failing).ok()) failures.fetch_add(1);
  });
  while (!started.load()) std::this_thread::yield();
  std::vector<std::thread> waiters;
  for (int i = 0; i < 4; ++i) {
    waiters.emplace_back([&] {
      auto h = cache.Lookup(9, failing);
      if (!h.ok()) {
        EXPECT_THAT(std::string(h.status().message()), ::testing::HasSubstr("page 9"));
        failures.fetch_add(1);
      }
    });
  }
  first.join();
  for (auto& t : waiters) t.join();
  EXPECT_EQ(failures.load(), 5);
  // Waiters that arrived during the load shared it; any that came after it failed loaded anew.
  EXPECT_GE(loads.load(), 1);
  EXPECT_EQ(cache.entries(), 0u);
  struct V : CacheValue {};
  auto good = [&]() -> absl::StatusOr<PageCache::Loaded> {
    return PageCache::Loaded{std::make_unique<V>(), 1};
  };
  EXPECT_TRUE(cache.Lookup(9, good).ok());
  EXPECT_EQ(cache.entries(), 1u);
}

}  // namespace
}  // namespace pbgi::internal
