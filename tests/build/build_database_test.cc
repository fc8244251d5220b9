// BuildDatabase end to end over LMDB: VerifyTree, meta record, agreement with the in-memory
// pipeline page by page, spilled and not, temporary files cleaned up.
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <tuple>
#include <vector>

#include "build/builder.h"
#include "build/external_sort.h"
#include "build/input_range.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/store.h"
#include "store/mem_page_store.h"
#include "tests/build/test_clouds.h"
#include "tests/common/child_process.h"
#include "tree/format.h"

namespace pbgi {
namespace {

using testing_build::ScratchDir;

// A position as the store holds it: its cell's centre on the store's grid (format version 3).
std::tuple<float, float, float> OnGrid(const internal::PositionGrid& grid, const glm::vec3& p) {
  return {grid.Coord(0, grid.Nearest(0, p.x)), grid.Coord(1, grid.Nearest(1, p.y)),
          grid.Coord(2, grid.Nearest(2, p.z))};
}

// Builds `cloud` into dir/db (dir/db_est with an estimated radius, dir/db_spill at a memory
// budget of a byte: every run spilled) and opens it.
void BuildVariant(const std::vector<Surfel>& cloud, Channels channels, bool estimate, int memory,
                  const ScratchDir& dir, std::string* db,
                  absl::StatusOr<std::unique_ptr<PageStore>>* store) {
  BuildOptions o;
  o.memory_bytes = memory;
  o.tmp_dir = dir.Sub("tmp");
  std::filesystem::create_directories(o.tmp_dir);
  o.channels = channels;
  o.estimate.radius = estimate;
  VectorSurfelSource src(cloud, /*has_radiance=*/channels != Channels::kOcclusion);
  *db = dir.Sub(estimate ? "db_est" : memory == 1 ? "db_spill" : "db");
  auto stats = BuildDatabase(src, *db, o);
  ASSERT_TRUE(stats.ok()) << stats.status();
  *store = PageStore::Open(*db);
  ASSERT_TRUE(store->ok()) << store->status();
}

// Two-sided surfels (their flag in the radius's sign bit) build a store that verifies (leaf SH
// recomputed from the points with each two-sided one as the pair n, -n), whose root holds
// band 1 of the one-sided surfels only and the even bands of both sides, and whose points read
// back with their flags and sheet tags (Surfel::sheet); also with an estimated radius, which
// must keep both, and through spilled runs (a memory budget of a byte).
TEST(BuildDatabaseTest, TwoSidedSurfelsBuildAVerifiableStore) {
  ScratchDir dir("db_two_sided");
  auto cloud = testing_build::SurfaceCloud(6000, 11);
  for (size_t i = 0; i < cloud.size(); ++i) {
    cloud[i].two_sided = i % 3 == 1;
    cloud[i].sheet = cloud[i].two_sided ? static_cast<uint8_t>(1 + i % 255) : 0;
  }
  for (const auto& [estimate, memory] :
       {std::pair{false, 64 << 20}, std::pair{true, 64 << 20}, std::pair{false, 1}}) {
    SCOPED_TRACE(estimate ? "estimated radius" : "given radius");
    SCOPED_TRACE(memory);
    std::string db;
    absl::StatusOr<std::unique_ptr<PageStore>> store;
    ASSERT_NO_FATAL_FAILURE(
        BuildVariant(cloud, Channels::kOcclusion, estimate, memory, dir, &db, &store));
    EXPECT_EQ((*store)->meta().version, kStoreFormatVersion);
    EXPECT_TRUE(VerifyTree(**store).ok()) << VerifyTree(**store);
    // Every point's flag, found by position (the store holds them in Morton order).
    // Positions are stored on the store's grid (format version 3, tree/format.h).
    const internal::PositionGrid grid = internal::PositionGrid::Of((*store)->meta());
    auto on_grid = [&](const glm::vec3& p) { return OnGrid(grid, p); };
    std::map<std::tuple<float, float, float>, int> want;
    for (const Surfel& s : cloud)
      want[on_grid(s.position)] += s.two_sided ? 1 + 2 * s.sheet : 0x1000;
    std::map<std::tuple<float, float, float>, int> got;
    auto txn = (*store)->BeginRead();
    ASSERT_TRUE(txn.ok()) << txn.status();
    const StoreMeta& m = (*store)->meta();
    uint64_t seen = 0;
    for (uint64_t page = 0; page < m.point_pages; ++page) {
      auto view = txn->Get(Section::kPoints, page);
      ASSERT_TRUE(view.ok()) << view.status();
      for (uint32_t i = 0; i < view->header->record_count; ++i, ++seen) {
        const Surfel s = internal::DecodePoint(view->payload.data(), i, m.channels, grid);
        EXPECT_GT(s.radius, 0.0f);
        got[{s.position.x, s.position.y, s.position.z}] += s.two_sided ? 1 + 2 * s.sheet : 0x1000;
      }
    }
    EXPECT_EQ(seen, cloud.size());
    EXPECT_EQ(got, want);
  }
}

// A two-sided surfel's back radiance (Surfel::back_radiance) is stored where some two-sided
// surfel's back differs from its front (Channels::kRadianceBothSides, 26-byte point records):
// through the in-memory sort, compact spilled runs and raw runs (estimated radii) alike, and
// VerifyTree checks each node's power SH against its points' fronts and backs. Where every
// back equals its front, or no surfel is two-sided, the database stays kRadiance, its records
// 20 bytes: nothing stored that the scene does not need.
TEST(BuildDatabaseTest, BackRadianceIsStoredWhereATwoSidedSurfelsBackDiffers) {
  ScratchDir dir("db_back");
  auto cloud = testing_build::SurfaceCloud(6000, 12);
  for (size_t i = 0; i < cloud.size(); ++i) {
    cloud[i].two_sided = i % 3 == 1;
    cloud[i].sheet = cloud[i].two_sided ? static_cast<uint8_t>(1 + i % 255) : 0;
    if (cloud[i].two_sided) {
      cloud[i].back_radiance = glm::vec3(0.1f + 0.5f * cloud[i].radiance.z, 0.02f * (i % 7), 3.0f);
    }
  }
  uint64_t both_sides_pages = 0;
  for (const auto& [estimate, memory] :
       {std::pair{false, 64 << 20}, std::pair{true, 64 << 20}, std::pair{false, 1}}) {
    SCOPED_TRACE(estimate ? "estimated radius" : "given radius");
    SCOPED_TRACE(memory);
    std::string db;
    absl::StatusOr<std::unique_ptr<PageStore>> store;
    ASSERT_NO_FATAL_FAILURE(
        BuildVariant(cloud, Channels::kRadiance, estimate, memory, dir, &db, &store));
    const StoreMeta& m = (*store)->meta();
    EXPECT_EQ(m.channels, Channels::kRadianceBothSides);
    EXPECT_TRUE(VerifyTree(**store).ok()) << VerifyTree(**store);
    if (!estimate) both_sides_pages = m.point_pages;
    // Every point's back radiance, found by position.
    const internal::PositionGrid grid = internal::PositionGrid::Of(m);
    auto on_grid = [&](const glm::vec3& p) { return OnGrid(grid, p); };
    std::map<std::tuple<float, float, float>, const Surfel*> input;
    for (const Surfel& s : cloud) input[on_grid(s.position)] = &s;
    auto txn = (*store)->BeginRead();
    ASSERT_TRUE(txn.ok()) << txn.status();
    uint64_t seen = 0, backs = 0;
    for (uint64_t page = 0; page < m.point_pages; ++page) {
      auto view = txn->Get(Section::kPoints, page);
      ASSERT_TRUE(view.ok()) << view.status();
      for (uint32_t i = 0; i < view->header->record_count; ++i, ++seen) {
        const Surfel s = internal::DecodePoint(view->payload.data(), i, m.channels, grid);
        const auto it = input.find({s.position.x, s.position.y, s.position.z});
        ASSERT_NE(it, input.end());
        const Surfel& in = *it->second;
        ASSERT_EQ(s.two_sided, in.two_sided);
        for (int k = 0; k < 3; ++k) {
          ASSERT_NEAR(s.radiance[k], in.radiance[k], 1e-3f * std::fabs(in.radiance[k]) + 1e-9f);
          if (in.two_sided) {
            ASSERT_NEAR(s.back_radiance[k], in.back_radiance[k],
                        1e-3f * std::fabs(in.back_radiance[k]) + 1e-9f);
          } else {
            ASSERT_EQ(s.back_radiance[k], 0.0f);
          }
        }
        backs += in.two_sided;
      }
    }
    EXPECT_EQ(seen, cloud.size());
    EXPECT_EQ(backs, cloud.size() / 3);
  }
  // Backs equal to fronts, or one-sided only: kRadiance, fewer point pages.
  for (bool two_sided : {true, false}) {
    SCOPED_TRACE(two_sided);
    auto same = cloud;
    for (Surfel& s : same) {
      s.back_radiance = s.radiance;
      if (!two_sided) s.two_sided = false;
    }
    BuildOptions o;
    o.tmp_dir = dir.Sub("tmp");
    VectorSurfelSource src(same, /*has_radiance=*/true);
    const std::string db = dir.Sub(two_sided ? "db_same" : "db_one");
    auto stats = BuildDatabase(src, db, o);
    ASSERT_TRUE(stats.ok()) << stats.status();
    auto store = PageStore::Open(db);
    ASSERT_TRUE(store.ok()) << store.status();
    EXPECT_EQ((*store)->meta().channels, Channels::kRadiance);
    EXPECT_TRUE(VerifyTree(**store).ok()) << VerifyTree(**store);
    EXPECT_LT((*store)->meta().point_pages, both_sides_pages);
  }
}

TEST(BuildDatabaseTest, BuildsAVerifiableStoreEqualToTheInMemoryPipeline) {
  ScratchDir dir("db");
  const auto cloud = testing_build::SurfaceCloud(30000, 5);
  for (Layout layout : {Layout::kCoherent, Layout::kShuffled}) {
    for (uint64_t memory : {uint64_t{1} << 30, uint64_t{1}}) {
      for (int threads : {1, 2}) {
        SCOPED_TRACE(std::string(LayoutName(layout)) + " memory " + std::to_string(memory) +
                     " threads " + std::to_string(threads));
        BuildOptions o;
        o.layout = layout;
        o.memory_bytes = memory;
        o.threads = threads;
        o.tmp_dir = dir.Sub("tmp");
        std::filesystem::create_directories(o.tmp_dir);
        VectorSurfelSource src(cloud);
        const std::string db = dir.Sub("db");
        auto stats = BuildDatabase(src, db, o);
        ASSERT_TRUE(stats.ok()) << stats.status();
        EXPECT_EQ(stats->points, cloud.size());
        EXPECT_EQ(stats->runs_spilled > 0, memory == 1);
        EXPECT_GT(stats->bytes_on_disk, cloud.size() * internal::kPointRecordRadianceBytes);
        EXPECT_TRUE(std::filesystem::is_empty(o.tmp_dir));

        auto store = PageStore::Open(db);
        ASSERT_TRUE(store.ok()) << store.status();
        const StoreMeta& m = (*store)->meta();
        EXPECT_EQ(m.point_count, cloud.size());
        EXPECT_EQ(m.node_count, stats->nodes);
        EXPECT_EQ(m.layout, LayoutName(layout));
        EXPECT_EQ(m.leaf_size, 16u);
        EXPECT_EQ(m.channels, Channels::kRadiance);
        EXPECT_TRUE(VerifyTree(**store).ok()) << VerifyTree(**store);

        // The same pages as the pipeline over memory.
        internal::MemPageStore mem(o.page_size);
        StoreMeta mm;
        VectorSurfelSource src2(cloud);
        ASSERT_TRUE(internal::BuildToSink(src2, mem, o, o.tmp_dir, &mm).ok());
        EXPECT_EQ(mm.root, m.root);
        auto txn = (*store)->BeginRead();
        ASSERT_TRUE(txn.ok());
        for (Section s : {Section::kNodes, Section::kPoints}) {
          for (const auto& [no, bytes] : mem.pages(s)) {
            auto v = txn->Get(s, no);
            ASSERT_TRUE(v.ok()) << v.status();
            ASSERT_EQ(v->header->record_count,
                      reinterpret_cast<const PageHeader*>(bytes.data())->record_count);
            ASSERT_EQ(0, std::memcmp(v->payload.data(), bytes.data() + sizeof(PageHeader),
                                     v->payload.size()))
                << SectionName(s) << " page " << no;
          }
        }
      }
    }
  }
}

// A write that fails on the LMDB writer thread (threads = 2; RLIMIT_FSIZE stands in for a full
// disk, in a child process so the limit stays there) ends the build with the store's error:
// no hang, no crash, and nothing left that opens.
TEST(BuildDatabaseTest, WriteErrorOnTheWriterThreadEndsTheBuild) {
  ScratchDir dir("fsize");
  const std::string db = dir.Sub("db");
  const auto cloud = testing_build::SurfaceCloud(60000, 8);  // about 0.9 MiB of compact pages
  const testing_common::ChildResult child = testing_common::RunInChild(
      [&] {
        BuildOptions o;
        o.threads = 2;
        o.memory_bytes = uint64_t{256} << 20;  // no spill: the limit hits the database file
        VectorSurfelSource src(cloud);
        auto stats = BuildDatabase(src, db, o);
        return stats.ok() ? std::string("built") : stats.status().ToString();
      },
      /*file_size_limit=*/512 << 10);
  ASSERT_TRUE(child.exited) << "the build crashed or hung (signal " << child.signal << ")";
  const std::string& got = child.report;
  EXPECT_NE(got.find("RESOURCE_EXHAUSTED"), std::string::npos) << got;
  EXPECT_NE(got.find("file too large"), std::string::npos) << got;
  EXPECT_FALSE(PageStore::Open(db).ok());
}

TEST(BuildDatabaseTest, OcclusionDatabaseIsSmaller) {
  ScratchDir dir("occl");
  const auto cloud = testing_build::UniformCloud(20000, 6);
  uint64_t bytes[2];
  int i = 0;
  for (Channels c : {Channels::kRadiance, Channels::kOcclusion}) {
    BuildOptions o;
    o.channels = c;
    VectorSurfelSource src(cloud);
    auto stats = BuildDatabase(src, dir.Sub("db" + std::to_string(i)), o);
    ASSERT_TRUE(stats.ok()) << stats.status();
    bytes[i++] = stats->bytes_on_disk;
    auto store = PageStore::Open(dir.Sub("db" + std::to_string(i - 1)));
    ASSERT_TRUE(store.ok()) << store.status();
    EXPECT_EQ((*store)->meta().channels, c);
    EXPECT_TRUE(VerifyTree(**store).ok()) << VerifyTree(**store);
  }
  EXPECT_LT(bytes[1], bytes[0] * 0.8);
}

TEST(BuildDatabaseTest, MissingTmpDirAndEmptyInputAreClearErrors) {
  ScratchDir dir("errs");
  const auto cloud = testing_build::UniformCloud(10, 7);
  BuildOptions o;
  o.tmp_dir = dir.Sub("nope");
  VectorSurfelSource src(cloud);
  auto s = BuildDatabase(src, dir.Sub("db"), o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("nope"), std::string::npos) << s.status();

  std::vector<Surfel> none;
  VectorSurfelSource empty(none);
  auto e = BuildDatabase(empty, dir.Sub("db2"), BuildOptions{});
  ASSERT_FALSE(e.ok());
  EXPECT_NE(e.status().message().find("no surfels"), std::string::npos) << e.status();
  // A failed build leaves nothing that opens.
  EXPECT_FALSE(PageStore::Open(dir.Sub("db2")).ok());
}

// A build streams its pages out: after it, most of data.mdb has been written back and dropped
// from the page cache (which a memory cgroup would charge to the build), yet the store verifies.
TEST(BuildDatabaseTest, PagesAreStreamedOutOfThePageCache) {
  ScratchDir dir("stream");
  // Enough points for a store of several write batches (compressed compact pages: ~15-20
  // bytes per point).
  const auto cloud = testing_build::SurfaceCloud(250000, 9);
  BuildOptions o;
  o.memory_bytes = uint64_t{16} << 20;  // 1 MiB write batches
  VectorSurfelSource src(cloud);
  const std::string db = dir.Sub("db");
  auto stats = BuildDatabase(src, db, o);
  ASSERT_TRUE(stats.ok()) << stats.status();
  ASSERT_GT(stats->bytes_on_disk, uint64_t{4} << 20);
  const std::string data = db + "/data.mdb";
  const int fd = open(data.c_str(), O_RDONLY);
  ASSERT_GE(fd, 0) << data;
  struct stat st;
  ASSERT_EQ(fstat(fd, &st), 0);
  const size_t bytes = static_cast<size_t>(st.st_size);
  void* map = mmap(nullptr, bytes, PROT_READ, MAP_SHARED, fd, 0);
  ASSERT_NE(map, MAP_FAILED);
  const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
  std::vector<unsigned char> in_core((bytes + page - 1) / page);
  ASSERT_EQ(mincore(map, bytes, in_core.data()), 0);
  size_t resident = 0;
  for (unsigned char c : in_core) resident += c & 1;
  munmap(map, bytes);
  close(fd);
  EXPECT_LT(resident * 2, in_core.size())
      << resident << " of " << in_core.size() << " pages of data.mdb still cached";
  auto store = PageStore::Open(db);
  ASSERT_TRUE(store.ok()) << store.status();
  EXPECT_TRUE(VerifyTree(**store).ok()) << VerifyTree(**store);
}

// The plan's shares never exceed the budget, threads only come with a budget that leaves their
// runs large (1 M points at 32 MiB once made 4,096 runs of 256 points), and a known input that
// fits one run is planned as one run.
// The radius bound is 64 float steps of the largest coordinate, the step being what
// std::nextafter gives (InputRangeCheck computes it from the bits): at and next to powers of two,
// where the step doubles, for either sign and on each axis.
TEST(InputRangeCheckTest, RadiusBoundIsSixtyFourStepsOfTheLargestCoordinate) {
  std::vector<float> coords = {0.75f, 1.0f, 1.5f, 1000.0f, 1048576.0f, 3e11f, 1099511627776.0f};
  for (float c : {1.0f, 1048576.0f, 1099511627776.0f}) coords.push_back(std::nextafter(c, 0.0f));
  for (float c : coords) {
    const float step = std::nextafter(c, std::numeric_limits<float>::infinity()) - c;
    const float bound = internal::kMinRadiusInSteps * step;
    ASSERT_GE(double(bound), internal::kMinRadius) << c;
    for (int axis = 0; axis < 3; ++axis) {
      for (float sign : {1.0f, -1.0f}) {
        Surfel s;
        s.position = glm::vec3(0.5f);
        s.position[axis] = sign * c;
        s.normal = glm::vec3(0.0f, 0.0f, 1.0f);
        s.radiance = glm::vec3(1.0f);
        s.radius = bound;
        internal::InputRangeCheck ok;
        EXPECT_TRUE(ok.Add(s, 0, true).ok()) << c << " axis " << axis;
        s.radius = std::nextafter(bound, 0.0f);
        internal::InputRangeCheck refused;
        const absl::Status st = refused.Add(s, 0, true);
        EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << c << " axis " << axis;
        EXPECT_NE(st.message().find("floats are"), absl::string_view::npos) << st.message();
      }
    }
  }
}

TEST(PlanMemoryTest, SharesFitTheBudgetAndSmallBudgetsDropThreads) {
  for (uint64_t mib : {32, 64, 256, 1024, 4096}) {
    SCOPED_TRACE(mib);
    BuildOptions o;
    o.memory_bytes = mib << 20;
    o.threads = 2;
    const internal::MemoryPlan p = internal::PlanMemory(o, 100000000);
    EXPECT_LE(p.batch_bytes + p.upper_bytes + p.sort_bytes + p.fixed_bytes, o.memory_bytes);
    const uint64_t per_record =
        p.threads > 1 ? internal::kSortBytesPerRecordThreaded : internal::kSortBytesPerRecord;
    EXPECT_LE(p.run_capacity * per_record, p.sort_bytes);
    EXPECT_GE(p.run_capacity, 32768u) << "runs of " << p.run_capacity << " points";
    EXPECT_EQ(p.threads, mib >= 64 ? 2 : 1);
  }
  BuildOptions o;
  o.memory_bytes = uint64_t{256} << 20;
  o.threads = 2;
  const internal::MemoryPlan fits = internal::PlanMemory(o, 1000);
  EXPECT_EQ(fits.run_capacity, 1000u);
  EXPECT_FALSE(fits.spills);
}

// Every budget from the minimum up, for inputs from one surfel to the most a store holds (and
// unknown): the sort's runs, then the merge with the write batch and the upper groups, each fit
// in the budget together with the fixed part.
TEST(PlanMemoryTest, EveryPhaseFitsTheBudgetForExtremeInputs) {
  for (int threads : {1, 2}) {
    for (uint64_t m : {MinimumBuildMemory(BuildOptions{}), uint64_t{40} << 20, uint64_t{256} << 20,
                       uint64_t{2} << 30, uint64_t{64} << 30}) {
      for (int64_t count : {int64_t{-1}, int64_t{1}, int64_t{1700000000}, int64_t{1} << 40}) {
        SCOPED_TRACE(::testing::Message()
                     << m << " bytes, " << count << " surfels, " << threads << " threads");
        BuildOptions o;
        o.memory_bytes = m;
        o.threads = threads;
        const internal::MemoryPlan p = internal::PlanMemory(o, count);
        const uint64_t per_record = p.threads > 1 && p.spills
                                        ? internal::kSortBytesPerRecordThreaded
                                        : internal::kSortBytesPerRecord;
        EXPECT_LE(p.fixed_bytes + p.run_capacity * per_record, m);  // the sort pass
        EXPECT_LE(p.fixed_bytes + p.merge_bytes + p.batch_bytes + p.upper_bytes, m);  // the merge
        EXPECT_GE(p.fixed_bytes, uint64_t{24} << 20);
      }
    }
  }
}

}  // namespace
}  // namespace pbgi
