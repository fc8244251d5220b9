// The cut that sees radiance (Cut::radiance_contrast; docs/design.md, "A cut that sees
// radiance") end to end: database, EffectiveCut, Gather, Shade.
#include <cmath>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/shade.h"
#include "pbgi/testing.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

// A closed room with dark walls and a bright panel in its ceiling, as cornell's light; receivers
// on the floor. Taken whole, a node of the ceiling that holds part of the panel spreads the
// panel's light over its whole cell, and the part of it that a receiver sees is not the part
// that is lit: cornell's irradiance was 3.5 % of the mean off at the default cut, and 1.85 % at
// a six times finer one. With the contrast the panel's edge is refined alone. Against a cut 30
// times finer (msa 0.001), at the tools' defaults otherwise (msa 0.03, res 12).
TEST(RadianceContrastTest, APanelsEdgeIsRefinedAndTheIrradianceComesCloser) {
  const float half = 2.0f, panel = 0.45f;
  std::vector<Surfel> surfels = testing_raster::RoomSurfels(half, 0.02f);
  for (Surfel& s : surfels) {
    const bool lit = s.position.z > half - 1e-3f && std::fabs(s.position.x - 0.3f) < panel &&
                     std::fabs(s.position.y + 0.2f) < panel;
    s.radiance = glm::vec3(lit ? 10.0f : 0.1f);
  }
  auto db = testing::TempDatabase::Create(surfels);
  ASSERT_TRUE(db.ok()) << db.status();
  std::vector<ShadeReceiver> receivers;
  for (float x : {-1.5f, -0.7f, 0.1f, 0.9f, 1.6f}) {
    for (float y : {-1.4f, -0.3f, 0.6f, 1.5f}) {
      receivers.push_back({{x, y, -half + 1e-3f}, {0, 0, 1}, {0, 0, 1}});
    }
  }
  auto options = [](float msa, float contrast) {
    ShadeOptions o;
    o.cut.max_solid_angle = msa;
    o.cut.cosine_weighted = true;
    o.cut.curved_scale = 0.3f;
    o.cut.curved_box_scale = 1.0f;
    o.raster.footprint = Footprint::kPolygons;
    o.radiance_contrast = contrast;
    return o;
  };
  auto shade = [&](const ShadeOptions& o, ShadeStats* stats) {
    std::vector<ShadeResult> out(receivers.size());
    EXPECT_TRUE(ShadeBatch((*db)->db(), receivers, o, absl::MakeSpan(out), stats).ok());
    return out;
  };
  ShadeStats s_fine, s_plain, s_contrast;
  const auto fine = shade(options(0.001f, 0.0f), &s_fine);
  const auto plain = shade(options(0.03f, 0.0f), &s_plain);
  const auto contrast = shade(options(0.03f, kRecommendedRadianceContrast), &s_contrast);
  double e_plain = 0.0, e_contrast = 0.0, mean = 0.0;
  for (size_t i = 0; i < receivers.size(); ++i) {
    mean += fine[i].irradiance.x;
    e_plain += std::fabs(plain[i].irradiance.x - fine[i].irradiance.x);
    e_contrast += std::fabs(contrast[i].irradiance.x - fine[i].irradiance.x);
  }
  const double clusters_plain = double(s_plain.query.clusters) / receivers.size();
  const double clusters_contrast = double(s_contrast.query.clusters) / receivers.size();
  RecordProperty("relative_error_plain", std::to_string(e_plain / mean));
  RecordProperty("relative_error_contrast", std::to_string(e_contrast / mean));
  RecordProperty("clusters_plain", std::to_string(clusters_plain));
  RecordProperty("clusters_contrast", std::to_string(clusters_contrast));
  EXPECT_LT(e_contrast, 0.6 * e_plain);
  // The panel's edge alone is refined: far fewer clusters than the finer cut's.
  EXPECT_GT(clusters_contrast, clusters_plain);
  EXPECT_LT(clusters_contrast, 1.5 * clusters_plain);

  // Every receiver's cut is valid against brute force with the contrast (the harness divides
  // each cluster's max solid angle as the traversal does).
  absl::StatusOr<Cut> cut = EffectiveCut((*db)->db(), options(0.03f, kRecommendedRadianceContrast));
  ASSERT_TRUE(cut.ok()) << cut.status();
  EXPECT_EQ(cut->radiance_contrast, kRecommendedRadianceContrast);
  EXPECT_GT(cut->contrast_floor, 0.0f);
  auto reader = (*db)->db().NewReader();
  ASSERT_TRUE(reader.ok());
  Gathered g;
  for (const ShadeReceiver& r : receivers) {
    const Receiver q{r.position, r.normal};
    ASSERT_TRUE((*reader)->Gather(q, *cut, &g).ok());
    const absl::Status s = testing::CheckValidCut(g, (*db)->surfels(), q, *cut);
    ASSERT_TRUE(s.ok()) << s;
  }
  // An occlusion-only shading does not use it.
  ShadeOptions occ = options(0.03f, kRecommendedRadianceContrast);
  occ.raster.compute_radiance = false;
  absl::StatusOr<Cut> occ_cut = EffectiveCut((*db)->db(), occ);
  ASSERT_TRUE(occ_cut.ok());
  EXPECT_EQ(occ_cut->radiance_contrast, 0.0f);
}

}  // namespace
}  // namespace pbgi
