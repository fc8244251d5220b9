// Gather over the in-memory fake store: the cut against brute force, small caches, threads,
// corrupt pages, counters, batches. (gather_db_test.cc does the same over real LMDB databases.)
#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <set>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"
#include "query/database_internal.h"
#include "tests/query/fake_db.h"
#include "tree/cut.h"
#include "tree/format.h"

// Counts allocations, to check that a warm gather makes none. (GCC pairs the inlined malloc
// and free of these replacements with the callers' new and delete and warns; they do match.)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
static std::atomic<uint64_t> g_allocations{0};
void* operator new(size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, size_t) noexcept { std::free(p); }
// Every other form too, so that nothing a sanitizer's runtime allocates is freed here (ASan
// reported std::stable_sort's nothrow buffer as an alloc-dealloc mismatch).
void* operator new[](size_t n) { return operator new(n); }
void* operator new(size_t n, const std::nothrow_t&) noexcept {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(n == 0 ? 1 : n);
}
void* operator new[](size_t n, const std::nothrow_t& t) noexcept { return operator new(n, t); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete[](void* p, size_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }

namespace pbgi {
namespace {

using internal::BuildFakeDb;
using internal::FakeDb;
using internal::FakeDbOptions;
using internal::MemPageStore;
using internal::NodeCutCosine;

std::unique_ptr<Database> Open(FakeDb& fake, uint64_t cache_bytes = 64 << 20,
                               uint64_t reader_bytes = 0) {
  DatabaseOptions o;
  o.cache_bytes = cache_bytes;
  o.reader_cache_bytes = reader_bytes;
  auto db = internal::OpenDatabase(std::move(fake.source), o);
  EXPECT_TRUE(db.ok()) << db.status();
  return std::move(*db);
}

// Half random receivers in and around the scene, half on surfels (as a renderer shades them).
std::vector<Receiver> Receivers(const std::vector<Surfel>& surfels, size_t n, uint64_t seed) {
  std::vector<Receiver> r = testing::RandomReceivers(n / 2, seed);
  for (size_t i = 0; r.size() < n; ++i) {
    const Surfel& s = surfels[(i * 7919 + seed) % surfels.size()];
    r.push_back({s.position + 1e-4f * s.normal, s.normal});
  }
  return r;
}

// A comparable digest of a result.
std::vector<std::tuple<uint64_t, uint64_t, int>> Digest(const Gathered& g) {
  std::vector<std::tuple<uint64_t, uint64_t, int>> d;
  for (const Cluster& c : g.clusters) d.emplace_back(c.first_point, c.point_count, 0);
  for (uint64_t id : g.surfel_ids) d.emplace_back(id, 1, 1);
  return d;
}

struct Config {
  uint32_t leaf_size;
  uint32_t page_size;
  Channels channels;
};

// A random scene in a fake database of the parameter's layout, and a Reader of it.
class GatherFakeTest : public ::testing::TestWithParam<Config> {
 protected:
  void SetUp() override {
    const Config cfg = GetParam();
    FakeDb fake = BuildFakeDb(testing::RandomSceneSurfels(3000, 11),
                              {cfg.leaf_size, cfg.page_size, cfg.channels});
    surfels = fake.surfels;
    db = Open(fake);
    auto r = db->NewReader();
    ASSERT_TRUE(r.ok());
    reader = std::move(*r);
  }
  std::vector<Surfel> surfels;  // in database order
  std::unique_ptr<Database> db;
  std::unique_ptr<Reader> reader;
};

TEST_P(GatherFakeTest, CutIsValidAgainstBruteForce) {
  Gathered coarse, fine, exact, near;
  const Cut coarse_cut{0.3f}, fine_cut{0.03f}, exact_cut{0.0f}, near_cut{0.03f, 0.25f};
  size_t clusters = 0;
  for (const Receiver& r : Receivers(surfels, 800, 5)) {
    ASSERT_TRUE(reader->Gather(r, coarse_cut, &coarse).ok());
    ASSERT_TRUE(reader->Gather(r, fine_cut, &fine).ok());
    ASSERT_TRUE(reader->Gather(r, exact_cut, &exact).ok());
    ASSERT_TRUE(reader->Gather(r, near_cut, &near).ok());
    absl::Status s = testing::CheckValidCut(coarse, surfels, r, coarse_cut);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckValidCut(fine, surfels, r, fine_cut);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckValidCut(near, surfels, r, near_cut);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckFinerCutNotSmaller(coarse, fine, surfels, r, coarse_cut, fine_cut);
    ASSERT_TRUE(s.ok()) << s;
    // max_solid_angle = 0: exactly the surfels in front, each on its own.
    EXPECT_TRUE(exact.clusters.empty());
    std::vector<uint64_t> ids = exact.surfel_ids;
    std::sort(ids.begin(), ids.end());
    ASSERT_EQ(ids, testing::SurfelsInFront(surfels, r, exact_cut));
    clusters += coarse.clusters.size();
  }
  EXPECT_GT(clusters, 800u);  // the cut does cluster
}

// The flat clusters of `plain` (NodeIsFlat), and how many of them `refined` holds whole (the
// same point range).
size_t FlatClusters(const Gathered& plain) {
  size_t n = 0;
  for (const Cluster& c : plain.clusters) {
    n += internal::NodeIsFlat(c.sh_area.data(), c.bounds.lo, c.bounds.hi) ? 1 : 0;
  }
  return n;
}
size_t FlatClustersKept(const Gathered& plain, const Gathered& refined) {
  size_t kept = 0;
  for (const Cluster& c : plain.clusters) {
    if (!internal::NodeIsFlat(c.sh_area.data(), c.bounds.lo, c.bounds.hi)) continue;
    for (const Cluster& d : refined.clusters) {
      if (d.first_point == c.first_point && d.point_count == c.point_count) {
        ++kept;
        break;
      }
    }
  }
  return kept;
}

// Cut::curved_scale: the curved nodes' cut is finer, the flat ones' the same; the harness checks
// the gather against the scaled criterion (a gather that ignored it fails the check).
TEST_P(GatherFakeTest, CurvedScaleRefinesTheCurvedNodesOnly) {
  Gathered plain, curved;
  const Cut plain_cut{0.03f};
  Cut curved_cut = plain_cut;
  curved_cut.curved_scale = 0.25f;
  size_t more = 0, caught = 0;
  for (const Receiver& r : Receivers(surfels, 400, 9)) {
    ASSERT_TRUE(reader->Gather(r, plain_cut, &plain).ok());
    ASSERT_TRUE(reader->Gather(r, curved_cut, &curved).ok());
    absl::Status s = testing::CheckValidCut(curved, surfels, r, curved_cut);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckFinerCutNotSmaller(plain, curved, surfels, r, plain_cut, curved_cut);
    ASSERT_TRUE(s.ok()) << s;
    more += curved.size() > plain.size();
    caught += !testing::CheckValidCut(plain, surfels, r, curved_cut).ok();
    // Flat clusters of the plain cut (with nothing standing on them) stay whole in the curved one.
    EXPECT_EQ(FlatClustersKept(plain, curved), FlatClusters(plain));
  }
  EXPECT_GT(more, 100u);
  EXPECT_GT(caught, 10u);
}

// Cut::curved_box_scale: a curved node is also taken whole only when its box subtends below
// the scaled max solid angle; flat nodes are kept as they were. The harness checks the gather
// against the box test (a gather that ignored it fails the check), and the cut refines the one
// without it.
TEST_P(GatherFakeTest, CurvedBoxScaleRefinesTheCurvedNodesOnly) {
  Gathered plain, boxed;
  Cut plain_cut{0.03f};
  plain_cut.cosine_weighted = true;
  plain_cut.curved_scale = 0.3f;
  Cut box_cut = plain_cut;
  box_cut.curved_box_scale = 1.0f;
  size_t more = 0, caught = 0;
  for (const Receiver& r : Receivers(surfels, 400, 13)) {
    ASSERT_TRUE(reader->Gather(r, plain_cut, &plain).ok());
    ASSERT_TRUE(reader->Gather(r, box_cut, &boxed).ok());
    absl::Status s = testing::CheckValidCut(boxed, surfels, r, box_cut);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckFinerCutNotSmaller(plain, boxed, surfels, r, plain_cut, box_cut);
    ASSERT_TRUE(s.ok()) << s;
    more += boxed.size() > plain.size();
    caught += !testing::CheckValidCut(plain, surfels, r, box_cut).ok();
    for (const Cluster& c : boxed.clusters) {
      if (internal::NodeIsFlat(c.sh_area.data(), c.bounds.lo, c.bounds.hi)) continue;
      const glm::vec3 centre = 0.5f * (c.bounds.lo + c.bounds.hi);
      const internal::NearSphere near =
          internal::NodeNearSphere(c.bounds.lo, c.bounds.hi, internal::NodeReach(c.area));
      const glm::vec3 n = glm::normalize(r.normal);
      EXPECT_LT(internal::NodeBoxSolidAngleFrom(centre, c.bounds.lo, c.bounds.hi, r.position) *
                    NodeCutCosine(near.centre, near.radius2, r.position, n),
                box_cut.max_solid_angle);
    }
    // Flat clusters of the plain cut (with nothing standing on them) stay whole.
    EXPECT_EQ(FlatClustersKept(plain, boxed), FlatClusters(plain));
  }
  EXPECT_GT(more, 20u);
  EXPECT_GT(caught, 10u);
  // A negative or non-finite scale is refused.
  Cut bad = box_cut;
  bad.curved_box_scale = -1.0f;
  EXPECT_EQ(reader->Gather(Receivers(surfels, 1, 1)[0], bad, &boxed).code(),
            absl::StatusCode::kInvalidArgument);
}

// NodeCutCosine against brute force: the largest cosine to the normal over many points of the
// sphere's surface (where the maximum lies), for spheres all around the receiver.
TEST(CutCosine, BoundsTheSphereTightlyAndHasItsAnalyticValues) {
  const glm::vec3 p(0.2f, -0.1f, 0.3f), n = glm::normalize(glm::vec3(0.3f, -0.2f, 1.0f));
  uint64_t state = 12345;
  auto uniform = [&] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>(state >> 40) / static_cast<float>(1 << 24);
  };
  auto unit = [&] {
    for (;;) {
      const glm::vec3 v(2 * uniform() - 1, 2 * uniform() - 1, 2 * uniform() - 1);
      const float l2 = glm::dot(v, v);
      if (l2 > 1e-4f && l2 <= 1.0f) return v / std::sqrt(l2);
    }
  };
  int clamped = 0, inside = 0;
  for (int k = 0; k < 2000; ++k) {
    const float dist = 0.5f + 4.0f * uniform();
    const float radius = dist * (0.02f + 0.9f * uniform());
    const glm::vec3 c = p + dist * unit();
    const float got = NodeCutCosine(c, radius * radius, p, n);
    float best = -1.0f;
    for (int i = 0; i < 4000; ++i) {
      const glm::vec3 v = c + radius * unit() - p;
      best = std::max(best, glm::dot(v, n) / glm::length(v));
    }
    const float want = std::clamp(best, kMinCutCosine, 1.0f);
    ASSERT_GE(got, want - 1e-5f) << "k " << k;  // a bound: never below the sphere's cosines
    ASSERT_LE(got, want + 0.02f) << "k " << k;  // and a tight one
    clamped += got == kMinCutCosine ? 1 : 0;
    inside += got == 1.0f ? 1 : 0;
  }
  EXPECT_GT(clamped, 50);  // both clamps were exercised
  EXPECT_GT(inside, 50);
  // Analytic: a small sphere centred on the horizon at distance d gives sin(alpha) = r / d; one
  // on the normal gives 1; a receiver inside the sphere gives 1.
  const glm::vec3 t = glm::normalize(glm::cross(n, glm::vec3(1, 0, 0)));
  EXPECT_NEAR(NodeCutCosine(p + 2.0f * t, 0.3f * 0.3f, p, n), 0.15f, 1e-5f);
  EXPECT_EQ(NodeCutCosine(p + 2.0f * n, 0.01f, p, n), 1.0f);
  EXPECT_EQ(NodeCutCosine(p + 0.1f * t, 0.04f, p, n), 1.0f);
  EXPECT_EQ(NodeCutCosine(p - 2.0f * n, 0.01f, p, n), kMinCutCosine);
}

// The cosine-weighted cut: valid against brute force, coarser than the plain cut at the same
// max_solid_angle (which refines it), and never the same as it (it does coarsen).
TEST_P(GatherFakeTest, CosineWeightedCutIsValidAndCoarsensThePlainOne) {
  Cut plain{0.03f}, cosine{0.03f}, cosine_near{0.03f, 0.25f};
  cosine.cosine_weighted = cosine_near.cosine_weighted = true;
  Gathered gp, gc, gn;
  size_t plain_elements = 0, cosine_elements = 0, rejected_as_plain = 0;
  for (const Receiver& r : Receivers(surfels, 800, 5)) {
    ASSERT_TRUE(reader->Gather(r, plain, &gp).ok());
    ASSERT_TRUE(reader->Gather(r, cosine, &gc).ok());
    ASSERT_TRUE(reader->Gather(r, cosine_near, &gn).ok());
    absl::Status s = testing::CheckValidCut(gc, surfels, r, cosine);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckValidCut(gn, surfels, r, cosine_near);
    ASSERT_TRUE(s.ok()) << s;
    s = testing::CheckFinerCutNotSmaller(gc, gp, surfels, r, cosine, plain);
    ASSERT_TRUE(s.ok()) << s;
    plain_elements += gp.size();
    cosine_elements += gc.size();
    // The harness tells the two criteria apart.
    rejected_as_plain += testing::CheckValidCut(gc, surfels, r, plain).ok() ? 0 : 1;
  }
  EXPECT_LT(cosine_elements, plain_elements);
  EXPECT_GT(rejected_as_plain, 100);
}

INSTANTIATE_TEST_SUITE_P(LeafAndPageSizes, GatherFakeTest,
                         ::testing::Values(Config{1, 4096 - 16, Channels::kRadiance},
                                           Config{8, 4096 - 16, Channels::kRadiance},
                                           Config{16, 2 * 4096 - 16, Channels::kOcclusion},
                                           Config{32, 1024, Channels::kOcclusion},
                                           Config{4, 600, Channels::kRadiance}),
                         [](const ::testing::TestParamInfo<Config>& info) {
                           return "leaf" + std::to_string(info.param.leaf_size) + "_page" +
                                  std::to_string(info.param.page_size) +
                                  (HasRadiance(info.param.channels) ? "_radiance" : "_occlusion");
                         });

TEST(GatherFake, FarReceiverGathersFewClustersNearOneDescends) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(2000, 3);
  FakeDb fake = BuildFakeDb(input, {});
  auto db = Open(fake);
  auto reader = db->NewReader();
  Gathered g;
  // Far away, facing the scene: a handful of clusters stand for everything.
  Receiver far{{0.5f, 0.5f, 30.0f}, {0, 0, -1}};
  ASSERT_TRUE((*reader)->Gather(far, Cut{}, &g).ok());
  EXPECT_GE(g.clusters.size(), 1u);
  EXPECT_LE(g.size(), 8u);
  // Facing away: nothing.
  ASSERT_TRUE((*reader)->Gather({{0.5f, 0.5f, 30.0f}, {0, 0, 1}}, Cut{}, &g).ok());
  EXPECT_EQ(g.size(), 0u);
  // A receiver beyond max_distance of everything: nothing.
  ASSERT_TRUE((*reader)->Gather(far, Cut{0.03f, 5.0f}, &g).ok());
  EXPECT_EQ(g.size(), 0u);
}

TEST(GatherFake, BadReceiverIsAnError) {
  FakeDb fake = BuildFakeDb(testing::RandomSceneSurfels(500, 3), {});
  auto db = Open(fake);
  auto reader = db->NewReader();
  Gathered g;
  EXPECT_EQ((*reader)->Gather({{0.5f, 0.5f, 0.5f}, {0, 0, 0}}, Cut{}, &g).code(),
            absl::StatusCode::kInvalidArgument);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ((*reader)->Gather({{nan, 0.5f, 0.5f}, {0, 0, 1}}, Cut{}, &g).code(),
            absl::StatusCode::kInvalidArgument);
  // A normal that is not unit length is normalized.
  Gathered unit;
  ASSERT_TRUE((*reader)->Gather({{0.5f, 0.5f, -1.0f}, {0, 0, 5}}, Cut{}, &g).ok());
  ASSERT_TRUE((*reader)->Gather({{0.5f, 0.5f, -1.0f}, {0, 0, 1}}, Cut{}, &unit).ok());
  EXPECT_EQ(Digest(g), Digest(unit));
  EXPECT_GT(g.size(), 0u);
}

TEST(GatherFake, RadianceClustersCarryPowerOcclusionOnesDoNot) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(1000, 4);
  for (auto channels : {Channels::kRadiance, Channels::kOcclusion}) {
    FakeDb fake = BuildFakeDb(input, {8, 4096 - 16, channels});
    auto db = Open(fake);
    auto reader = db->NewReader();
    Gathered g;
    ASSERT_TRUE((*reader)->Gather({{0.5f, 0.5f, 5.0f}, {0, 0, -1}}, Cut{0.5f}, &g).ok());
    ASSERT_FALSE(g.clusters.empty());
    float power = 0;
    for (const Cluster& c : g.clusters) power += std::abs(c.sh_power[0][0]);
    if (channels == Channels::kRadiance) {
      EXPECT_GT(power, 0.0f);
    } else {
      EXPECT_EQ(power, 0.0f);
    }
  }
}

// A budget of a few pages thrashes but answers exactly as an unlimited one.
TEST(GatherFake, TinyCacheAnswersLikeABigOne) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(3000, 8);
  FakeDb big_fake = BuildFakeDb(input, {8, 1024, Channels::kRadiance});
  FakeDb small_fake = BuildFakeDb(input, {8, 1024, Channels::kRadiance});
  auto big = Open(big_fake, 64 << 20);
  auto small = Open(small_fake, 3 * 1024, 1);
  auto rb = big->NewReader();
  auto rs = small->NewReader();
  Gathered a, b;
  QueryStats sb, ss;
  for (const Receiver& r : Receivers(big_fake.surfels, 300, 9)) {
    ASSERT_TRUE((*rb)->Gather(r, Cut{}, &a, &sb).ok());
    absl::Status s = (*rs)->Gather(r, Cut{}, &b, &ss);
    ASSERT_TRUE(s.ok()) << s;
    ASSERT_EQ(Digest(a), Digest(b));
  }
  EXPECT_GT(ss.pages_read, 5 * sb.pages_read);  // it did thrash
  EXPECT_LE(small->CacheUsageBytes(), 4 * 1024u + 4096u);
  // The big cache never evicted, so it read each page the receivers touch once: the tiny one,
  // however often it reloaded them, read the same pages.
  ASSERT_EQ(big->TotalStats().shared.evictions, 0u);
  EXPECT_EQ(big->DistinctPagesRead(), sb.pages_read);
  EXPECT_EQ(small->DistinctPagesRead(), sb.pages_read);
  EXPECT_LT(small->DistinctPagesRead(), ss.pages_read);
}

// One budget for both levels: with the default shares, eight Readers holding pins keep the
// shared cache (where every decoded page lives) within cache_bytes.
TEST(GatherFake, OneBudgetHoldsWithManyReaders) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(4000, 23);
  FakeDb fake = BuildFakeDb(input, {8, 1024, Channels::kRadiance});
  std::vector<Receiver> receivers = Receivers(fake.surfels, 64, 6);
  const uint64_t budget = 40 * 1024;  // about 40 pages
  auto db = Open(fake, budget);
  std::vector<std::unique_ptr<Reader>> readers;
  for (int i = 0; i < 8; ++i) readers.push_back(std::move(*db->NewReader()));
  Gathered g;
  uint64_t peak = 0;
  for (size_t k = 0; k < receivers.size(); ++k) {
    ASSERT_TRUE(readers[k % 8]->Gather(receivers[k], Cut{}, &g).ok());
    peak = std::max(peak, db->CacheUsageBytes());
  }
  EXPECT_LE(peak, budget);
  EXPECT_GT(peak, budget / 2);  // and it is used
}

// Eight threads at once produce exactly the single-threaded results (run under TSan too).
TEST(GatherFake, EightThreadsMatchOneThread) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(4000, 21);
  FakeDb fake = BuildFakeDb(input, {8, 4096 - 16, Channels::kRadiance});
  std::vector<Receiver> receivers = Receivers(fake.surfels, 400, 2);
  // A cache of about a third of the pages: threads evict, share and wait on each other.
  const uint64_t pages =
      fake.source->page_count(Section::kNodes) + fake.source->page_count(Section::kPoints);
  auto db = Open(fake, pages * 4096 / 3);
  std::vector<std::vector<std::tuple<uint64_t, uint64_t, int>>> expected;
  {
    auto reader = db->NewReader();
    Gathered g;
    for (const Receiver& r : receivers) {
      ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g).ok());
      expected.push_back(Digest(g));
    }
  }
  db->DropCache();
  std::atomic<int> mismatches{0}, errors{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&, t] {
      auto reader = db->NewReader();
      if (!reader.ok()) {
        errors.fetch_add(1);
        return;
      }
      Gathered g;
      for (size_t k = 0; k < receivers.size(); ++k) {
        const size_t i = (k + t * 37) % receivers.size();  // different orders per thread
        if (!(*reader)->Gather(receivers[i], Cut{}, &g).ok()) errors.fetch_add(1);
        if (Digest(g) != expected[i]) mismatches.fetch_add(1);
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(errors.load(), 0);
  EXPECT_EQ(mismatches.load(), 0);
  CacheStats total = db->TotalStats();
  EXPECT_GT(total.reader.hits, 0u);
  EXPECT_GT(total.shared.hits, 0u);
}

// Threads that miss the same pages at once read each page once (single flight through Gather).
TEST(GatherFake, ConcurrentColdGathersReadEachPageOnce) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(2000, 5);
  FakeDb fake = BuildFakeDb(input, {8, 4096 - 16, Channels::kRadiance});
  MemPageStore* src = fake.source.get();
  src->set_read_delay_us(2000);
  auto db = Open(fake, 64 << 20);
  std::vector<std::thread> threads;
  std::atomic<int> ready{0};
  for (int t = 0; t < 6; ++t) {
    threads.emplace_back([&] {
      auto reader = db->NewReader();
      Gathered g;
      ready.fetch_add(1);
      while (ready.load() < 6) std::this_thread::yield();
      EXPECT_TRUE((*reader)->Gather({{0.5f, 0.5f, 0.5f}, {0, 0, 1}}, Cut{}, &g).ok());
    });
  }
  for (auto& t : threads) t.join();
  const uint64_t pages = src->page_count(Section::kNodes) + src->page_count(Section::kPoints);
  EXPECT_LE(src->reads(), pages);
  for (uint64_t p = 0; p < src->page_count(Section::kNodes); ++p) {
    EXPECT_LE(src->reads_of(Section::kNodes, p), 1u) << "nodes page " << p;
  }
}

TEST(GatherFake, CountersAddUp) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(3000, 6);
  FakeDb fake = BuildFakeDb(input, {8, 1024, Channels::kRadiance});
  auto db = Open(fake);
  auto reader = db->NewReader();
  Gathered g;
  QueryStats first, second;
  const Receiver r{{0.5f, 0.5f, 0.5f}, {0, 1, 0}};
  ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g, &first).ok());
  EXPECT_EQ(first.queries, 1u);
  EXPECT_GT(first.nodes_visited, 0u);
  EXPECT_EQ(first.clusters, g.clusters.size());
  EXPECT_EQ(first.surfels, g.surfels.size());
  uint64_t nodes = 0;
  for (int l = 0; l < kStatLevels; ++l) {
    nodes += first.nodes[l];
    EXPECT_EQ(first.reader_hits[l] + first.reader_misses[l], first.pages_touched[l]);
    EXPECT_EQ(first.shared_hits[l] + first.shared_misses[l], first.reader_misses[l]);
  }
  EXPECT_EQ(nodes, first.nodes_visited);
  EXPECT_EQ(first.TotalSharedMisses(), first.pages_read);
  EXPECT_GT(first.pages_read, 0u);
  EXPECT_EQ(first.bytes_read, first.pages_read * 1024);
  // The same gather again is served from the caches.
  ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g, &second).ok());
  EXPECT_EQ(second.pages_read, 0u);
  EXPECT_EQ(second.nodes_visited, first.nodes_visited);
  EXPECT_EQ((*reader)->stats().shared.pages_read, first.pages_read);
  EXPECT_EQ((*reader)->stats().reader.hits + (*reader)->stats().reader.misses,
            first.TotalPagesTouched() + second.TotalPagesTouched());
}

// Database::TotalStats() is exact at any time: it sums what each live Reader has published
// (after every gather, on its own cache line) and what destroyed Readers left.
TEST(GatherFake, TotalStatsAreExactWhileReadersLive) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(3000, 7);
  FakeDb fake = BuildFakeDb(input, {8, 1024, Channels::kRadiance});
  std::vector<Receiver> receivers = Receivers(fake.surfels, 5, 8);
  auto db = Open(fake);
  auto a = db->NewReader();
  auto b = db->NewReader();
  ASSERT_TRUE(a.ok() && b.ok());
  Gathered g;
  auto expect_sum = [&](const CacheStats& want) {
    const CacheStats got = db->TotalStats();
    EXPECT_EQ(got.reader.hits, want.reader.hits);
    EXPECT_EQ(got.reader.misses, want.reader.misses);
    EXPECT_EQ(got.reader.pages_read, want.reader.pages_read);
    EXPECT_EQ(got.shared.hits, want.shared.hits);
    EXPECT_EQ(got.shared.misses, want.shared.misses);
    EXPECT_EQ(got.shared.pages_read, want.shared.pages_read);
    EXPECT_EQ(got.shared.bytes_read, want.shared.bytes_read);
  };
  for (const Receiver& r : receivers) ASSERT_TRUE((*a)->Gather(r, Cut{}, &g).ok());
  ASSERT_TRUE((*b)->Gather(receivers[0], Cut{0.001f}, &g).ok());
  const CacheStats b_final = (*b)->stats();
  CacheStats both = (*a)->stats();
  both.Add(b_final);
  EXPECT_GT(both.shared.pages_read, 0u);
  expect_sum(both);  // a few gathers, both Readers alive
  b->reset();
  expect_sum(both);  // b's counters stay in the total
  ASSERT_TRUE((*a)->Gather(receivers[1], Cut{0.001f}, &g).ok());
  CacheStats now = (*a)->stats();
  now.Add(b_final);
  expect_sum(now);
}

TEST(GatherFake, WarmGatherDoesNotAllocate) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(3000, 7);
  FakeDb fake = BuildFakeDb(input, {8, 4096 - 16, Channels::kRadiance});
  std::vector<Receiver> receivers = Receivers(fake.surfels, 50, 3);
  auto db = Open(fake);
  auto reader = db->NewReader();
  Gathered g;
  QueryStats stats;
  g.clusters.reserve(100000);
  g.surfels.reserve(100000);
  g.surfel_ids.reserve(100000);
  for (const Receiver& r : receivers) ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g, &stats).ok());
  const uint64_t before = g_allocations.load();
  for (const Receiver& r : receivers) ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g, &stats).ok());
  EXPECT_EQ(g_allocations.load() - before, 0u);
}

// A warm gather is served by its Reader's own LRU alone: no lookup or unpin in the shared cache
// (each takes a shard lock and writes an entry's reference count that other threads touch) and
// no store read, also while another Reader works on the same cache. Issue 4's 2-thread goal
// rests on this: a warm traversal shares nothing that it writes.
TEST(GatherFake, WarmGatherMakesNoSharedCacheCalls) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(3000, 9);
  FakeDb fake = BuildFakeDb(input, {8, 1024, Channels::kRadiance});
  MemPageStore* src = fake.source.get();
  std::vector<Receiver> receivers = Receivers(fake.surfels, 40, 11);
  auto db = Open(fake);
  auto a = db->NewReader();
  auto b = db->NewReader();
  ASSERT_TRUE(a.ok() && b.ok());
  Gathered g;
  for (const Receiver& r : receivers) ASSERT_TRUE((*a)->Gather(r, Cut{}, &g).ok());
  const uint64_t calls = db->SharedCacheCalls();
  const uint64_t reads = src->reads();
  EXPECT_GT(calls, 0u);
  EXPECT_GT(reads, 0u);
  QueryStats second;
  for (const Receiver& r : receivers) ASSERT_TRUE((*a)->Gather(r, Cut{}, &g, &second).ok());
  EXPECT_EQ(db->SharedCacheCalls() - calls, 0u);
  EXPECT_EQ(src->reads() - reads, 0u);
  EXPECT_GT(second.TotalPagesTouched(), 0u);
  EXPECT_EQ(second.TotalReaderHits(), second.TotalPagesTouched());
  EXPECT_EQ(second.TotalSharedHits() + second.TotalSharedMisses(), 0u);
  // b's first gather goes to the shared cache (and finds its pages there)...
  QueryStats b_first;
  ASSERT_TRUE((*b)->Gather(receivers[0], Cut{}, &g, &b_first).ok());
  EXPECT_GT(db->SharedCacheCalls(), calls);
  EXPECT_GT(b_first.TotalSharedHits(), 0u);
  EXPECT_EQ(src->reads() - reads, 0u);
  // ...and a stays warm while b lives and holds pins.
  const uint64_t after_b = db->SharedCacheCalls();
  for (const Receiver& r : receivers) ASSERT_TRUE((*a)->Gather(r, Cut{}, &g).ok());
  EXPECT_EQ(db->SharedCacheCalls() - after_b, 0u);
}

TEST(GatherFake, BatchInZOrderMatchesSingleGathers) {
  std::vector<Surfel> input = testing::RandomSceneSurfels(2000, 12);
  FakeDb fake = BuildFakeDb(input, {});
  std::vector<Receiver> receivers = Receivers(fake.surfels, 200, 4);
  auto db = Open(fake);
  auto reader = db->NewReader();
  std::vector<uint32_t> order = ZOrder(receivers);
  ASSERT_EQ(order.size(), receivers.size());
  std::vector<uint32_t> sorted = order;
  std::sort(sorted.begin(), sorted.end());
  for (uint32_t i = 0; i < sorted.size(); ++i) ASSERT_EQ(sorted[i], i);  // a permutation
  // Z-order keeps neighbours together: consecutive receivers are closer than random pairs.
  double walk = 0, random_walk = 0;
  for (size_t i = 1; i < order.size(); ++i) {
    walk += glm::length(receivers[order[i]].position - receivers[order[i - 1]].position);
    random_walk += glm::length(receivers[i].position - receivers[i - 1].position);
  }
  EXPECT_LT(walk, 0.6 * random_walk);
  std::vector<size_t> visited;
  Gathered single;
  absl::Status s = (*reader)->GatherBatch(
      receivers, Cut{}, order, [&](size_t i, const Gathered& g) -> absl::Status {
        visited.push_back(i);
        absl::Status st = (*reader)->Gather(receivers[i], Cut{}, &single);
        if (!st.ok()) return st;
        EXPECT_EQ(Digest(g), Digest(single));
        return absl::OkStatus();
      });
  ASSERT_TRUE(s.ok()) << s;
  ASSERT_EQ(visited.size(), order.size());
  for (size_t k = 0; k < order.size(); ++k) EXPECT_EQ(visited[k], order[k]);
  // The callback's error stops the batch.
  int calls = 0;
  s = (*reader)->GatherBatch(receivers, Cut{}, {}, [&](size_t, const Gathered&) {
    return ++calls == 3 ? absl::CancelledError("stop") : absl::OkStatus();
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(calls, 3);
}

// --- corrupt pages: an error naming the page, no crash -----------------------------------

class CorruptPageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    fake_ = BuildFakeDb(testing::RandomSceneSurfels(2000, 13), {8, 1024, Channels::kRadiance});
    src_ = fake_.source.get();
    ASSERT_GE(src_->page_count(Section::kNodes), 3u);
  }
  // Opens the fake (once per test: the Database takes the source) and gathers everything.
  absl::Status GatherAll() {
    auto db = Open(fake_);
    auto reader = db->NewReader();
    Gathered g;
    // max_solid_angle 0 from below the scene, facing it, visits every page.
    return (*reader)->Gather({{0.5f, 0.5f, -10.0f}, {0, 0, 1}}, Cut{0.0f}, &g);
  }
  // Decodes node record `slot` of `page`, lets `edit` change it and encodes it back in place
  // (format version 3 records are packed, tree/format.h).
  template <typename Edit>
  void EditNode(uint64_t page, uint32_t slot, Edit edit) {
    auto* bytes = src_->MutablePage(Section::kNodes, page);
    const Channels ch = src_->meta().channels;
    const internal::PositionGrid grid = internal::PositionGrid::Of(src_->meta());
    uint8_t* rec = bytes->data() + sizeof(PageHeader) + slot * internal::NodeRecordSize(ch);
    internal::NodeRecordRadiance r = internal::DecodeNodeRecord(rec, ch, grid);
    edit(r);
    internal::EncodeNodeRecord(r, ch, grid, rec);
  }
  FakeDb fake_;
  MemPageStore* src_ = nullptr;
};

TEST_F(CorruptPageTest, StoreErrorIsPassedOnWithThePage) {
  src_->FailPage(Section::kNodes, 2,
                 absl::DataLossError("fake-db: nodes page 2: checksum mismatch"));
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("nodes page 2"));
}

TEST_F(CorruptPageTest, BadChildCount) {
  EditNode(1, 0, [](internal::NodeRecordRadiance& n) {
    n.common.child_count = 100;
    n.common.flags = 0;
  });
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("nodes page 1 is corrupt"));
}

TEST_F(CorruptPageTest, LinkPastTheRecords) {
  // Make the root's children point past the end of their page.
  EditNode(0, 0, [](internal::NodeRecordRadiance& root) {
    ASSERT_EQ(root.common.flags & internal::kNodeFlagLeaf, 0u);
    root.common.children = internal::MakeNodeRef(internal::RefPage(root.common.children), 4000);
  });
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("is corrupt"));
}

TEST_F(CorruptPageTest, CycleIsCaughtByDepth) {
  EditNode(0, 0, [](internal::NodeRecordRadiance& root) {
    root.common.children = internal::MakeNodeRef(0, 0);  // the root is its own child
    root.common.child_count = 1;
  });
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("nodes page 0"));
}

TEST_F(CorruptPageTest, WrongPageNumber) {
  auto* bytes = src_->MutablePage(Section::kNodes, 1);
  reinterpret_cast<PageHeader*>(bytes->data())->page_no = 77;
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("nodes page 1"));
}

TEST_F(CorruptPageTest, WrongKind) {
  auto* bytes = src_->MutablePage(Section::kPoints, 0);
  reinterpret_cast<PageHeader*>(bytes->data())->kind = 1;
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("points page 0"));
}

TEST_F(CorruptPageTest, WrongPointCount) {
  auto* bytes = src_->MutablePage(Section::kPoints, 1);
  reinterpret_cast<PageHeader*>(bytes->data())->record_count = 3;
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("points page 1"));
}

TEST_F(CorruptPageTest, PointRangeOutsideTheDatabase) {
  EditNode(1, 1, [](internal::NodeRecordRadiance& n) {
    n.common.first_point = internal::kMaxStoredPointIndex;  // far past the 2000 points
  });
  absl::Status s = GatherAll();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(std::string(s.message()), ::testing::HasSubstr("nodes page 1"));
}

TEST_F(CorruptPageTest, FailedPageIsRetriedNotCached) {
  src_->FailPage(Section::kPoints, 0, absl::DataLossError("fake-db: points page 0: bad"));
  auto db = Open(fake_);
  auto reader = db->NewReader();
  Gathered g;
  const Receiver r{{0.5f, 0.5f, -10.0f}, {0, 0, 1}};
  EXPECT_FALSE((*reader)->Gather(r, Cut{0.0f}, &g).ok());
  const uint64_t reads = src_->reads_of(Section::kPoints, 0);
  EXPECT_FALSE((*reader)->Gather(r, Cut{0.0f}, &g).ok());
  EXPECT_EQ(src_->reads_of(Section::kPoints, 0), reads + 1);
}

}  // namespace
}  // namespace pbgi
