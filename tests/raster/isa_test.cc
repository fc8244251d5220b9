// The rasterizer's AVX2 builds (cluster preparation, splatting, polygon footprints,
// integration) against the baseline ones: the same code in two encodings, so Shade() must agree
// bit for bit.
#include <cmath>
#include <random>
#include <vector>

#include "glm/geometric.hpp"
#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "raster/cluster_prep.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

// A closed sphere of clusters and surfels around receivers inside it, plus a disk of surfels
// close enough to a receiver to take the exact near-field path.
Gathered MixedScene() {
  Gathered g;
  const std::vector<Surfel> sphere = testing_raster::SphereSurfels(
      glm::vec3(0.0f), 1.0f, 6000, /*inward=*/true, glm::vec3(0.8f, 0.5f, 0.2f));
  std::vector<Surfel> rest;
  for (size_t i = 0; i < sphere.size(); ++i) {
    if (i % 5 == 0) {
      rest.push_back(sphere[i]);
    } else if (i % 5 == 1) {
      g.surfels.push_back(sphere[i]);
    }
  }
  g.clusters = testing_raster::Clusters(rest, 0.2f);
  const std::vector<Surfel> disk =
      testing_raster::DiskSurfels(glm::vec3(0.0f, 0.0f, 0.06f), glm::vec3(0, 0, -1), 0.2f, 0.05f);
  g.surfels.insert(g.surfels.end(), disk.begin(), disk.end());
  return g;
}

void ExpectSame(const ShadeResult& a, const ShadeResult& b) {
  EXPECT_EQ(a.occlusion, b.occlusion);
  EXPECT_EQ(a.coverage, b.coverage);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(a.irradiance[k], b.irradiance[k]);
    EXPECT_EQ(a.glossy[k], b.glossy[k]);
  }
  EXPECT_EQ(a.clusters_drawn, b.clusters_drawn);
  EXPECT_EQ(a.surfels_drawn, b.surfels_drawn);
  EXPECT_EQ(a.near_disks_drawn, b.near_disks_drawn);
  EXPECT_EQ(a.culled, b.culled);
}

TEST(RasterIsaTest, Avx2AndBaselineAgreeBitForBit) {
  if (!internal::CpuHasAvx2()) GTEST_SKIP() << "no AVX2 on this CPU: only the baseline runs";
  const Gathered g = MixedScene();
  ASSERT_GT(g.clusters.size(), 40u);
  MicroBuffer mb;
  int shaded = 0, near = 0;
  for (Footprint footprint : {Footprint::kSplats, Footprint::kPolygons}) {
    for (bool clamp : {true, false}) {
      for (bool radiance : {true, false}) {
        for (int res : {8, 12}) {
          RasterOptions o;
          o.footprint = footprint;
          o.resolution = res;
          o.clamp = clamp;
          o.compute_radiance = radiance;
          o.lobe = radiance ? GlossyLobe::kPhong : GlossyLobe::kNone;
          for (const glm::vec3& p : {glm::vec3(0.0f), glm::vec3(0.3f, -0.2f, 0.1f)}) {
            ShadeReceiver r;
            r.position = p;
            r.normal = glm::normalize(glm::vec3(0.1f, 0.2f, 1.0f));
            r.reflection = glm::normalize(glm::vec3(1, 0, 1));
            ShadeResult fast, base;
            internal::ForceBaselineIsaForTesting(false);
            ASSERT_TRUE(Shade(g, r, o, &mb, &fast).ok());
            internal::ForceBaselineIsaForTesting(true);
            ASSERT_TRUE(Shade(g, r, o, &mb, &base).ok());
            internal::ForceBaselineIsaForTesting(false);
            ExpectSame(fast, base);
            EXPECT_GT(base.occlusion, 0.1f);
            near += static_cast<int>(base.near_disks_drawn);
            ++shaded;
          }
        }
      }
    }
  }
  EXPECT_EQ(shaded, 32);
  EXPECT_GT(near, 0);  // the exact-disk path ran too
}

}  // namespace
}  // namespace pbgi
