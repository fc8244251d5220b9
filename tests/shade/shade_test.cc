// The shading driver (pbgi/shade.h): results independent of threads and order and equal to a
// serial Gather + Shade per receiver, errors named by receiver, the first error of any thread,
// progress and cancellation.
#include "pbgi/shade.h"

#include <atomic>
#include <limits>
#include <memory>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/testing.h"
#include "query/database_internal.h"
#include "tests/query/fake_db.h"

namespace pbgi {
namespace {

class ShadeBatchTest : public ::testing::Test {
 protected:
  void SetUp() override {
    surfels_ = testing::RandomSceneSurfels(20000, 7);
    auto db = testing::TempDatabase::Create(surfels_);
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = std::move(db).value();
    for (const Receiver& r : testing::RandomReceivers(600, 11)) {
      receivers_.push_back({r.position, r.normal, r.normal});
    }
  }
  std::vector<Surfel> surfels_;
  std::unique_ptr<testing::TempDatabase> db_;
  std::vector<ShadeReceiver> receivers_;
};

// Each receiver's result depends only on that receiver: not on the thread that shaded it, nor on
// the order in which receivers were visited.
TEST_F(ShadeBatchTest, ThreadsAndOrderDoNotChangeResults) {
  ShadeOptions one;
  one.threads = 1;
  one.z_order = false;
  std::vector<ShadeResult> a(receivers_.size()), b(receivers_.size());
  ShadeStats sa, sb;
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, one, absl::MakeSpan(a), &sa).ok());
  ShadeOptions two = one;
  two.threads = 2;
  two.z_order = true;
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, two, absl::MakeSpan(b), &sb).ok());
  int open = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].occlusion, b[i].occlusion) << i;
    EXPECT_EQ(a[i].irradiance, b[i].irradiance) << i;
    EXPECT_GE(a[i].occlusion, 0.0f);
    EXPECT_LE(a[i].occlusion, 1.0f);
    if (a[i].occlusion < 1.0f) ++open;
  }
  EXPECT_GT(open, 0);
  EXPECT_EQ(sa.receivers, receivers_.size());
  EXPECT_EQ(sa.query.clusters + sa.query.surfels, sb.query.clusters + sb.query.surfels);
  EXPECT_GT(sa.query.nodes_visited, 0u);
  EXPECT_EQ(sa.query.queries, receivers_.size());
  EXPECT_EQ(sb.query.queries, receivers_.size());
}

// The driver is exactly Gather then Shade per receiver, to the bit (glossy lobe included): with
// the lobe-aware cut (ShadeOptions::lobe_cut, the default), Gather's cut carries the raster's
// lobe around each receiver's reflection; without it, the cut as given.
TEST_F(ShadeBatchTest, EqualsSerialGatherAndShade) {
  for (const bool lobe_cut : {true, false}) {
    SCOPED_TRACE(lobe_cut ? "lobe cut" : "cut as given");
    ShadeOptions o;
    o.threads = 2;
    o.cut.cosine_weighted = true;
    o.lobe_cut = lobe_cut;
    o.raster.lobe = GlossyLobe::kPhong;
    for (size_t i = 0; i < receivers_.size(); ++i) {
      receivers_[i].reflection = glm::vec3(0.3f, float(i % 7) - 3.0f, 1.0f);
    }
    std::vector<ShadeResult> got(receivers_.size());
    ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(got)).ok());
    auto reader = db_->db().NewReader();
    ASSERT_TRUE(reader.ok());
    MicroBuffer buffer;
    Gathered g;
    for (size_t i = 0; i < receivers_.size(); ++i) {
      const ShadeReceiver& r = receivers_[i];
      Cut cut = o.cut;
      if (lobe_cut) {
        cut.lobe.kind = CutLobeKind::kPhong;
        cut.lobe.direction = r.reflection;
        cut.lobe.phong_exponent = o.raster.phong_exponent;
      }
      ASSERT_TRUE((*reader)->Gather({r.position, r.normal}, cut, &g).ok());
      ShadeResult want;
      ASSERT_TRUE(Shade(g, r, o.raster, &buffer, &want).ok());
      ASSERT_EQ(got[i].occlusion, want.occlusion) << i;
      ASSERT_EQ(got[i].irradiance, want.irradiance) << i;
      ASSERT_EQ(got[i].glossy, want.glossy) << i;
      ASSERT_EQ(got[i].clusters_drawn, want.clusters_drawn) << i;
    }
  }
}

TEST_F(ShadeBatchTest, RejectsBadReceiversByIndex) {
  std::vector<ShadeReceiver> bad = receivers_;
  bad[17].normal = glm::vec3(0.0f);
  std::vector<ShadeResult> out(bad.size());
  absl::Status s = ShadeBatch(db_->db(), bad, ShadeOptions{}, absl::MakeSpan(out));
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("receiver 17"), absl::string_view::npos) << s;
  bad[17].normal = glm::vec3(0, 0, 1);
  bad[3].position.x = std::numeric_limits<float>::quiet_NaN();
  s = ShadeBatch(db_->db(), bad, ShadeOptions{}, absl::MakeSpan(out));
  EXPECT_NE(s.message().find("receiver 3"), absl::string_view::npos) << s;
  std::vector<ShadeResult> wrong(5);
  s = ShadeBatch(db_->db(), receivers_, ShadeOptions{}, absl::MakeSpan(wrong));
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  ShadeOptions res;
  res.raster.resolution = 2;
  s = ShadeBatch(db_->db(), receivers_, res, absl::MakeSpan(out));
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(ShadeBatchTest, ReportsProgressUpToTheTotal) {
  ShadeOptions o;
  o.threads = 2;
  o.progress_interval_seconds = 0;  // every block
  std::vector<ShadeProgress> seen;
  o.progress = [&](const ShadeProgress& p) { seen.push_back(p); };
  std::vector<ShadeResult> out(receivers_.size());
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(out)).ok());
  ASSERT_GE(seen.size(), 2u);  // blocks of at most 64 receivers, then the end
  for (size_t i = 0; i < seen.size(); ++i) {
    EXPECT_EQ(seen[i].total, receivers_.size());
    EXPECT_LE(seen[i].done, seen[i].total);
    if (i > 0) {
      EXPECT_GE(seen[i].done, seen[i - 1].done);
    }
  }
  EXPECT_EQ(seen.back().done, receivers_.size());
}

TEST_F(ShadeBatchTest, CancelStopsTheBatch) {
  std::atomic<bool> cancel{false};
  ShadeOptions o;
  o.threads = 2;
  o.cancel = &cancel;
  o.progress_interval_seconds = 0;
  // Raised from the first progress report: the batch stops at the next block.
  o.progress = [&](const ShadeProgress&) { cancel.store(true); };
  std::vector<ShadeResult> out(receivers_.size());
  ShadeStats stats;
  absl::Status s = ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(out), &stats);
  EXPECT_EQ(s.code(), absl::StatusCode::kCancelled) << s;
  cancel.store(true);
  o.progress = nullptr;
  s = ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(out));
  EXPECT_EQ(s.code(), absl::StatusCode::kCancelled) << s;
  EXPECT_NE(s.message().find("after 0 of 600"), absl::string_view::npos) << s;
}

// A damaged page fails the batch with the page's own error, whichever thread read it.
TEST(ShadeBatchErrorTest, FirstErrorOfAnyThreadWins) {
  internal::FakeDb fake = internal::BuildFakeDb(testing::RandomSceneSurfels(3000, 5), {});
  fake.source->FailPage(Section::kPoints, 0, absl::DataLossError("fake-db: points page 0: bad"));
  auto db = internal::OpenDatabase(std::move(fake.source));
  ASSERT_TRUE(db.ok()) << db.status();
  std::vector<ShadeReceiver> receivers;
  for (const Receiver& r : testing::RandomReceivers(400, 3)) {
    receivers.push_back({r.position, r.normal, r.normal});
  }
  ShadeOptions o;
  o.threads = 2;
  o.cut.max_solid_angle = 0.0f;  // every surfel on its own: every point page is read
  std::vector<ShadeResult> out(receivers.size());
  absl::Status s = ShadeBatch(**db, receivers, o, absl::MakeSpan(out));
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find("points page 0: bad"), absl::string_view::npos) << s;
}

}  // namespace
}  // namespace pbgi
