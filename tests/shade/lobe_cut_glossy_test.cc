// The lobe-aware cut (ShadeOptions::lobe_cut, Cut::lobe) isolated: glossy receivers facing a
// wall whose radiance varies on about the scale of a Phong 32 lobe's footprint. At the default
// max_solid_angle the plain cut brings one mean radiance per cluster of a sixth of the lobe;
// the lobe cut refines where the lobe looks and comes much closer to brute force (msa 0, every
// surfel on its own), with the same rasterizer. Occlusion and irradiance do not change.
#include <cmath>
#include <cstdio>
#include <memory>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/shade.h"
#include "pbgi/testing.h"

namespace pbgi {
namespace {

class LobeCutGlossyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    // The wall z = 0, x and y in [-1.5, 1.5], facing +z; radiance a checkerboard of squares
    // of 0.3 (a Phong 32 lobe from a receiver 1 away covers about 0.4).
    const float spacing = 0.015f, half = 1.5f, period = 0.6f;
    const int n = static_cast<int>(2 * half / spacing);
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        Surfel s;
        s.position = glm::vec3(-half + (i + 0.5f) * spacing, -half + (j + 0.5f) * spacing, 0.0f);
        s.normal = glm::vec3(0, 0, 1);
        s.radius = 0.6f * spacing;
        // A checkerboard: sharp edges, as an emitter's or a shadow's.
        const int cx = static_cast<int>(std::floor(s.position.x / period));
        const int cy = static_cast<int>(std::floor(s.position.y / period + 0.3f));
        const float v = (cx + cy) % 2 == 0 ? 0.9f : 0.1f;
        s.radiance = glm::vec3(v, 0.5f * v, 1.0f - v);
        surfels_.push_back(s);
      }
    }
    BuildOptions b;
    b.memory_bytes = 128 << 20;
    b.channels = Channels::kRadiance;
    auto db = testing::TempDatabase::Create(surfels_, b);
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = std::move(db).value();
    // Receivers 0.8 .. 1.2 above the wall facing it, their lobes tilted up to ~25 degrees.
    for (int k = 0; k < 24; ++k) {
      const float a = 0.7f * k, t = 0.45f * std::sin(1.3f * k);
      ShadeReceiver r;
      r.position = glm::vec3(0.3f * std::cos(a), 0.3f * std::sin(a), 0.8f + 0.4f * (k % 5) / 4);
      r.normal = glm::vec3(0.1f * std::sin(a), 0.0f, -1.0f);
      r.reflection = glm::vec3(t * std::cos(a + 1), t * std::sin(a + 1), -1.0f);
      receivers_.push_back(r);
    }
  }

  std::vector<ShadeResult> Run(float msa, bool lobe_cut, GlossyLobe lobe, ShadeStats* stats) {
    ShadeOptions so;
    so.threads = 2;
    so.cut.max_solid_angle = msa;
    so.lobe_cut = lobe_cut;
    so.raster.lobe = lobe;
    so.raster.phong_exponent = 32.0f;
    so.raster.ggx_roughness = 0.3f;
    std::vector<ShadeResult> out(receivers_.size());
    const absl::Status s = ShadeBatch(db_->db(), receivers_, so, absl::MakeSpan(out), stats);
    EXPECT_TRUE(s.ok()) << s;
    return out;
  }

  static double MeanAbsDiff(const std::vector<ShadeResult>& a, const std::vector<ShadeResult>& b) {
    double sum = 0;
    for (size_t i = 0; i < a.size(); ++i) {
      const glm::vec3 d = glm::abs(a[i].glossy - b[i].glossy);
      sum += (d.x + d.y + d.z) / 3.0;
    }
    return sum / double(a.size());
  }

  std::vector<Surfel> surfels_;
  std::unique_ptr<testing::TempDatabase> db_;
  std::vector<ShadeReceiver> receivers_;
};

TEST_F(LobeCutGlossyTest, LobeCutComesCloseToBruteForceAtTheDefaultSolidAngle) {
  for (GlossyLobe lobe : {GlossyLobe::kPhong, GlossyLobe::kGgx}) {
    ShadeStats sb, sp, sl;
    const std::vector<ShadeResult> brute = Run(0.0f, false, lobe, &sb);
    const std::vector<ShadeResult> plain = Run(0.03f, false, lobe, &sp);
    const std::vector<ShadeResult> lobed = Run(0.03f, true, lobe, &sl);
    double mean = 0;
    for (const ShadeResult& r : brute) mean += (r.glossy.x + r.glossy.y + r.glossy.z) / 3.0;
    mean /= double(brute.size());
    const double e_plain = MeanAbsDiff(plain, brute), e_lobe = MeanAbsDiff(lobed, brute);
    const double n = double(receivers_.size());
    std::printf(
        "%s: mean %.4f, plain cut MAE %.5f (%.2f%%, %.0f clusters), lobe cut MAE %.5f "
        "(%.2f%%, %.0f clusters), brute force %.0f surfels\n",
        lobe == GlossyLobe::kPhong ? "Phong 32" : "GGX 0.3", mean, e_plain, 100 * e_plain / mean,
        sp.query.clusters / n, e_lobe, 100 * e_lobe / mean, sl.query.clusters / n,
        sb.query.surfels / n);
    EXPECT_EQ(sb.query.clusters, 0u);
    // Measured: Phong 32 1.28% -> 0.41%, GGX 0.3 0.74% -> 0.34% of the mean (res 12), for
    // about 2x the clusters.
    EXPECT_GT(e_plain, 0.005 * mean);  // the plain cut's error is real
    EXPECT_LT(e_lobe, (lobe == GlossyLobe::kPhong ? 0.45 : 0.7) * e_plain);
  }
}

// Without a lobe, lobe_cut changes nothing: occlusion and irradiance are bit-identical, and so
// is glossy with lobe_cut off to the plain cut's (the cut before the lobe-aware one).
TEST_F(LobeCutGlossyTest, OcclusionAndIrradianceDoNotChange) {
  ShadeStats a, b;
  const std::vector<ShadeResult> on = Run(0.03f, true, GlossyLobe::kNone, &a);
  const std::vector<ShadeResult> off = Run(0.03f, false, GlossyLobe::kNone, &b);
  for (size_t i = 0; i < on.size(); ++i) {
    EXPECT_EQ(on[i].occlusion, off[i].occlusion);
    EXPECT_EQ(on[i].irradiance, off[i].irradiance);
  }
  EXPECT_EQ(a.query.clusters, b.query.clusters);
  EXPECT_EQ(a.query.surfels, b.query.surfels);
  // Glossy without the lobe cut is the plain cut's glossy: the same gathers as no lobe at all.
  ShadeStats c;
  const std::vector<ShadeResult> glossy_plain = Run(0.03f, false, GlossyLobe::kPhong, &c);
  EXPECT_EQ(c.query.clusters, b.query.clusters);
  for (size_t i = 0; i < on.size(); ++i) {
    EXPECT_EQ(glossy_plain[i].occlusion, off[i].occlusion);
    EXPECT_EQ(glossy_plain[i].irradiance, off[i].irradiance);
  }
}

}  // namespace
}  // namespace pbgi
