// ShadeMode::kShared (pbgi/shade.h): the receivers it shades get exactly what kExact gives them,
// the others are interpolated close to kExact's answer, the result does not depend on the thread
// count, an object edge (surface ids) acts like the border of the image, and bad layouts are
// rejected by field.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/shade.h"
#include "pbgi/testing.h"
#include "tests/shade/scenes.h"

namespace pbgi {
namespace {

using testing_shade::FloorAndWall;

constexpr int kSide = 64;  // the image: kSide x kSide receivers on the floor

class SharedShadeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = testing::TempDatabase::Create(FloorAndWall());
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = std::move(db).value();
    // Pixel (x, y) looks at the floor point at the centre of its cell of a kSide grid; the wall
    // runs between columns 31 and 32. Row-major pixels, but the receivers in another order (the
    // layout, not the batch order, says who is a neighbour).
    for (int y = 0; y < kSide; ++y) {
      for (int x = 0; x < kSide; ++x) {
        const glm::vec3 p((float(x) + 0.5f) / kSide, (float(y) + 0.5f) / kSide, 1e-4f);
        receivers_.push_back({p, {0, 0, 1}, {0, 0, 1}});
        pixel_.push_back(uint32_t(y * kSide + x));
        side_.push_back(x < kSide / 2 ? 0 : 1);
      }
    }
    std::reverse(receivers_.begin(), receivers_.end());
    std::reverse(pixel_.begin(), pixel_.end());
    std::reverse(side_.begin(), side_.end());
    exact_.resize(receivers_.size());
    ShadeOptions o = Base();
    ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(exact_)).ok());
  }

  ShadeOptions Base() const {
    ShadeOptions o;
    o.threads = 2;
    o.cut.max_solid_angle = 0.03f;
    o.raster.resolution = 12;
    return o;
  }
  ShadeOptions Shared(int spacing, float tolerance) const {
    ShadeOptions o = Base();
    o.mode = ShadeMode::kShared;
    o.sharing.image = {kSide, kSide, pixel_, side_};
    o.sharing.spacing = spacing;
    o.sharing.tolerance = tolerance;
    return o;
  }

  std::unique_ptr<testing::TempDatabase> db_;
  std::vector<ShadeReceiver> receivers_;
  std::vector<uint32_t> pixel_, side_;
  std::vector<ShadeResult> exact_;
};

// The sparse set and every refined receiver are shaded exactly as kExact shades them (to the
// bit); the rest are interpolated within a few tolerances of kExact, with a mean error well
// under one tolerance; and most receivers are interpolated on this smooth floor.
TEST_F(SharedShadeTest, ShadedAreExactAndInterpolatedAreClose) {
  const float tol = 0.05f;
  const ShadeOptions o = Shared(8, tol);
  std::vector<ShadeResult> got(receivers_.size());
  std::vector<uint8_t> shaded(receivers_.size(), 7);
  ShadeStats stats;
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(got), &stats, absl::MakeSpan(shaded))
          .ok());
  uint64_t n_shaded = 0;
  double occ_sum = 0, occ_max = 0, irr_rel_max = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_LE(shaded[i], 1) << i;
    if (shaded[i]) {
      ++n_shaded;
      ASSERT_EQ(got[i].occlusion, exact_[i].occlusion) << i;
      ASSERT_EQ(got[i].irradiance, exact_[i].irradiance) << i;
      ASSERT_EQ(got[i].clusters_drawn, exact_[i].clusters_drawn) << i;
      continue;
    }
    EXPECT_EQ(got[i].clusters_drawn + got[i].surfels_drawn, 0u) << i;
    const double d = std::abs(double(got[i].occlusion) - double(exact_[i].occlusion));
    occ_sum += d;
    occ_max = std::max(occ_max, d);
    const double e = glm::length(glm::dvec3(got[i].irradiance - exact_[i].irradiance)) /
                     std::max(1e-6, glm::length(glm::dvec3(exact_[i].irradiance)));
    irr_rel_max = std::max(irr_rel_max, e);
  }
  const uint64_t n_interp = got.size() - n_shaded;
  EXPECT_EQ(stats.shaded, n_shaded);
  EXPECT_EQ(stats.interpolated, n_interp);
  EXPECT_EQ(stats.receivers, got.size());
  EXPECT_EQ(stats.query.queries, n_shaded);
  // At least half the receivers interpolated (the floor is smooth away from the wall).
  EXPECT_GT(n_interp, got.size() / 2) << n_shaded << " shaded";
  ASSERT_GT(n_interp, 0u);
  EXPECT_LT(occ_sum / double(n_interp), 0.2 * tol);
  EXPECT_LT(occ_max, tol);
  EXPECT_LT(irr_rel_max, 0.15);
}

// A zero tolerance interpolates only where the shaded neighbours agree exactly; a generous one
// interpolates more; and the split-sphere rule with radius_factor 0 forbids every interpolation.
TEST_F(SharedShadeTest, ToleranceAndRadiusControlHowMuchIsShaded) {
  ShadeStats loose, tight, none;
  std::vector<ShadeResult> got(receivers_.size());
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, Shared(8, 0.05f), absl::MakeSpan(got), &loose).ok());
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, Shared(8, 0.005f), absl::MakeSpan(got), &tight).ok());
  ShadeOptions o = Shared(8, 0.05f);
  o.sharing.radius_factor = 0.0f;
  std::vector<uint8_t> shaded(receivers_.size());
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(got), &none, absl::MakeSpan(shaded))
          .ok());
  EXPECT_LT(loose.shaded, tight.shaded);
  EXPECT_EQ(none.shaded, receivers_.size());
  EXPECT_EQ(none.interpolated, 0u);
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_EQ(shaded[i], 1) << i;
    ASSERT_EQ(got[i].occlusion, exact_[i].occlusion) << i;
  }
}

// Decisions depend on shaded values and geometry only: one thread and two give the same bits.
TEST_F(SharedShadeTest, ThreadCountDoesNotChangeResults) {
  ShadeOptions one = Shared(8, 0.02f), two = one;
  one.threads = 1;
  one.z_order = false;
  std::vector<ShadeResult> a(receivers_.size()), b(receivers_.size());
  std::vector<uint8_t> sa(receivers_.size()), sb(receivers_.size());
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, one, absl::MakeSpan(a), nullptr, absl::MakeSpan(sa)).ok());
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, two, absl::MakeSpan(b), nullptr, absl::MakeSpan(sb)).ok());
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(sa[i], sb[i]) << i;
    ASSERT_EQ(a[i].occlusion, b[i].occlusion) << i;
    ASSERT_EQ(a[i].irradiance, b[i].irradiance) << i;
  }
}

// Receivers of another surface id are never interpolated from: the left half's occlusion is the
// same, to the bit, whether the right half is there with another id or not there at all (the
// image's sky). Occlusion's tolerance is absolute, so the right half does not change it.
TEST_F(SharedShadeTest, SurfaceIdEdgeActsLikeTheImageBorder) {
  ShadeOptions o = Shared(16, 0.05f);
  o.raster.compute_radiance = false;
  std::vector<ShadeResult> both(receivers_.size());
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(both)).ok());
  std::vector<ShadeReceiver> left;
  std::vector<uint32_t> left_pixel, left_side, index;
  for (size_t i = 0; i < receivers_.size(); ++i) {
    if (side_[i] != 0) continue;
    left.push_back(receivers_[i]);
    left_pixel.push_back(pixel_[i]);
    left_side.push_back(0);
    index.push_back(uint32_t(i));
  }
  o.sharing.image = {kSide, kSide, left_pixel, left_side};
  std::vector<ShadeResult> alone(left.size());
  ShadeStats stats;
  ASSERT_TRUE(ShadeBatch(db_->db(), left, o, absl::MakeSpan(alone), &stats).ok());
  ASSERT_GT(stats.interpolated, 0u);
  for (size_t k = 0; k < left.size(); ++k) {
    ASSERT_EQ(alone[k].occlusion, both[index[k]].occlusion) << k;
  }
}

// Without an image layout the receivers are a point set: the shaded ones are exact, the others
// close, and the thread count changes nothing.
TEST_F(SharedShadeTest, PointSetSharing) {
  const float tol = 0.2f;
  ShadeOptions o = Shared(4, tol);
  o.sharing.image = {};
  o.raster.compute_radiance = false;
  std::vector<ShadeResult> a(receivers_.size()), b(receivers_.size());
  std::vector<uint8_t> sa(receivers_.size()), sb(receivers_.size());
  ShadeStats stats;
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(a), &stats, absl::MakeSpan(sa)).ok());
  o.threads = 1;
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(b), nullptr, absl::MakeSpan(sb)).ok());
  double sum = 0;
  uint64_t n = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(sa[i], sb[i]) << i;
    ASSERT_EQ(a[i].occlusion, b[i].occlusion) << i;
    if (sa[i]) {
      ASSERT_EQ(a[i].occlusion, exact_[i].occlusion) << i;
    } else {
      sum += std::abs(double(a[i].occlusion) - double(exact_[i].occlusion));
      ++n;
    }
  }
  EXPECT_EQ(stats.interpolated, n);
  EXPECT_GT(n, a.size() / 2);
  ASSERT_GT(n, 0u);
  EXPECT_LT(sum / double(n), 0.075 * tol);
}

// A point set at a tight tolerance: the floor darkens toward the wall, so neighbours' values
// spread beyond the tolerance while a plane through them fits within half of it; such
// receivers are interpolated from the plane (at the receiver, within the candidates' range), not
// shaded, and stay as close to kExact as the tolerance asks.
TEST_F(SharedShadeTest, PointSetSharingFollowsGradients) {
  const float tol = 0.02f;
  ShadeOptions o = Shared(4, tol);
  o.sharing.image = {};
  o.raster.compute_radiance = false;
  std::vector<ShadeResult> got(receivers_.size());
  std::vector<uint8_t> shaded(receivers_.size());
  ShadeStats stats;
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(got), &stats, absl::MakeSpan(shaded))
          .ok());
  double sum = 0, worst = 0;
  uint64_t n = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    if (shaded[i]) {
      ASSERT_EQ(got[i].occlusion, exact_[i].occlusion) << i;
      continue;
    }
    const double e = std::abs(double(got[i].occlusion) - double(exact_[i].occlusion));
    sum += e, worst = std::max(worst, e), ++n;
  }
  std::printf("interpolated %llu of %zu, mean |error| %.5f, worst %.5f\n",
              static_cast<unsigned long long>(n), got.size(), n ? sum / double(n) : 0.0, worst);
  // The spread test alone interpolates 302 of the 4096 here.
  EXPECT_GT(n, got.size() / 3);
  ASSERT_GT(n, 0u);
  EXPECT_LT(sum / double(n), 0.1 * tol);
  EXPECT_LT(worst, tol);
}

// Progress reaches the total exactly once at the end, and a cancel raised from a progress
// report stops the shared batch with Cancelled.
TEST_F(SharedShadeTest, ProgressAndCancel) {
  ShadeOptions o = Shared(8, 0.05f);
  o.progress_interval_seconds = 0;
  uint64_t last = 0, ends = 0;
  bool monotone = true;
  o.progress = [&](const ShadeProgress& p) {
    monotone = monotone && p.done >= last && p.done <= p.total;
    last = p.done;
    if (p.done == p.total) ++ends;
  };
  std::vector<ShadeResult> out(receivers_.size());
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(out)).ok());
  EXPECT_TRUE(monotone);
  EXPECT_EQ(last, receivers_.size());
  EXPECT_GE(ends, 1u);
  std::atomic<bool> cancel{false};
  o.cancel = &cancel;
  o.progress = [&](const ShadeProgress&) { cancel.store(true); };
  const absl::Status s = ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(out));
  EXPECT_EQ(s.code(), absl::StatusCode::kCancelled) << s;
}

TEST_F(SharedShadeTest, RejectsBadLayoutsByField) {
  std::vector<ShadeResult> out(receivers_.size());
  auto code_and_message = [&](const ShadeOptions& o, const char* want) {
    const absl::Status s = ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(out));
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
    EXPECT_NE(s.message().find(want), absl::string_view::npos) << s;
  };
  ShadeOptions o = Shared(8, 0.02f);
  o.sharing.spacing = 6;
  code_and_message(o, "spacing 6");
  o = Shared(8, -1.0f);
  code_and_message(o, "tolerance");
  std::vector<uint32_t> dup = pixel_;
  dup[5] = dup[9];
  o = Shared(8, 0.02f);
  o.sharing.image.pixel_of = dup;
  code_and_message(o, "are both on pixel");
  std::vector<uint32_t> outside = pixel_;
  outside[3] = kSide * kSide;
  o.sharing.image.pixel_of = outside;
  code_and_message(o, "receiver 3 is on pixel");
  o = Shared(8, 0.02f);
  o.sharing.image.surface_id = absl::MakeConstSpan(side_).subspan(1);
  code_and_message(o, "surface ids");
  o = Shared(8, 0.02f);
  o.sharing.image.width = 0;
  code_and_message(o, "not an image size");
}

}  // namespace
}  // namespace pbgi
