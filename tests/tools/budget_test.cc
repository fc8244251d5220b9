// The shade step's budget (tools/budget.h): --cache split into what the process holds, the
// job (a view's pixels, a chunk of receivers) and the page cache, and the refusal of a budget
// that leaves too few pages, naming every part and the budget that does.
#include "tools/budget.h"

#include <string>

#include "gtest/gtest.h"

namespace pbgi::tools {
namespace {

constexpr uint64_t kMiB = uint64_t{1} << 20;

TEST(ShadeBudgetTest, TheCacheGetsWhatTheProcessAndTheViewLeave) {
  // The demo: --cache 1536M, a 2400x1350 view, the process at 100 MiB.
  const uint64_t view = ViewJobBytes(2400, 1350);
  EXPECT_EQ(view, uint64_t{829440000});  // 256 bytes a pixel
  EXPECT_EQ(ViewJobWhat(2400, 1350), "the view's 2400x1350 pixels (256 bytes each)");
  auto b = SplitShadeBudget("--cache", "1536M", 1536 * kMiB, 100 * kMiB, view, "the process",
                            "the view", 2, 32768);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->total, 1536 * kMiB);
  EXPECT_EQ(b->resident, 100 * kMiB);
  EXPECT_EQ(b->job, view);
  EXPECT_EQ(b->cache, 1536 * kMiB - 100 * kMiB - view);
  EXPECT_EQ(b->resident + b->job + b->cache, b->total);
  EXPECT_EQ(DescribeShadeBudget(*b, "the process", "the view"),
            "1.5 GiB: 100.0 MiB held by the process, 791.0 MiB for the view, 645.0 MiB for the "
            "page cache");
  // `pbgi shade` counts no resident part, and its line names none.
  auto s = SplitShadeBudget("--cache", "256M", 256 * kMiB, 0, 64 * kMiB, "", "a chunk", 2, 4096);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(s->cache, 192 * kMiB);
  EXPECT_EQ(DescribeShadeBudget(*s, "", "a chunk"),
            "256.0 MiB: 64.0 MiB for a chunk, 192.0 MiB for the page cache");
}

TEST(ShadeBudgetTest, ExactlyTheSmallestCacheIsAccepted) {
  const uint64_t min_cache = MinShadeCacheBytes(4, 32768);
  EXPECT_EQ(min_cache, uint64_t{4} * 4 * 32768);
  EXPECT_EQ(MinShadeCacheBytes(1, 1024), uint64_t{4} * 4096);  // pages count 4 KiB at least
  EXPECT_EQ(MinShadeCacheBytes(0, 4096), uint64_t{4} * 4096);  // at least one thread
  const uint64_t resident = 70 * kMiB, job = 10 * kMiB;
  auto fits = SplitShadeBudget("--cache", "x", resident + job + min_cache, resident, job, "p", "v",
                               4, 32768);
  ASSERT_TRUE(fits.ok()) << fits.status();
  EXPECT_EQ(fits->cache, min_cache);
  auto short_by_one = SplitShadeBudget("--cache", "x", resident + job + min_cache - 1, resident,
                                       job, "p", "v", 4, 32768);
  EXPECT_EQ(short_by_one.status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(ShadeBudgetTest, ATooSmallBudgetIsRefusedNamingEachPart) {
  // The view alone is more than the budget: nothing is left for pages.
  const uint64_t view = ViewJobBytes(2400, 1350);
  auto b = SplitShadeBudget("--cache", "800M", 800 * kMiB, 90 * kMiB, view,
                            "the process (its code, the scene and its tracer)",
                            ViewJobWhat(2400, 1350), 2, 32768);
  ASSERT_EQ(b.status().code(), absl::StatusCode::kInvalidArgument);
  const std::string m(b.status().message());
  EXPECT_NE(m.find("--cache 800M leaves 0 B for pages after the 791.0 MiB of the view's "
                   "2400x1350 pixels (256 bytes each) and the 90.0 MiB held by the process (its "
                   "code, the scene and its tracer)"),
            std::string::npos)
      << m;
  EXPECT_NE(m.find("less than the 256.0 KiB that 2 threads need (4 pages of 32768 bytes each)"),
            std::string::npos)
      << m;
  // The budget it names is the smallest that is accepted.
  const uint64_t kib = (90 * kMiB + view + MinShadeCacheBytes(2, 32768) + 1023) / 1024;
  EXPECT_NE(m.find("give at least --cache " + std::to_string(kib) + "K"), std::string::npos) << m;
  auto given = SplitShadeBudget("--cache", "y", kib * 1024, 90 * kMiB, view, "p", "v", 2, 32768);
  EXPECT_TRUE(given.ok()) << given.status();
  // Without a resident part the message names the job alone.
  auto s = SplitShadeBudget("--cache", "1500K", 1500 * 1024, 0, 1024 * kShadeBytesPerReceiver, "",
                            "a chunk of 1024 receivers", 16, 32768);
  ASSERT_FALSE(s.ok());
  const std::string n(s.status().message());
  EXPECT_NE(n.find("after the 352.0 KiB of a chunk of 1024 receivers, less than"),
            std::string::npos)
      << n;
  EXPECT_EQ(n.find("held by"), std::string::npos) << n;
}

}  // namespace
}  // namespace pbgi::tools
