// The radius and normal estimates of point clouds that lack them (build/neighbour_estimate.h),
// against analytic answers: uniform random points on a sphere (area 4 pi R^2, outward normals)
// and on a plane (normals towards a viewpoint on either side), streamed in Morton order through
// several blocks of the estimator's window.
#include "build/neighbour_estimate.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "glm/gtc/type_ptr.hpp"
#include "gtest/gtest.h"
#include "tests/build/test_clouds.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

std::vector<SortRecord> MortonSorted(const std::vector<glm::vec3>& points, Bounds* bounds) {
  for (const glm::vec3& p : points) bounds->Extend(p);
  const MortonQuantizer q(*bounds);
  std::vector<SortRecord> recs;
  for (const glm::vec3& p : points) {
    Surfel s;
    s.position = p;
    s.normal = glm::vec3(0.0f);
    s.radius = 0.0f;
    recs.push_back(MakeSortRecord(q.Key(p), s));
  }
  std::sort(recs.begin(), recs.end(),
            [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
  return recs;
}

std::vector<SortRecord> Estimate(const std::vector<SortRecord>& in, const Bounds& bounds,
                                 const BuildOptions::Estimate& e) {
  NeighbourEstimator est(e, bounds);
  std::vector<SortRecord> out;
  auto sink = [&](const SortRecord& r) {
    out.push_back(r);
    return absl::OkStatus();
  };
  for (const SortRecord& r : in) EXPECT_TRUE(est.Add(r, sink).ok());
  EXPECT_TRUE(est.Finish(sink).ok());
  return out;
}

TEST(NeighbourEstimateTest, SphereRadiiSumToItsAreaAndNormalsPointOutward) {
  // 100k points: three blocks and a partial one, so every block boundary case runs.
  const size_t n = 100000;
  const float radius = 2.0f;
  const glm::vec3 centre(5, -3, 1);
  std::mt19937_64 rng(7);
  std::vector<glm::vec3> pts;
  for (size_t i = 0; i < n; ++i) pts.push_back(centre + radius * testing_build::RandomUnit(rng));
  Bounds b;
  const auto sorted = MortonSorted(pts, &b);
  BuildOptions::Estimate e;
  e.radius = e.normals = true;
  const auto out = Estimate(sorted, b, e);
  ASSERT_EQ(out.size(), n);
  double area = 0;
  size_t outliers = 0, misoriented = 0, off_axis = 0;
  const double expected_r2 = 4.0 * radius * radius / double(n);  // pi r^2 = 4 pi R^2 / n
  for (size_t i = 0; i < n; ++i) {
    ASSERT_EQ(out[i].key, sorted[i].key) << "order changed at " << i;
    const double r2 = double(out[i].radius) * out[i].radius;
    area += 3.14159265358979 * r2;
    if (r2 > 2.0 * expected_r2) ++outliers;
    const glm::vec3 radial = glm::normalize(glm::make_vec3(out[i].position) - centre);
    const float c = glm::dot(glm::make_vec3(out[i].normal), radial);
    if (c < 0) ++misoriented;
    if (std::abs(c) < std::cos(5.0 * 3.14159265 / 180)) ++off_axis;
  }
  const double true_area = 4.0 * 3.14159265358979 * radius * radius;
  EXPECT_NEAR(area / true_area, 1.0, 0.05) << "total surfel area " << area;
  std::printf("sphere: area ratio %.4f, outliers (r^2 > 2x) %.3f%%, normals > 5 deg off %.3f%%\n",
              area / true_area, 100.0 * double(outliers) / double(n),
              100.0 * double(off_axis) / double(n));
  // Points whose neighbours lie across an octant boundary outside the window: a few percent.
  EXPECT_LT(double(outliers) / double(n), 0.03) << outliers;
  EXPECT_EQ(misoriented, 0u);
  EXPECT_LT(double(off_axis) / double(n), 0.01) << off_axis << " normals more than 5 deg off";
}

TEST(NeighbourEstimateTest, PlaneNormalsFaceTheViewpointAndRadiiMatchTheDensity) {
  const size_t n = 50000;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(-10.0f, 10.0f);
  std::vector<glm::vec3> pts;
  for (size_t i = 0; i < n; ++i) pts.push_back(glm::vec3(u(rng), u(rng), 0.5f));
  Bounds b;
  const auto sorted = MortonSorted(pts, &b);
  for (float side : {1.0f, -1.0f}) {
    BuildOptions::Estimate e;
    e.radius = e.normals = true;
    e.towards_viewpoint = true;
    e.viewpoint = glm::vec3(0, 0, 0.5f + 30.0f * side);
    const auto out = Estimate(sorted, b, e);
    std::vector<double> r2;
    for (const SortRecord& r : out) {
      ASSERT_NEAR(r.normal[2], side, 1e-4) << r.position[0] << "," << r.position[1];
      // Away from the square's edges (whose points miss half their neighbours).
      if (std::abs(r.position[0]) < 9 && std::abs(r.position[1]) < 9) {
        r2.push_back(double(r.radius) * r.radius);
      }
    }
    double mean = 0;
    for (double v : r2) mean += v;
    mean /= double(r2.size());
    EXPECT_NEAR(3.14159265358979 * mean / (400.0 / double(n)), 1.0, 0.05);
  }
}

TEST(NeighbourEstimateTest, CoincidentPointsGetAPositiveRadius) {
  std::vector<glm::vec3> pts(100, glm::vec3(1, 2, 3));
  pts.push_back(glm::vec3(2, 2, 3));
  Bounds b;
  const auto sorted = MortonSorted(pts, &b);
  BuildOptions::Estimate e;
  e.radius = true;
  for (const SortRecord& r : Estimate(sorted, b, e)) {
    EXPECT_GT(r.radius, 0.0f);
    EXPECT_TRUE(std::isfinite(r.radius));
  }
}

}  // namespace
}  // namespace pbgi::internal
