// The builder over the in-memory store: tree invariants checked by VerifyTreePages and by an
// independent brute-force octree (std::stable_sort + recursion), for every layout and both
// channel sets, spilled and not; edge cases; SH of one disk against numerical integration.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <functional>
#include <memory>
#include <numeric>
#include <set>
#include <string>
#include <vector>

#include "build/builder.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/sh.h"
#include "store/mem_page_store.h"
#include "tests/build/test_clouds.h"
#include "tree/format.h"
#include "tree/morton.h"
#include "tree/verify.h"

namespace pbgi::internal {
namespace {

using testing_build::ClusteredCloud;
using testing_build::MakeSurfel;
using testing_build::ScratchDir;
using testing_build::SurfaceCloud;
using testing_build::UniformCloud;

struct Built {
  std::unique_ptr<MemPageStore> sink;
  StoreMeta meta;
  BuildStats stats;
};

absl::StatusOr<Built> BuildMem(const std::vector<Surfel>& cloud, const BuildOptions& o,
                               const std::string& tmp) {
  Built b;
  b.sink = std::make_unique<MemPageStore>(o.page_size);
  VectorSurfelSource src(cloud);
  auto stats = BuildToSink(src, *b.sink, o, tmp, &b.meta);
  if (!stats.ok()) return stats.status();
  b.stats = *stats;
  return b;
}

NodeRecordRadiance ReadNode(const Built& b, NodeRef ref) {
  auto page = b.sink->Get(Section::kNodes, RefPage(ref));
  EXPECT_TRUE(page.ok()) << page.status();
  const uint32_t size = NodeRecordSize(b.meta.channels);
  EXPECT_LT(RefSlot(ref), page->header->record_count) << "ref page " << RefPage(ref);
  return DecodeNodeRecord(page->payload.data() + size_t{RefSlot(ref)} * size, b.meta.channels,
                          PositionGrid::Of(b.meta));
}

Surfel ReadPoint(const Built& b, uint64_t i) {
  const uint32_t per = PointsPerPage(b.meta.page_size, b.meta.channels);
  auto page = b.sink->Get(Section::kPoints, i / per);
  EXPECT_TRUE(page.ok()) << page.status();
  return DecodePoint(page->payload.data(), static_cast<uint32_t>(i % per), b.meta.channels,
                     PositionGrid::Of(b.meta));
}

// The reference: sort by key with std::stable_sort, split recursively.
struct RefNode {
  uint64_t first = 0, count = 0;
  uint32_t depth = 0;
  bool leaf = false;
  Bounds bounds;
  double area = 0;
  std::vector<RefNode> kids;
};

struct Reference {
  std::vector<Surfel> sorted;  // input in Morton order, normals normalized
  std::vector<uint64_t> keys;
  std::vector<uint32_t> ranks;  // rank among the points of the same key (tree/morton.h)
  RefNode root;
  uint64_t nodes = 0;
  uint32_t max_depth = 0;
};

RefNode Split(Reference& r, uint64_t lo, uint64_t hi, uint32_t depth, uint32_t leaf_size) {
  RefNode n;
  n.first = lo;
  n.count = hi - lo;
  n.depth = depth;
  ++r.nodes;
  r.max_depth = std::max(r.max_depth, depth);
  for (uint64_t i = lo; i < hi; ++i) {
    n.bounds.Extend(r.sorted[i].position);
    n.area += sh::kPi * double(r.sorted[i].radius) * r.sorted[i].radius;
  }
  if (n.count <= leaf_size || depth == kMaxSplitDepth) {
    n.leaf = true;
    return n;
  }
  // Above depth 21 by key octant, below by the next octal digit of the rank.
  auto digit = [&](uint64_t i) -> uint64_t {
    if (depth < 21) return (r.keys[i] >> (3 * (20 - int(depth)))) & 7;
    return (r.ranks[i] >> (3 * (kMaxSplitDepth - 1 - depth))) & 7;
  };
  uint64_t i = lo;
  while (i < hi) {
    uint64_t oct = digit(i), j = i;
    while (j < hi && digit(j) == oct) ++j;
    n.kids.push_back(Split(r, i, j, depth + 1, leaf_size));
    i = j;
  }
  return n;
}

Reference MakeReference(const std::vector<Surfel>& cloud, uint32_t leaf_size) {
  Reference r;
  Bounds b;
  for (const Surfel& s : cloud) b.Extend(s.position);
  MortonQuantizer q(b);
  std::vector<uint64_t> keys(cloud.size());
  std::vector<size_t> idx(cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    keys[i] = q.Key(cloud[i].position);
    idx[i] = i;
  }
  std::stable_sort(idx.begin(), idx.end(), [&](size_t a, size_t c) { return keys[a] < keys[c]; });
  // The store holds each surfel quantized on the grid of the keys' cube (format version 3,
  // tree/format.h); the tree is made from the keys of the input positions.
  const PositionGrid grid = GridOfCube(MortonCube(b));
  for (size_t i : idx) {
    const bool same = !r.keys.empty() && r.keys.back() == keys[i];
    r.ranks.push_back(same ? std::min(r.ranks.back() + 1, kMaxRank) : 0);
    const Surfel& s = cloud[i];
    const glm::vec3 n(glm::normalize(glm::dvec3(s.normal)));  // as the builder normalizes
    const float pos[3] = {s.position.x, s.position.y, s.position.z};
    const float nrm[3] = {n.x, n.y, n.z};
    const float rad[3] = {s.radiance.x, s.radiance.y, s.radiance.z};
    uint8_t code[kPointRecordRadianceBytes];
    EncodePointRecord(pos, nrm, EncodeRadius(s.radius, s.two_sided), rad, Channels::kRadiance, grid,
                      code);
    r.sorted.push_back(DecodePointRecord(code, Channels::kRadiance, grid));
    r.keys.push_back(keys[i]);
  }
  r.root = Split(r, 0, cloud.size(), 0, leaf_size);
  return r;
}

void CompareNode(const Built& b, const Reference& ref, const RefNode& want, NodeRef at,
                 std::set<NodeRef>* seen) {
  ASSERT_TRUE(seen->insert(at).second) << "node visited twice";
  const NodeRecordRadiance got = ReadNode(b, at);
  const NodeRecordCommon& c = got.common;
  ASSERT_EQ(c.first_point, want.first);
  ASSERT_EQ(c.point_count, want.count);
  ASSERT_EQ(c.depth, want.depth);
  ASSERT_EQ(bool(c.flags & kNodeFlagLeaf), want.leaf) << "at first point " << want.first;
  for (int k = 0; k < 3; ++k) {
    ASSERT_EQ(c.lo[k], want.bounds.lo[k]);
    ASSERT_EQ(c.hi[k], want.bounds.hi[k]);
  }
  ASSERT_NEAR(c.area, want.area, 1e-5 * want.area);
  if (want.leaf) {
    ASSERT_EQ(c.child_count, 0u);
    for (uint64_t i = want.first; i < want.first + want.count; ++i) {
      Surfel p = ReadPoint(b, i);
      const Surfel& s = ref.sorted[i];
      ASSERT_EQ(p.position, s.position) << "point " << i;
      ASSERT_EQ(p.radius, s.radius);
      ASSERT_NEAR(glm::length(p.normal - glm::normalize(s.normal)), 0.0f, 1e-6f);
      if (HasRadiance(b.meta.channels)) {
        ASSERT_EQ(p.radiance, s.radiance);
      } else {
        ASSERT_EQ(p.radiance, glm::vec3(0.0f));
        for (int ch = 0; ch < 3; ++ch) {
          for (int k = 0; k < 9; ++k) ASSERT_EQ(got.sh_power[ch][k], 0.0f);
        }
      }
    }
    return;
  }
  ASSERT_EQ(c.child_count, want.kids.size());
  // Siblings are contiguous in one page.
  auto page = b.sink->Get(Section::kNodes, RefPage(c.children));
  ASSERT_TRUE(page.ok());
  ASSERT_LE(RefSlot(c.children) + c.child_count, page->header->record_count);
  for (uint32_t i = 0; i < c.child_count; ++i) {
    CompareNode(b, ref, want.kids[i], MakeNodeRef(RefPage(c.children), RefSlot(c.children) + i),
                seen);
    if (::testing::Test::HasFatalFailure()) return;
  }
}

void CheckAgainstReference(const Built& b, const std::vector<Surfel>& cloud, uint32_t leaf) {
  Reference ref = MakeReference(cloud, leaf);
  EXPECT_EQ(b.meta.point_count, cloud.size());
  EXPECT_EQ(b.meta.node_count, ref.nodes);
  EXPECT_EQ(b.meta.max_depth, ref.max_depth);
  std::set<NodeRef> seen;
  CompareNode(b, ref, ref.root, b.meta.root, &seen);
  EXPECT_EQ(seen.size(), ref.nodes);
}

bool SamePages(const Built& a, const Built& b) {
  for (Section s : {Section::kNodes, Section::kPoints}) {
    if (a.sink->pages(s) != b.sink->pages(s)) return false;
  }
  return a.meta.root == b.meta.root;
}

struct CloudCase {
  const char* name;
  std::vector<Surfel> (*make)();
};

std::vector<Surfel> Uniform() { return UniformCloud(6000, 11); }
std::vector<Surfel> Clustered() { return ClusteredCloud(6000, 12); }
std::vector<Surfel> Surface() { return SurfaceCloud(6000, 13); }

class LayoutTest : public ::testing::TestWithParam<std::tuple<int, Layout, Channels>> {};

TEST_P(LayoutTest, InvariantsAndSpillIdentity) {
  static const CloudCase kClouds[] = {
      {"uniform", Uniform}, {"clustered", Clustered}, {"surface", Surface}};
  const auto [cloud_i, layout, channels] = GetParam();
  const CloudCase& cc = kClouds[cloud_i];
  SCOPED_TRACE(cc.name);
  const std::vector<Surfel> cloud = cc.make();
  ScratchDir dir(std::string("layout_") + cc.name + "_" + LayoutName(layout));

  BuildOptions o;
  o.layout = layout;
  o.channels = channels;
  o.leaf_size = 8;
  o.page_size = EfficientPageSize(1);  // small pages: many of them
  auto big = BuildMem(cloud, o, dir.path());
  ASSERT_TRUE(big.ok()) << big.status();
  EXPECT_EQ(big->stats.runs_spilled, 0u);
  ASSERT_TRUE(VerifyTreePages(big->meta, *big->sink).ok())
      << VerifyTreePages(big->meta, *big->sink);
  CheckAgainstReference(*big, cloud, o.leaf_size);

  o.memory_bytes = 1;  // floors at 256-point runs: 24 runs, merged in several passes
  auto tiny = BuildMem(cloud, o, dir.path());
  ASSERT_TRUE(tiny.ok()) << tiny.status();
  EXPECT_GE(tiny->stats.runs_spilled, 20u);
  EXPECT_GE(tiny->stats.merge_passes, 1u);
  EXPECT_TRUE(SamePages(*big, *tiny)) << "spilled build differs from the in-memory one";
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));

  // Two or three threads (pipelined sort and merge) build the same pages as the default one.
  for (int threads : {2, 3}) {
    for (uint64_t memory : {uint64_t{1}, uint64_t{1} << 30}) {
      o.threads = threads;
      o.memory_bytes = memory;
      auto t = BuildMem(cloud, o, dir.path());
      ASSERT_TRUE(t.ok()) << t.status();
      EXPECT_EQ(t->stats.threads, threads);
      EXPECT_EQ(t->stats.runs_spilled > 0, memory == 1);
      EXPECT_TRUE(SamePages(*big, *t)) << threads << " threads, memory " << memory;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    AllLayouts, LayoutTest,
    ::testing::Combine(::testing::Values(0, 1, 2),
                       ::testing::Values(Layout::kCoherent, Layout::kPostOrder,
                                         Layout::kBreadthFirst, Layout::kShuffled),
                       ::testing::Values(Channels::kRadiance, Channels::kOcclusion)));

// The bottom of the coherent layout: the descendants of a node with at most a unit of records
// below it (a quarter page, node_packer.h) lie in at most two pages, so a walk that enters such
// a subtree stays in its page to the leaves. (The upper levels are paged level by level, which
// a gather's cut wants; tests/build/layout_io_test.cc measures that through the query layer.)
TEST(CoherentLayoutTest, SmallSubtreesLieInAtMostTwoPages) {
  for (uint32_t pages_4k : {1u, 4u}) {
    const std::vector<Surfel> cloud = SurfaceCloud(20000, 21);
    ScratchDir dir("coherence");
    BuildOptions o;
    o.leaf_size = 8;
    o.page_size = EfficientPageSize(pages_4k);
    auto b = BuildMem(cloud, o, dir.path());
    ASSERT_TRUE(b.ok()) << b.status();
    const uint32_t unit = std::max<uint32_t>(8, NodesPerPage(o.page_size, o.channels) / 4);
    // Post-order walk: records below each node and the set of pages holding them.
    struct Below {
      uint64_t records = 0;
      std::set<uint64_t> pages;
    };
    uint64_t small = 0, one_page = 0;
    std::function<Below(NodeRef)> walk = [&](NodeRef r) {
      Below out;
      const NodeRecordRadiance n = ReadNode(*b, r);
      for (uint32_t i = 0; i < n.common.child_count; ++i) {
        const NodeRef c = MakeNodeRef(RefPage(n.common.children), RefSlot(n.common.children) + i);
        Below kid = walk(c);
        out.records += 1 + kid.records;
        out.pages.insert(RefPage(c));
        out.pages.insert(kid.pages.begin(), kid.pages.end());
      }
      if (out.records > 0 && out.records <= unit) {
        ++small;
        if (out.pages.size() == 1) ++one_page;
        EXPECT_LE(out.pages.size(), 2u) << "node at page " << RefPage(r) << " slot " << RefSlot(r);
      }
      return out;
    };
    walk(b->meta.root);
    EXPECT_GT(small, 100u);
    // Most units start a page or fit the one being filled.
    EXPECT_GT(one_page, small * 3 / 4) << one_page << " of " << small;
  }
}

TEST(BuildEdgeTest, EmptyInputIsAClearError) {
  ScratchDir dir("empty");
  auto b = BuildMem({}, BuildOptions{}, dir.path());
  ASSERT_FALSE(b.ok());
  EXPECT_EQ(b.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(b.status().message().find("no surfels"), std::string::npos) << b.status();
}

TEST(BuildEdgeTest, OnePointIsALeafRoot) {
  ScratchDir dir("one");
  std::vector<Surfel> cloud = {MakeSurfel({1, 2, 3}, {0, 0, 1}, 0.5f, {1, 1, 1})};
  auto b = BuildMem(cloud, BuildOptions{}, dir.path());
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->meta.node_count, 1u);
  EXPECT_EQ(b->meta.max_depth, 0u);
  EXPECT_TRUE(VerifyTreePages(b->meta, *b->sink).ok());
  CheckAgainstReference(*b, cloud, 16);
}

TEST(BuildEdgeTest, TwoPointsWithLeafSizeOneSplit) {
  ScratchDir dir("two");
  std::vector<Surfel> cloud = {MakeSurfel({0, 0, 0}, {0, 0, 1}, 0.5f, {1, 1, 1}),
                               MakeSurfel({1, 1, 1}, {0, 1, 0}, 0.5f, {1, 0, 1})};
  BuildOptions o;
  o.leaf_size = 1;
  auto b = BuildMem(cloud, o, dir.path());
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->meta.node_count, 3u);  // opposite corners: root with two leaf children
  EXPECT_TRUE(VerifyTreePages(b->meta, *b->sink).ok()) << VerifyTreePages(b->meta, *b->sink);
  CheckAgainstReference(*b, cloud, 1);
}

// Issue 17: coincident points made one leaf that every nearby receiver gathered whole. Below
// the last cell they split by rank (tree/morton.h) into leaves of at most the leaf size: 100
// ranks need three octal digits, so seven single-child levels, then 64 + 36, then leaves of 8.
TEST(BuildEdgeTest, CoincidentPointsSplitBelowTheLastCellIntoLeavesOfTheLeafSize) {
  ScratchDir dir("coincident");
  std::vector<Surfel> cloud(100, MakeSurfel({5, 5, 5}, {1, 0, 0}, 0.1f, {0.5f, 0.5f, 0.5f}));
  cloud.push_back(MakeSurfel({6, 6, 6}, {1, 0, 0}, 0.1f, {0.5f, 0.5f, 0.5f}));
  auto b = BuildMem(cloud, BuildOptions{}, dir.path());
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->meta.max_depth, kMaxSplitDepth - 1);
  EXPECT_EQ(b->stats.max_leaf_points, 8u);
  EXPECT_TRUE(VerifyTreePages(b->meta, *b->sink).ok()) << VerifyTreePages(b->meta, *b->sink);
  CheckAgainstReference(*b, cloud, 16);
}

TEST(BuildEdgeTest, AllCoincidentPoints) {
  ScratchDir dir("allsame");
  std::vector<Surfel> cloud(50, MakeSurfel({-1, 0, 7}, {0, 0, 1}, 0.1f, {1, 2, 3}));
  auto b = BuildMem(cloud, BuildOptions{}, dir.path());
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->stats.max_leaf_points, 8u);
  EXPECT_TRUE(VerifyTreePages(b->meta, *b->sink).ok()) << VerifyTreePages(b->meta, *b->sink);
  CheckAgainstReference(*b, cloud, 16);
}

TEST(BuildEdgeTest, PlaneHugeTinyAndFarClouds) {
  ScratchDir dir("extremes");
  std::vector<std::vector<Surfel>> clouds;
  auto plane = UniformCloud(3000, 31);
  for (auto& s : plane) s.position.z = 2.5f;
  clouds.push_back(plane);
  clouds.push_back(UniformCloud(3000, 32, 1e7f));
  clouds.push_back(UniformCloud(3000, 33, 1e-6f));
  // Far from the origin: floats there are 0.125 apart, so the disks must span 64 such steps to
  // be placed at all (build/input_range.h); the cloud's extent is still only 160 steps.
  auto far = UniformCloud(3000, 34, 10.0f, glm::vec3(1e6f, -2e6f, 5e5f));
  for (auto& s : far) s.radius = 8.0f + s.radius;
  clouds.push_back(far);
  for (size_t i = 0; i < clouds.size(); ++i) {
    SCOPED_TRACE(i);
    BuildOptions o;
    o.memory_bytes = 1;
    auto b = BuildMem(clouds[i], o, dir.path());
    ASSERT_TRUE(b.ok()) << b.status();
    EXPECT_TRUE(VerifyTreePages(b->meta, *b->sink).ok()) << VerifyTreePages(b->meta, *b->sink);
    CheckAgainstReference(*b, clouds[i], 16);
    EXPECT_GT(b->meta.max_depth, 1u);
  }
}

TEST(BuildEdgeTest, InvalidSurfelsAreRefusedWithTheirNumberOrSkipped) {
  ScratchDir dir("invalid");
  auto cloud = UniformCloud(100, 41);
  cloud[17].radius = 0.0f;
  cloud[40].normal = glm::vec3(0.0f);
  cloud[77].position.y = std::nanf("");
  auto b = BuildMem(cloud, BuildOptions{}, dir.path());
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("surfel 17"), std::string::npos) << b.status();
  EXPECT_NE(b.status().message().find("radius"), std::string::npos) << b.status();
  BuildOptions o;
  o.skip_invalid = true;
  auto s = BuildMem(cloud, o, dir.path());
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(s->stats.skipped, 3u);
  EXPECT_EQ(s->meta.point_count, 97u);
  EXPECT_TRUE(VerifyTreePages(s->meta, *s->sink).ok());
}

TEST(BuildEdgeTest, VerifyCatchesACorruptedAggregate) {
  ScratchDir dir("corrupt");
  auto cloud = UniformCloud(500, 51);
  auto b = BuildMem(cloud, BuildOptions{}, dir.path());
  ASSERT_TRUE(b.ok());
  // Rebuild the sink with one SH coefficient of the root changed.
  MemPageStore bad(b->meta.page_size);
  for (Section s : {Section::kNodes, Section::kPoints}) {
    for (auto& [no, bytes] : b->sink->pages(s)) {
      std::vector<uint8_t> payload(bytes.begin() + sizeof(PageHeader), bytes.end());
      PageHeader h;
      std::memcpy(&h, bytes.data(), sizeof(h));
      payload.resize(h.payload_bytes);
      if (s == Section::kNodes && no == RefPage(b->meta.root)) {
        const Channels ch = b->meta.channels;
        const PositionGrid grid = PositionGrid::Of(b->meta);
        uint8_t* rec = payload.data() + size_t{RefSlot(b->meta.root)} * NodeRecordSize(ch);
        NodeRecordRadiance r = DecodeNodeRecord(rec, ch, grid);
        r.common.sh_area[4] += 0.01f * r.common.area;
        EncodeNodeRecord(r, ch, grid, rec);
      }
      ASSERT_TRUE(bad.Append(s, no, PageKind(h.kind), h.record_count, payload).ok());
    }
  }
  absl::Status st = VerifyTreePages(b->meta, bad);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("SH coefficient 4"), std::string::npos) << st;
}

TEST(BuildEdgeTest, CancelAndBadOptionsAreErrors) {
  ScratchDir dir("cancel");
  auto cloud = UniformCloud(1000, 61);
  std::atomic<bool> cancel{true};
  BuildOptions o;
  o.cancel = &cancel;
  auto c = BuildMem(cloud, o, dir.path());
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), absl::StatusCode::kCancelled);

  BuildOptions small;
  small.page_size = 512;  // cannot hold a sibling group of 8 radiance records (99 bytes each)
  auto p = BuildMem(cloud, small, dir.path());
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.status().message().find("page size 512"), std::string::npos) << p.status();

  BuildOptions zero;
  zero.leaf_size = 0;
  EXPECT_FALSE(BuildMem(cloud, zero, dir.path()).ok());
}

TEST(BuildEdgeTest, ProgressIsReportedForEveryPass) {
  ScratchDir dir("progress");
  auto cloud = UniformCloud(300000, 62);
  std::set<std::string> passes;
  BuildOptions o;
  o.progress = [&](const BuildProgress& p) {
    passes.insert(p.pass);
    EXPECT_LE(p.points_done, 300000u);
  };
  auto b = BuildMem(cloud, o, dir.path());
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(passes, (std::set<std::string>{"bounds", "sort", "merge+octree"}));
}

// c_i = integral over the sphere of A max(0, n.w) Y_i(w), by the midpoint rule.
TEST(ShTest, OneDiskMatchesNumericalIntegrationOfItsClampedCosine) {
  ScratchDir dir("sh");
  const glm::vec3 n = glm::normalize(glm::vec3(0.3f, -0.5f, 0.8f));
  const float radius = 0.7f;
  std::vector<Surfel> cloud = {MakeSurfel({0, 0, 0}, n, radius, {2, 1, 0.5f})};
  auto b = BuildMem(cloud, BuildOptions{}, dir.path());
  ASSERT_TRUE(b.ok());
  NodeRecordRadiance root = ReadNode(*b, b->meta.root);
  // The aggregates are made from the surfel as stored (format version 3 quantizes its radius
  // and normal, tree/format.h), and stored in fixed point scaled by the largest coefficient.
  const Surfel stored = ReadPoint(*b, 0);
  EXPECT_NEAR(stored.radius, radius, radius / 2048);
  EXPECT_LT(glm::length(stored.normal - n), 1e-4f);
  const glm::vec3 sn = stored.normal;
  const double area = sh::kPi * double(stored.radius) * stored.radius;
  const int nt = 600, np = 1200;
  double c[9] = {};
  for (int i = 0; i < nt; ++i) {
    const double theta = (i + 0.5) * sh::kPi / nt;
    for (int j = 0; j < np; ++j) {
      const double phi = (j + 0.5) * 2 * sh::kPi / np;
      const double x = std::sin(theta) * std::cos(phi), y = std::sin(theta) * std::sin(phi),
                   z = std::cos(theta);
      const double cosv = std::max(0.0, sn.x * x + sn.y * y + sn.z * z);
      const double dw = std::sin(theta) * (sh::kPi / nt) * (2 * sh::kPi / np);
      auto basis = sh::Basis(x, y, z);
      for (int k = 0; k < 9; ++k) c[k] += area * cosv * basis[k] * dw;
    }
  }
  double cmax = 0;
  for (int k = 0; k < 9; ++k) cmax = std::max(cmax, std::abs(c[k]));
  for (int k = 0; k < 9; ++k) {
    EXPECT_NEAR(root.common.sh_area[k], c[k], 2e-4 * area + cmax / 32767) << "coefficient " << k;
    EXPECT_NEAR(root.sh_power[0][k], 2.0 * c[k], 4e-4 * area + 2.0 * cmax / 254)
        << "coefficient " << k;
  }
  EXPECT_NEAR(root.common.area, area, 1e-6 * area);
}

}  // namespace
}  // namespace pbgi::internal
