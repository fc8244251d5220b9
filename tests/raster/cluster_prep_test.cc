// Cluster preparation: the lane-parallel paths (four lanes on the baseline ISA, eight with AVX2
// where the CPU has it) against the one-at-a-time path, on clusters that cover every cull and every
// branch.
#include "raster/cluster_prep.h"

#include <cmath>
#include <random>
#include <vector>

#include "glm/geometric.hpp"
#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

using internal::ClusterFrame;
using internal::PreparedSplat;

// Random clusters around the origin: patches of surfels with spread normals (flat to
// isotropic), some behind the receiver's tangent plane, some far, some empty or without area.
std::vector<Cluster> RandomClusters(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g;
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Cluster> out;
  for (int i = 0; i < count; ++i) {
    const glm::vec3 centre = glm::vec3(g(rng), g(rng), g(rng)) * (0.5f + 3.0f * u(rng));
    const glm::vec3 n = glm::normalize(glm::vec3(g(rng), g(rng), g(rng)));
    const float spread = i % 3 == 0 ? 0.0f : 2.0f * u(rng);
    // Every fifth: normals along the world axes (AxisFacesRadiance's content).
    const bool axis = i % 5 == 2;
    std::vector<Surfel> s;
    for (int k = 0; k < 6; ++k) {
      Surfel x;
      x.position = centre + 0.2f * glm::vec3(g(rng), g(rng), g(rng));
      x.normal = glm::normalize(n + spread * glm::vec3(g(rng), g(rng), g(rng)));
      if (axis) {
        const glm::vec3 m = glm::abs(x.normal);
        const int k = m.x >= m.y && m.x >= m.z ? 0 : m.y >= m.z ? 1 : 2;
        glm::vec3 e(0.0f);
        e[k] = x.normal[k] > 0.0f ? 1.0f : -1.0f;
        x.normal = e;
      }
      x.radius = 0.02f + 0.05f * u(rng);
      x.radiance = glm::vec3(u(rng), u(rng), 3.0f * u(rng));
      s.push_back(x);
    }
    Cluster c = testing_raster::Aggregate(s);
    if (i % 17 == 5) c.bounds = Bounds{};  // empty
    if (i % 23 == 7) {                     // no area
      c.sh_area = Sh9{};
      c.area = 0.0f;
    }
    out.push_back(c);
  }
  return out;
}

// The two paths evaluate the same expressions in the same order (no FMA: ISO C++ does not
// contract), so they agree bit for bit; this also keeps a grazing cluster's cull (area
// rounding to 0 or not) the same on both.
void ExpectSameSplat(const PreparedSplat& a, const PreparedSplat& b, int index) {
  SCOPED_TRACE(index);
  for (int k = 0; k < 4; ++k) EXPECT_EQ(a.rgb1[k], b.rgb1[k]);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(a.dir[k], b.dir[k]);
    EXPECT_EQ(a.normal[k], b.normal[k]);
  }
  EXPECT_EQ(a.omega, b.omega);
  EXPECT_EQ(a.depth, b.depth);
  EXPECT_EQ(a.extent, b.extent);
  EXPECT_EQ(a.plane, b.plane);
  EXPECT_EQ(a.thick, b.thick);
  EXPECT_EQ(a.near, 0);
  EXPECT_EQ(a.flat, b.flat);
}

// Every side rule, with and without radiance, both instruction sets the machine has, several
// receivers (one with a max_distance that culls part of the set).
TEST(ClusterPrepTest, LanesMatchOneAtATime) {
  const std::vector<Cluster> clusters = RandomClusters(403, 3);
  std::vector<bool> isas = {false};
  if (internal::CpuHasAvx2()) isas.push_back(true);
  int drawn = 0, culled = 0;
  for (const glm::vec3& normal :
       {glm::vec3(0, 0, 1), glm::normalize(glm::vec3(0.3f, -0.8f, 0.2f)), glm::vec3(-1, 0, 0)}) {
    glm::vec3 t, b;
    testing_raster::Basis(normal, &t, &b);
    for (float max_distance : {std::numeric_limits<float>::infinity(), 2.5f}) {
      for (HitSides sides : {HitSides::kFront, HitSides::kBack, HitSides::kBoth}) {
        const ClusterFrame f(glm::vec3(0.1f, -0.2f, 0.05f), t, b, normal, max_distance, sides,
                             ClusterModel::kMoments);
        for (bool avx2 : isas) {
          for (bool rad : {false, true}) {
            // Counts that leave every tail: eight-lane blocks, a four-lane block, single ones.
            for (size_t count : {clusters.size(), clusters.size() - 1, clusters.size() - 5,
                                 size_t{7}, size_t{3}, size_t{0}}) {
              SCOPED_TRACE(testing::Message()
                           << "avx2 " << avx2 << " radiance " << rad << " count " << count);
              std::vector<PreparedSplat> one(count + 1), lanes(count + 1);
              int n1 = 0;
              for (size_t i = 0; i < count; ++i) {
                n1 += rad ? internal::PrepareClusterOne<true>(clusters[i], f, &one[n1])
                          : internal::PrepareClusterOne<false>(clusters[i], f, &one[n1]);
              }
              const int n = rad ? internal::PrepareClusters<true>(clusters.data(), count, f,
                                                                  lanes.data(), avx2)
                                : internal::PrepareClusters<false>(clusters.data(), count, f,
                                                                   lanes.data(), avx2);
              ASSERT_EQ(n, n1);
              for (int i = 0; i < n1; ++i) ExpectSameSplat(lanes[i], one[i], i);
              if (count == clusters.size()) {
                drawn += n1;
                culled += static_cast<int>(count) - n1;
              }
            }
          }
        }
      }
    }
  }
  // Both outcomes occur often.
  EXPECT_GT(drawn, 1000);
  EXPECT_GT(culled, 1000);
}

}  // namespace
}  // namespace pbgi
