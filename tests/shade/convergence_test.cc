// Convergence (issue 14): against the Embree reference on the scene's own triangles, the
// occlusion error falls when the cut gets finer and the surfels denser, on a procedural scene
// and on a mesh we did not design for the method. An error with a floor would be a bias of the
// method, not a coarse cut (docs/eval.md, "Convergence").
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "tests/common/scratch_dir.h"

namespace pbgi {
namespace {

struct Errors {
  double mae = 0, bias = 0;
};

// One scene: its tracer, receivers on its visible surfaces and their converged reference.
class SceneUnderTest {
 public:
  static std::unique_ptr<SceneUnderTest> Make(std::shared_ptr<const Scene> scene, int receivers,
                                              int rays) {
    auto s = std::unique_ptr<SceneUnderTest>(new SceneUnderTest);
    s->scene_ = std::move(scene);
    auto tracer = Tracer::Create(*s->scene_);
    EXPECT_TRUE(tracer.ok()) << tracer.status();
    if (!tracer.ok()) return nullptr;
    s->tracer_ = std::move(tracer).value();
    SamplerOptions rs;
    rs.count = receivers;
    rs.seed = 7919;
    rs.bake = false;
    rs.placement = SamplerOptions::Placement::kUniform;  // receivers anywhere on a triangle
    auto src = MakeSceneSurfelSource(s->scene_, rs);
    EXPECT_TRUE(src.ok()) << src.status();
    if (!src.ok()) return nullptr;
    std::vector<Surfel> buf(1024);
    for (;;) {
      auto got = (*src)->Next(absl::MakeSpan(buf));
      EXPECT_TRUE(got.ok()) << got.status();
      if (!got.ok() || *got == 0) break;
      for (size_t i = 0; i < *got; ++i) {
        const glm::vec3 p = buf[i].position + s->tracer_->epsilon() * buf[i].normal;
        s->receivers_.push_back({p, buf[i].normal});
        s->shade_receivers_.push_back({p, buf[i].normal, buf[i].normal});
      }
    }
    s->truth_ = s->tracer_->ReferenceOcclusion(s->receivers_, rays,
                                               std::numeric_limits<float>::infinity(), 2);
    return s;
  }

  // PBGI with the tools' defaults (polygon footprints, curved_scale 0.3, res 12) over a fresh
  // database of `points` surfels, at max_solid_angle `msa`; the mean over `layouts` databases
  // (sampler seeds 1, 2, ...).
  Errors Shade(int64_t points, float msa, int resolution = 12, HitSides sides = HitSides::kFront,
               int layouts = 1) {
    Errors mean;
    for (int l = 1; l <= layouts; ++l) {
      const Errors e = ShadeLayout(points, msa, resolution, sides, static_cast<uint64_t>(l));
      mean.mae += e.mae / layouts;
      mean.bias += e.bias / layouts;
    }
    return mean;
  }

  Errors ShadeLayout(int64_t points, float msa, int resolution, HitSides sides, uint64_t seed) {
    testing_common::ScratchDir dir("convergence");
    SamplerOptions so;
    so.count = points;
    so.seed = seed;
    so.bake = false;
    auto src = MakeSceneSurfelSource(scene_, so);
    EXPECT_TRUE(src.ok()) << src.status();
    BuildOptions bo;
    bo.channels = Channels::kOcclusion;
    bo.tmp_dir = dir.path().string();
    const std::string path = (dir.path() / "db").string();
    auto built = BuildDatabase(**src, path, bo);
    EXPECT_TRUE(built.ok()) << built.status();
    auto db = Database::Open(path);
    EXPECT_TRUE(db.ok()) << db.status();
    if (!db.ok()) return {1.0, 1.0};
    ShadeOptions o;
    o.cut.max_solid_angle = msa;
    o.cut.curved_scale = 0.3f;
    o.cut.curved_box_scale = 1.0f;
    o.raster.footprint = Footprint::kPolygons;
    o.raster.resolution = resolution;
    o.raster.compute_radiance = false;
    o.raster.hitsides = sides;
    std::vector<ShadeResult> out(shade_receivers_.size());
    const absl::Status st = ShadeBatch(**db, shade_receivers_, o, absl::MakeSpan(out));
    EXPECT_TRUE(st.ok()) << st;
    Errors e;
    for (size_t i = 0; i < out.size(); ++i) {
      const double d = double(out[i].occlusion) - double(truth_[i]);
      e.mae += std::fabs(d);
      e.bias += d;
    }
    e.mae /= double(out.size());
    e.bias /= double(out.size());
    std::printf("%s: %lld surfels (seed %llu), msa %g, res %d: MAE %.5f bias %+.5f\n",
                scene_->name.c_str(), static_cast<long long>(points),
                static_cast<unsigned long long>(seed), msa, resolution, e.mae, e.bias);
    return e;
  }

  size_t receivers() const { return receivers_.size(); }

 private:
  SceneUnderTest() = default;
  std::shared_ptr<const Scene> scene_;
  std::unique_ptr<Tracer> tracer_;
  std::vector<Receiver> receivers_;
  std::vector<ShadeReceiver> shade_receivers_;
  std::vector<float> truth_;
};

// The goal in small: at msa 0.005 with 4x the surfels the error is at most `ratio` of
// the default's (msa 0.03; the goal is half), and the finer settings never do worse than the
// coarser ones.
void ExpectConverges(SceneUnderTest& s, int64_t points, double ratio = 0.5, int layouts = 1) {
  const Errors coarse = s.Shade(points, 0.03f, 12, HitSides::kFront, layouts);
  const Errors finer_cut = s.Shade(points, 0.005f, 12, HitSides::kFront, layouts);
  const Errors finer = s.Shade(4 * points, 0.005f, 12, HitSides::kFront, layouts);
  EXPECT_LE(finer_cut.mae, coarse.mae * 1.05);
  EXPECT_LE(finer.mae, ratio * coarse.mae);
  EXPECT_LE(std::fabs(finer.bias), std::fabs(coarse.bias) + 0.001);
}

TEST(ConvergenceTest, CornellErrorFallsWithTheCutAndTheDensity) {
  auto scene = MakeScene("cornell");
  ASSERT_TRUE(scene.ok()) << scene.status();
  auto s =
      SceneUnderTest::Make(std::make_shared<const Scene>(std::move(scene).value()), 300, 16384);
  ASSERT_NE(s, nullptr);
  ASSERT_GT(s->receivers(), 250u);
  ExpectConverges(*s, 20000);
}

// The same on a mesh we did not design for (Wuson.ply, 3,732 triangles: ears folded in layers
// thinner than a spacing, a tail, creases). Here the finer error is not yet the goal's half of
// the coarse one (docs/eval.md, "Session 8"): the test holds it at 0.95, so that the error
// falling with the cut and the density is checked on a mesh. It was 0.765 (0.00481 against
// 0.00629) until a near sheet's pieces got opaque cores (docs/design.md, "A piece's core"),
// which took the coarse error down 12 % (0.00552) and the finer one up 4 % (0.00502: one
// receiver 1.7 spacings from an ear's edge, whose core grows past it, +0.17).
TEST(ConvergenceTest, MeshErrorFallsWithTheCutAndTheDensity) {
  ImportReport report;
  auto scene = ImportMesh("/usr/share/assimp/models/PLY/Wuson.ply", &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  auto s = SceneUnderTest::Make(std::make_shared<const Scene>(std::move(scene).value()), 300, 8192);
  ASSERT_NE(s, nullptr);
  ASSERT_GT(s->receivers(), 250u);
  ExpectConverges(*s, 50000, 0.95, 3);
}

// A closed mesh (Wuson.ply, wound outward by the import) shows no back faces to a receiver
// outside it, so the reference is the same for both sides and hitsides both must not add bias:
// it did (+0.13 here against +0.007 with front), from the receiver's own surface drawn from behind
// (bug: own_surface_seen_from_behind) and the far inside filling the near side's gaps (bug:
// back_faces_fill_front_gaps).
TEST(ConvergenceTest, ClosedMeshOccludesTheSameWithBothSides) {
  ImportReport report;
  auto scene = ImportMesh("/usr/share/assimp/models/PLY/Wuson.ply", &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  auto s = SceneUnderTest::Make(std::make_shared<const Scene>(std::move(scene).value()), 200, 4096);
  ASSERT_NE(s, nullptr);
  ASSERT_GT(s->receivers(), 150u);
  const Errors front = s->Shade(50000, 0.03f, 12, HitSides::kFront);
  const Errors both = s->Shade(50000, 0.03f, 12, HitSides::kBoth);
  EXPECT_LT(both.bias - front.bias, 0.006);
  EXPECT_LT(both.mae, 1.4 * front.mae);
}

}  // namespace
}  // namespace pbgi
