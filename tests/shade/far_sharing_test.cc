// Far-field sharing (pbgi/query.h FarCut, pbgi/raster.h FarBuffer, ShadeOptions::far_sharing):
// - for every member of a group, the shared far clusters plus its own near gather are a valid
//   cut (brute force: every surfel in front represented exactly once, every cluster obeys the
//   member's cut), for plain and cosine-weighted cuts on random scenes;
// - with no far field (a distance factor too large for any node), a member's near gather and
//   shading equal Gather and Shade to the bit, and groups of one equal kExact;
// - on a floor with a wall, shading with a shared far field stays within a stated tolerance of
//   the per-receiver path, with fewer elements per receiver, and one thread gives two threads'
//   bits;
// - bad options are rejected by field.
#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "glm/geometric.hpp"
#include "gtest/gtest.h"
#include "pbgi/shade.h"
#include "pbgi/testing.h"
#include "tests/shade/scenes.h"

namespace pbgi {
namespace {

using testing_shade::FloorAndWall;

// The far clusters and one member's near gather as one result.
Gathered Combined(const FarCut& far, const Gathered& near) {
  Gathered g = near;
  g.clusters.insert(g.clusters.end(), far.far.clusters.begin(), far.far.clusters.end());
  return g;
}

glm::vec3 RandomUnit(std::mt19937_64& rng) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  glm::vec3 v;
  do {
    v = {n(rng), n(rng), n(rng)};
  } while (glm::dot(v, v) < 1e-4f);
  return glm::normalize(v);
}

class FarCutTest : public ::testing::TestWithParam<bool> {};

// Groups of random size, place and normal over a random scene: the shared far set plus each
// member's near gather is a valid cut for that member, and the far set is not empty for most
// groups (the property is not vacuous).
TEST_P(FarCutTest, FarPlusNearIsAValidCutForEveryMember) {
  const bool cosine = GetParam();
  const std::vector<Surfel> scene = testing::RandomSceneSurfels(30000, 7);
  auto db = testing::TempDatabase::Create(scene);
  ASSERT_TRUE(db.ok()) << db.status();
  auto reader = (*db)->db().NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();
  auto surfels = testing::ReadAllSurfels((*db)->db());
  ASSERT_TRUE(surfels.ok()) << surfels.status();
  Cut cut;
  cut.max_solid_angle = 0.03f;
  cut.cosine_weighted = cosine;
  cut.curved_scale = 0.3f;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  int with_far = 0, groups = 0;
  uint64_t near_elements = 0, exact_elements = 0;
  FarCut far;
  Gathered near, exact;
  for (int g = 0; g < 150; ++g) {
    ReceiverGroup group;
    group.centre = glm::vec3(-0.1f + 1.2f * u(rng), -0.1f + 1.2f * u(rng), -0.1f + 1.2f * u(rng));
    group.radius = 0.002f + 0.03f * u(rng);
    group.normal = RandomUnit(rng);
    // Members: the centre and points of the sphere, some on the group's plane, some off it.
    const bool flat = g % 2 == 0;
    std::vector<glm::vec3> members = {group.centre};
    for (int k = 0; k < 8; ++k) {
      glm::vec3 d = RandomUnit(rng);
      if (flat) d -= glm::dot(d, group.normal) * glm::normalize(group.normal);
      if (glm::length(d) > 0.0f) d = glm::normalize(d);
      members.push_back(group.centre + (0.999f * group.radius * u(rng)) * d);
    }
    for (const glm::vec3& p : members) {
      group.thickness =
          std::max(group.thickness, std::fabs(glm::dot(group.normal, p - group.centre)));
    }
    group.thickness = std::min(group.thickness, group.radius);
    const float factor = g % 3 == 0 ? 2.0f : 6.0f;
    // Half the groups with the curved-box test (Cut::curved_box_scale), which the far set must
    // keep for every member too.
    cut.curved_box_scale = g % 4 < 2 ? 1.0f : 0.0f;
    ASSERT_TRUE((*reader)->GatherFar(group, cut, factor, &far).ok());
    ++groups;
    if (!far.far.clusters.empty()) ++with_far;
    EXPECT_TRUE(far.far.surfels.empty());
    for (const glm::vec3& p : members) {
      ASSERT_TRUE((*reader)->GatherNear(p, cut, far, &near).ok());
      const Receiver r{p, far.group.normal};
      const absl::Status s = testing::CheckValidCut(Combined(far, near), *surfels, r, cut);
      ASSERT_TRUE(s.ok()) << "group " << g << ": " << s;
      ASSERT_TRUE((*reader)->Gather(r, cut, &exact).ok());
      near_elements += near.size();
      exact_elements += exact.size();
    }
  }
  EXPECT_GE(with_far, groups / 2);
  // The point of sharing: a member gathers less on its own.
  EXPECT_LT(near_elements, exact_elements);
}

INSTANTIATE_TEST_SUITE_P(PlainAndCosine, FarCutTest, ::testing::Bool());

constexpr int kSide = 48;

class FarShadeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = testing::TempDatabase::Create(FloorAndWall());
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = std::move(db).value();
    for (int y = 0; y < kSide; ++y) {
      for (int x = 0; x < kSide; ++x) {
        const glm::vec3 p((float(x) + 0.5f) / kSide, (float(y) + 0.5f) / kSide, 1e-4f);
        receivers_.push_back({p, {0, 0, 1}, {0, 0, 1}});
      }
    }
    exact_.resize(receivers_.size());
    ASSERT_TRUE(
        ShadeBatch(db_->db(), receivers_, Base(), absl::MakeSpan(exact_), &exact_stats_).ok());
  }
  static ShadeOptions Base() {
    ShadeOptions o;
    o.threads = 2;
    o.cut.max_solid_angle = 0.03f;
    o.cut.cosine_weighted = true;
    o.raster.resolution = 12;
    o.raster.footprint = Footprint::kPolygons;
    return o;
  }
  static ShadeOptions Far(float radius, float factor) {
    ShadeOptions o = Base();
    o.far_sharing.enabled = true;
    o.far_sharing.max_radius = radius;
    o.far_sharing.distance_factor = factor;
    o.far_sharing.max_members = 16;
    return o;
  }

  std::unique_ptr<testing::TempDatabase> db_;
  std::vector<ShadeReceiver> receivers_;
  std::vector<ShadeResult> exact_;
  ShadeStats exact_stats_;
};

// Without a far field (no node lies 1000 radii away in a unit scene) the near gather is Gather
// and ShadeWithFar is Shade, to the bit; and groups of one are shaded as kExact shades them.
TEST_F(FarShadeTest, NoFarFieldAndGroupsOfOneAreExact) {
  auto reader = db_->db().NewReader();
  ASSERT_TRUE(reader.ok());
  const RasterOptions ro = Base().raster;
  const Cut cut = Base().cut;
  MicroBuffer mb;
  FarCut far;
  FarBuffer fb;
  Gathered near, exact;
  for (size_t i = 0; i < receivers_.size(); i += 97) {
    const ShadeReceiver& r = receivers_[i];
    ASSERT_TRUE((*reader)->GatherFar({r.position, 0.01f, r.normal, 0.0f}, cut, 1000.0f, &far).ok());
    ASSERT_TRUE(far.far.clusters.empty());
    ASSERT_TRUE(ShadeFar(far.far, r, ro, &mb, &fb).ok());
    ASSERT_TRUE((*reader)->GatherNear(r.position, cut, far, &near).ok());
    ASSERT_TRUE((*reader)->Gather({r.position, r.normal}, cut, &exact).ok());
    ASSERT_EQ(near.clusters.size(), exact.clusters.size());
    ASSERT_EQ(near.surfel_ids, exact.surfel_ids);
    ShadeResult a, b;
    ASSERT_TRUE(ShadeWithFar(near, r, fb, ro, &mb, &a).ok());
    ASSERT_TRUE(Shade(exact, r, ro, &mb, &b).ok());
    ASSERT_EQ(a.occlusion, b.occlusion) << i;
    ASSERT_EQ(a.irradiance, b.irradiance) << i;
  }
  // A radius too small for any two receivers: every group has one member.
  ShadeStats stats;
  std::vector<ShadeResult> got(receivers_.size());
  ASSERT_TRUE(
      ShadeBatch(db_->db(), receivers_, Far(1e-7f, 8.0f), absl::MakeSpan(got), &stats).ok());
  EXPECT_EQ(stats.far_groups, 0u);
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_EQ(got[i].occlusion, exact_[i].occlusion) << i;
    ASSERT_EQ(got[i].irradiance, exact_[i].irradiance) << i;
  }
}

// With a shared far field, occlusion stays within 0.05 of the per-receiver path everywhere and
// 0.01 on average, irradiance within 8% on average (the far buffer is drawn from the group's
// centre: a far element's direction is off by up to 1 / distance_factor radians, which opens
// or overlaps the seam where a surface crosses from the near field into the far one); each
// receiver draws fewer elements on its own; and the groups (and so the bits) do not depend on
// the thread count.
TEST_F(FarShadeTest, SharedFarFieldIsCloseToThePerReceiverPath) {
  ShadeOptions o = Far(0.03f, 16.0f);
  std::vector<ShadeResult> got(receivers_.size());
  ShadeStats stats;
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(got), &stats).ok());
  EXPECT_GT(stats.far_groups, receivers_.size() / 16);
  EXPECT_GT(stats.far_members, receivers_.size() / 2);
  double occ_sum = 0, occ_max = 0, irr_rel_sum = 0;
  uint64_t drawn = 0, exact_drawn = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    const double d = std::abs(double(got[i].occlusion) - double(exact_[i].occlusion));
    occ_sum += d;
    occ_max = std::max(occ_max, d);
    irr_rel_sum += glm::length(glm::dvec3(got[i].irradiance - exact_[i].irradiance)) /
                   std::max(1e-6, glm::length(glm::dvec3(exact_[i].irradiance)));
    drawn += got[i].clusters_drawn + got[i].surfels_drawn;
    exact_drawn += exact_[i].clusters_drawn + exact_[i].surfels_drawn;
  }
  const double n = double(got.size());
  EXPECT_LT(occ_sum / n, 0.01);
  EXPECT_LT(occ_max, 0.05);
  EXPECT_LT(irr_rel_sum / n, 0.08);
  EXPECT_LT(drawn, exact_drawn) << drawn << " elements drawn per receiver against " << exact_drawn;

  ShadeOptions one = o;
  one.threads = 1;
  std::vector<ShadeResult> single(receivers_.size());
  ASSERT_TRUE(ShadeBatch(db_->db(), receivers_, one, absl::MakeSpan(single)).ok());
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_EQ(got[i].occlusion, single[i].occlusion) << i;
    ASSERT_EQ(got[i].irradiance, single[i].irradiance) << i;
  }
}

TEST_F(FarShadeTest, BadOptionsAreRejectedByField) {
  std::vector<ShadeResult> got(receivers_.size());
  auto message = [&](const ShadeOptions& o) {
    return std::string(ShadeBatch(db_->db(), receivers_, o, absl::MakeSpan(got)).message());
  };
  ShadeOptions o = Far(0.0f, 8.0f);
  EXPECT_NE(message(o).find("max_radius"), std::string::npos);
  o = Far(0.03f, 0.5f);
  EXPECT_NE(message(o).find("distance_factor"), std::string::npos);
  o = Far(0.03f, 8.0f);
  o.far_sharing.max_members = 1;
  EXPECT_NE(message(o).find("max_members"), std::string::npos);
  o = Far(0.03f, 8.0f);
  o.cut.max_distance = 1.0f;
  EXPECT_NE(message(o).find("max_distance"), std::string::npos);
  o = Far(0.03f, 8.0f);
  o.raster.lobe = GlossyLobe::kPhong;
  EXPECT_NE(message(o).find("lobe"), std::string::npos);
  auto reader = db_->db().NewReader();
  ASSERT_TRUE(reader.ok());
  FarCut far;
  Gathered near;
  ASSERT_TRUE(
      (*reader)->GatherFar({{0.5f, 0.5f, 0.0f}, 0.01f, {0, 0, 1}, 0.0f}, Cut{}, 8.0f, &far).ok());
  const absl::Status s = (*reader)->GatherNear({0.6f, 0.5f, 0.0f}, Cut{}, far, &near);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(std::string(s.message()).find("outside its radius"), std::string::npos) << s;
  EXPECT_EQ(
      (*reader)->GatherFar({{0.5f, 0.5f, 0.0f}, 0.01f, {0, 0, 1}, 0.02f}, Cut{}, 8.0f, &far).code(),
      absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace pbgi
