// PBGI's glossy radiance (ShadeResult::glossy) against the Embree reference of the same lobe
// (Tracer::ReferenceGlossy) on a small Cornell box, as `pbgi eval --mode glossy` compares them:
// receivers are a camera view's primary hits, each lobe centred on the mirrored view direction.
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/shade.h"
#include "tests/common/scratch_dir.h"
#include "tools/scene_views.h"

namespace pbgi::tools {
namespace {

struct Compared {
  double mae = 0, bias = 0, mean = 0;  // of the mean channel, over receivers
};

class GlossyEvalTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto scene = LoadScene("cornell", 1, 0);
    ASSERT_TRUE(scene.ok()) << scene.status();
    scene_ = *scene;
    SamplerOptions sampler;
    sampler.count = 60000;
    auto src = MakeSceneSurfelSource(scene_, sampler);
    ASSERT_TRUE(src.ok()) << src.status();
    BuildOptions bo;
    bo.memory_bytes = 64 << 20;
    bo.channels = Channels::kRadiance;
    db_path_ = dir_.Sub("cornell.pbgi");
    auto st = BuildDatabase(**src, db_path_, bo);
    ASSERT_TRUE(st.ok()) << st.status();
    auto tracer = Tracer::Create(*scene_);
    ASSERT_TRUE(tracer.ok()) << tracer.status();
    tracer_ = std::move(*tracer);
    const CameraReceivers cr = MakeCameraReceivers(*tracer_, DefaultCamera(*scene_, 32, 24));
    for (size_t i = 0; i < cr.shade.size(); i += 3) receivers_.push_back(cr.shade[i]);
    ASSERT_GT(receivers_.size(), 150u);
  }

  Compared Compare(const GlossyParams& lobe, float msa, int res) {
    auto db = Database::Open(db_path_);
    EXPECT_TRUE(db.ok()) << db.status();
    ShadeOptions so;
    so.threads = 2;
    so.cut.max_solid_angle = msa;
    so.cut.cosine_weighted = false;
    so.raster.resolution = res;
    so.raster.lobe = lobe.lobe;
    so.raster.phong_exponent = lobe.phong_exponent;
    so.raster.ggx_roughness = lobe.ggx_roughness;
    std::vector<ShadeResult> got(receivers_.size());
    const absl::Status s = ShadeBatch(**db, receivers_, so, absl::MakeSpan(got));
    EXPECT_TRUE(s.ok()) << s;
    const std::vector<glm::vec3> want = tracer_->ReferenceGlossy(receivers_, lobe, 4096, 3);
    Compared c;
    for (size_t i = 0; i < got.size(); ++i) {
      const double g = (got[i].glossy.x + got[i].glossy.y + got[i].glossy.z) / 3.0;
      const double w = (want[i].x + want[i].y + want[i].z) / 3.0;
      c.mae += std::abs(g - w);
      c.bias += g - w;
      c.mean += w;
    }
    const double n = double(got.size());
    c.mae /= n, c.bias /= n, c.mean /= n;
    return c;
  }

  testing_common::ScratchDir dir_;
  std::shared_ptr<const Scene> scene_;
  std::string db_path_;
  std::unique_ptr<Tracer> tracer_;
  std::vector<ShadeReceiver> receivers_;
};

TEST_F(GlossyEvalTest, PhongAndGgxMatchTheReference) {
  for (const GlossyParams& lobe :
       {GlossyParams{GlossyLobe::kPhong, 32.0f, 0.2f}, GlossyParams{GlossyLobe::kGgx, 32.0f, 0.3f},
        GlossyParams{GlossyLobe::kPhong, 8.0f, 0.2f}}) {
    const Compared c = Compare(lobe, 0.01f, 16);
    ASSERT_GT(c.mean, 0.0);
    SCOPED_TRACE(testing::Message() << "lobe " << int(lobe.lobe) << " e " << lobe.phong_exponent
                                    << " alpha " << lobe.ggx_roughness << ": MAE " << c.mae
                                    << " bias " << c.bias << " mean " << c.mean);
    std::printf("glossy lobe %d e %g alpha %g: MAE %.5f bias %.5f mean %.5f (%.2f%%)\n",
                int(lobe.lobe), lobe.phong_exponent, lobe.ggx_roughness, c.mae, c.bias, c.mean,
                100.0 * c.mae / c.mean);
    EXPECT_LT(c.mae, 0.08 * c.mean);
    EXPECT_LT(std::abs(c.bias), 0.03 * c.mean);
  }
}

}  // namespace
}  // namespace pbgi::tools
