// Resumable builds (BuildOptions::resumable, docs/format.md "Resume"): a build interrupted after
// its sort pass (the test hook, or a cancel in the middle of the merge) keeps its runs and a
// manifest; a build with `resume` merges them and writes the same pages as an uninterrupted
// build; anything that does not match is refused by name; the runs are gone after success.
#include <atomic>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "build/run_manifest.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/store.h"
#include "tests/build/test_clouds.h"
#include "tree/format.h"

namespace pbgi {
namespace {

using testing_build::ScratchDir;
namespace fs = std::filesystem;

// Every node and point page of `a` equals `b`'s (header record counts and payload bytes), and the
// meta records agree on everything but timings and provenance.
void ExpectSamePages(const std::string& a, const std::string& b) {
  auto sa = PageStore::Open(a);
  auto sb = PageStore::Open(b);
  ASSERT_TRUE(sa.ok()) << sa.status();
  ASSERT_TRUE(sb.ok()) << sb.status();
  const StoreMeta& ma = (*sa)->meta();
  const StoreMeta& mb = (*sb)->meta();
  EXPECT_EQ(ma.point_count, mb.point_count);
  EXPECT_EQ(ma.node_count, mb.node_count);
  EXPECT_EQ(ma.node_pages, mb.node_pages);
  EXPECT_EQ(ma.point_pages, mb.point_pages);
  EXPECT_EQ(ma.root, mb.root);
  EXPECT_EQ(ma.max_depth, mb.max_depth);
  EXPECT_EQ(ma.stats.at("key_bounds"), mb.stats.at("key_bounds"));
  EXPECT_EQ(ma.stats.at("skipped"), mb.stats.at("skipped"));
  auto ta = (*sa)->BeginRead();
  auto tb = (*sb)->BeginRead();
  ASSERT_TRUE(ta.ok() && tb.ok());
  for (Section s : {Section::kNodes, Section::kPoints}) {
    const uint64_t pages = s == Section::kNodes ? ma.node_pages : ma.point_pages;
    for (uint64_t p = 0; p < pages; ++p) {
      auto va = ta->Get(s, p);
      auto vb = tb->Get(s, p);
      ASSERT_TRUE(va.ok() && vb.ok()) << SectionName(s) << " page " << p;
      ASSERT_EQ(va->header->record_count, vb->header->record_count);
      ASSERT_EQ(va->payload.size(), vb->payload.size());
      ASSERT_EQ(0, std::memcmp(va->payload.data(), vb->payload.data(), va->payload.size()))
          << SectionName(s) << " page " << p;
    }
  }
  EXPECT_TRUE(VerifyTree(**sb).ok()) << VerifyTree(**sb);
}

class ResumeTest : public ::testing::TestWithParam<int> {
 protected:
  void SetUp() override {
    cloud_ = testing_build::SurfaceCloud(20000, 23);
    tmp_ = dir_.Sub("tmp");
    fs::create_directories(tmp_);
  }
  BuildOptions Options() const {
    BuildOptions o;
    o.memory_bytes = 1;  // runs of 256 records: 79 runs, and intermediate merge passes
    o.threads = GetParam();
    o.tmp_dir = tmp_;
    o.resumable.input_identity = "cloud 20000 seed 23";
    return o;
  }
  absl::StatusOr<BuildStats> Build(const std::string& db, const BuildOptions& o) {
    VectorSurfelSource src(cloud_);
    return BuildDatabase(src, db, o);
  }

  ScratchDir dir_{"resume"};
  std::vector<Surfel> cloud_;
  std::string tmp_;
};

TEST_P(ResumeTest, ResumedBuildsEqualAnUninterruptedOne) {
  const std::string full = dir_.Sub("full");
  auto st = Build(full, Options());
  ASSERT_TRUE(st.ok()) << st.status();
  ASSERT_GT(st->runs_spilled, 10u);
  ASSERT_GT(st->merge_passes, 0u);
  EXPECT_FALSE(st->resumed);
  EXPECT_TRUE(fs::is_empty(tmp_)) << "a finished build leaves its runs behind";

  // Interrupted right after the sort pass (the hook).
  const std::string db = dir_.Sub("after_sort");
  BuildOptions o = Options();
  o.resumable.stop_after_sort = true;
  auto broken = Build(db, o);
  ASSERT_TRUE(absl::IsCancelled(broken.status())) << broken.status();
  const std::string runs = BuildRunDirectory(db, o);
  ASSERT_TRUE(fs::exists(runs + "/manifest"));
  EXPECT_FALSE(PageStore::Open(db).ok()) << "an interrupted build left a store that opens";

  BuildOptions r = Options();
  r.resumable.resume = true;
  r.leaf_size = 16;  // options after the sort may differ; these do not, so the pages must match
  auto resumed = Build(db, r);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_TRUE(resumed->resumed);
  EXPECT_EQ(resumed->points, st->points);
  EXPECT_EQ(resumed->runs_spilled, st->runs_spilled);
  EXPECT_FALSE(fs::exists(runs)) << "the kept runs outlive the resumed build";
  ExpectSamePages(full, db);
}

// Interrupted in the middle of the merge+octree pass (a cancel, as Ctrl-C sets it, once the
// pass has reported progress: progress comes every 2^18 points, hence the larger cloud), then
// resumed, and interrupted in the resumed merge again: the runs survive both.
TEST_P(ResumeTest, CancelInTheMergeKeepsTheRunsForAnotherResume) {
  cloud_ = testing_build::SurfaceCloud(300000, 29);
  BuildOptions o = Options();
  o.memory_bytes = 40 << 20;
  const std::string full = dir_.Sub("full");
  auto st = Build(full, o);
  ASSERT_TRUE(st.ok()) << st.status();
  ASSERT_GT(st->runs_spilled, 1u);
  const std::string db = dir_.Sub("mid");
  const std::string runs = BuildRunDirectory(db, o);
  for (bool resume : {false, true}) {
    BuildOptions c = o;
    c.resumable.resume = resume;
    std::atomic<bool> cancel{false};
    c.cancel = &cancel;
    c.progress = [&](const BuildProgress& p) {
      if (std::string(p.pass) == "merge+octree") cancel = true;
    };
    auto broken = Build(db, c);
    ASSERT_TRUE(absl::IsCancelled(broken.status())) << broken.status();
    ASSERT_TRUE(fs::exists(runs + "/manifest"));
  }
  BuildOptions r = o;
  r.resumable.resume = true;
  auto resumed = Build(db, r);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_TRUE(resumed->resumed);
  EXPECT_FALSE(fs::exists(runs));
  ExpectSamePages(full, db);
}

TEST_P(ResumeTest, RefusesWhatDoesNotMatch) {
  const std::string db = dir_.Sub("db");
  BuildOptions o = Options();
  o.resumable.resume = true;
  // Nothing kept yet.
  auto none = Build(db, o);
  EXPECT_TRUE(absl::IsNotFound(none.status())) << none.status();
  EXPECT_NE(none.status().message().find("nothing to resume"), std::string::npos);

  BuildOptions stop = Options();
  stop.resumable.stop_after_sort = true;
  ASSERT_TRUE(absl::IsCancelled(Build(db, stop).status()));
  const std::string runs = BuildRunDirectory(db, o);

  auto refused = [&](BuildOptions r, const char* what) {
    r.resumable.resume = true;
    auto s = Build(db, r);
    EXPECT_TRUE(absl::IsFailedPrecondition(s.status())) << what << ": " << s.status();
    EXPECT_NE(s.status().message().find(what), std::string::npos) << s.status();
    EXPECT_TRUE(fs::exists(runs + "/manifest")) << "a refused resume removed the runs";
  };
  BuildOptions other_input = Options();
  other_input.resumable.input_identity = "another cloud";
  refused(other_input, "the input");
  BuildOptions occlusion = Options();
  occlusion.channels = Channels::kOcclusion;
  refused(occlusion, "radiance");
  BuildOptions skip = Options();
  skip.skip_invalid = true;
  refused(skip, "--skip-invalid");
  BuildOptions normals = Options();
  normals.estimate.normals = true;
  refused(normals, "estimated normals");

  // A damaged run: found by its CRC while merging. A short one: at once, by its size.
  const std::string run = runs + "/run-000003";
  {
    std::fstream f(run, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(100);
    f.put('\x5a');
  }
  BuildOptions r = Options();
  r.resumable.resume = true;
  auto damaged = Build(db, r);
  EXPECT_TRUE(absl::IsDataLoss(damaged.status())) << damaged.status();
  EXPECT_NE(damaged.status().message().find("run-000003"), std::string::npos);
  EXPECT_NE(damaged.status().message().find("checksum"), std::string::npos);
  fs::resize_file(run, fs::file_size(run) - 48);
  auto shortened = Build(db, r);
  EXPECT_TRUE(absl::IsDataLoss(shortened.status())) << shortened.status();
  EXPECT_NE(shortened.status().message().find("run-000003"), std::string::npos);
  EXPECT_FALSE(PageStore::Open(db).ok());

  // A fresh build (no resume) replaces the damaged runs, and finishes clean.
  auto fresh = Build(db, Options());
  ASSERT_TRUE(fresh.ok()) << fresh.status();
  EXPECT_TRUE(fs::is_empty(tmp_));
}

// A manifest cut short (a crash while writing it cannot leave one: it is renamed into place; a
// hand-edited or truncated one) is refused as incomplete.
TEST_P(ResumeTest, TruncatedManifestIsRefused) {
  const std::string db = dir_.Sub("db");
  BuildOptions stop = Options();
  stop.resumable.stop_after_sort = true;
  ASSERT_TRUE(absl::IsCancelled(Build(db, stop).status()));
  const std::string manifest = BuildRunDirectory(db, stop) + "/manifest";
  fs::resize_file(manifest, fs::file_size(manifest) / 2);
  BuildOptions r = Options();
  r.resumable.resume = true;
  auto s = Build(db, r);
  EXPECT_TRUE(absl::IsDataLoss(s.status())) << s.status();
  EXPECT_NE(s.status().message().find("not a complete manifest"), std::string::npos);
}

INSTANTIATE_TEST_SUITE_P(Threads, ResumeTest, ::testing::Values(1, 2));

}  // namespace
}  // namespace pbgi
