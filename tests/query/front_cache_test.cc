// The per-Reader LRU: LRU order, byte budget, pins held in the shared cache.
#include "query/front_cache.h"

#include "gtest/gtest.h"

namespace pbgi::internal {
namespace {

PageCache::Handle Load(PageCache& cache, uint64_t key, uint32_t count) {
  auto load = [&]() -> absl::StatusOr<PageCache::Loaded> {
    auto p = std::make_unique<CachedPage>();
    p->page.section = Section::kPoints;
    p->page.page_no = key;
    p->page.count = count;
    PageCache::Loaded l;
    l.charge = 100;
    l.value = std::move(p);
    return l;
  };
  auto h = cache.Lookup(key, load);
  EXPECT_TRUE(h.ok());
  return std::move(*h);
}

TEST(FrontCacheTest, KeepsMostRecentWithinBudgetAndPinsThem) {
  PageCache shared(10000, 0);
  FrontCache front(300, 16);  // three pages of charge 100
  for (uint64_t k = 1; k <= 3; ++k) front.Insert(k, Load(shared, k, uint32_t(k)));
  EXPECT_EQ(shared.pinned_usage(), 300u);
  ASSERT_NE(front.Find(1), nullptr);  // 2 is now the oldest
  EXPECT_EQ(front.Find(1)->count, 1u);
  front.Insert(4, Load(shared, 4, 4));
  EXPECT_EQ(front.Find(2), nullptr);
  EXPECT_NE(front.Find(1), nullptr);
  EXPECT_NE(front.Find(3), nullptr);
  EXPECT_NE(front.Find(4), nullptr);
  EXPECT_EQ(front.evictions(), 1u);
  EXPECT_EQ(front.used_bytes(), 300u);
  EXPECT_EQ(shared.pinned_usage(), 300u);  // 2's pin was released
  front.Clear();
  EXPECT_EQ(shared.pinned_usage(), 0u);
  EXPECT_EQ(shared.usage(), 400u);  // still in the shared cache
}

TEST(FrontCacheTest, AlwaysHoldsTwoPagesAndManyCyclesDoNotBreakIt) {
  PageCache shared(1 << 20, 0);
  FrontCache front(50, 8);  // budget below one page
  for (uint64_t k = 0; k < 5000; ++k) {
    if (front.Find(k % 13) == nullptr) front.Insert(k % 13, Load(shared, k % 13, 0));
    EXPECT_LE(front.size(), 2u);
  }
  EXPECT_EQ(front.size(), 2u);
}

}  // namespace
}  // namespace pbgi::internal
