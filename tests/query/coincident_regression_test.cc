// Regression of issue 17: 200,000 coincident points made one leaf that every nearby receiver
// gathered whole (7.4 ms per receiver, linear in the count). Below the last octree cell the
// builder now splits such a pile by rank (tree/morton.h), so it has aggregates at every level:
// the cut takes it as a few clusters from afar, and what a receiver gathers is bounded by the
// cut, not by the pile. The cost is asserted as counts (nodes visited, elements gathered), and
// every cut is checked against brute force.
#include <cmath>
#include <random>
#include <vector>

#include "absl/strings/str_format.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"

namespace pbgi {
namespace {

TEST(CoincidentRegressionTest, APileOfCoincidentPointsIsGatheredAsFewClusters) {
  constexpr size_t kPile = 200000;
  constexpr float kRadius = 0.001f;
  const glm::vec3 at(0.5f, 0.5f, 0.5f);
  std::mt19937_64 rng(5);
  std::normal_distribution<float> g(0.0f, 1.0f);
  std::vector<Surfel> surfels;
  surfels.reserve(kPile + 4000);
  for (size_t i = 0; i < kPile; ++i) {
    glm::vec3 n;
    do {
      n = glm::vec3(g(rng), g(rng), g(rng));
    } while (glm::dot(n, n) < 1e-6f);
    surfels.push_back({at, glm::normalize(n), kRadius, glm::vec3(0.5f)});
  }
  // And a floor, so that the pile is not the whole database.
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int i = 0; i < 4000; ++i) {
    surfels.push_back({{u(rng), u(rng), 0.0f}, {0, 0, 1}, 0.01f, glm::vec3(0.5f)});
  }
  BuildOptions bo;
  bo.channels = Channels::kOcclusion;
  auto db = testing::TempDatabase::Create(surfels, bo);
  ASSERT_TRUE(db.ok()) << db.status();
  EXPECT_LE((*db)->build_stats().max_leaf_points, bo.leaf_size);
  auto reader = (*db)->db().NewReader();
  ASSERT_TRUE(reader.ok());

  struct Case {
    float distance;       // from the pile, in scene units
    uint64_t max_cost;    // nodes visited + clusters + surfels gathered
  } cases[] = {{2.0f, 150}, {1.0f, 250}, {0.3f, 2000}};  // measured: 48-76, 125-139, 1124-1213
  for (const Case& c : cases) {
    for (const glm::vec3 dir : {glm::vec3(1, 0, 0), glm::vec3(0, 1, 0), glm::vec3(0.6f, 0, 0.8f)}) {
      SCOPED_TRACE(absl::StrFormat("distance %g, direction (%g, %g, %g)", c.distance, dir.x,
                                   dir.y, dir.z));
      const Receiver r{at + c.distance * dir, -dir};  // facing the pile
      Gathered g;
      QueryStats stats;
      ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g, &stats).ok());
      absl::Status valid = testing::CheckValidCut(g, (*db)->surfels(), r, Cut{});
      ASSERT_TRUE(valid.ok()) << valid;
      const uint64_t cost = stats.nodes_visited + g.clusters.size() + g.surfels.size();
      EXPECT_LE(cost, c.max_cost) << stats.nodes_visited << " nodes, " << g.clusters.size()
                                  << " clusters, " << g.surfels.size() << " surfels";
      // The pile is represented, not dropped: everything in front is covered (the check
      // above), and by far fewer elements than its points.
      EXPECT_LT(g.surfels.size(), kPile / 100);
    }
  }
}

}  // namespace
}  // namespace pbgi
