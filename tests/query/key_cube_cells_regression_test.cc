// Regression of the cells a gather hands the rasterizer when the source declared bounds larger
// than the points' extent (a sampled scene's mesh bounds, SurfelSource::KnownBounds): the
// reader derived every Cluster::cell and leaf cell from the cube around the points' own bounds,
// while the builder cut the Morton keys (and so the octree) from the cube around the declared
// ones. The "cells" were then neither the nodes' octree cells nor sure to hold their content,
// and the rasterizer's snapping to cell sides (raster/footprints.cc FootprintBox) silently did
// not happen for most clusters of `pbgi eval` and `pbgi demo` scenes (bug:
// cells_off_the_key_cube). The builder now records the key box (build statistic key_bounds)
// and the reader uses it: the cells are the octree's (one grid per depth, rooted at the
// declared bounds' cube) and hold what they are the cells of.
#include <algorithm>
#include <cmath>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"
#include "tests/common/scratch_dir.h"

namespace pbgi {
namespace {

// Whether `b` lies inside `cell` within `tol`.
bool Holds(const Bounds& cell, const Bounds& b, float tol) {
  for (int a = 0; a < 3; ++a) {
    if (b.lo[a] < cell.lo[a] - tol || b.hi[a] > cell.hi[a] + tol) return false;
  }
  return true;
}

// The depth at which a cube of side `root` halves to `side`, or -1 when `side` is not such a
// power-of-two fraction of it (relative tolerance 1e-4).
int DepthOf(float side, double root) {
  const double d = std::log2(root / double(side));
  const double r = std::round(d);
  if (r < 0 || std::abs(root / std::exp2(r) - double(side)) > 1e-4 * double(side)) return -1;
  return static_cast<int>(r);
}

// The points of a vector, with bounds declared as a scene's sampler declares its mesh's.
class DeclaredBoundsSource final : public SurfelSource {
 public:
  DeclaredBoundsSource(absl::Span<const Surfel> surfels, const Bounds& declared)
      : inner_(surfels), declared_(declared) {}
  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override { return inner_.Next(out); }
  absl::Status Rewind() override { return inner_.Rewind(); }
  Bounds KnownBounds() const override { return declared_; }

 private:
  VectorSurfelSource inner_;
  Bounds declared_;
};

// Builds `cloud` with bounds `declared` and checks every gathered cell against the octree over
// the declared box's cube (side `root` from `origin`, padded as tree/morton.h pads it): on its
// grid, at the node's depth, holding the node's content.
void ExpectCellsOnTheKeyGrid(const std::vector<Surfel>& cloud, const Bounds& declared, double root,
                             const glm::dvec3& origin) {
  testing_common::ScratchDir dir("key_cube");
  BuildOptions bo;
  bo.leaf_size = 8;
  bo.tmp_dir = dir.path().string();
  DeclaredBoundsSource source(cloud, declared);
  const std::string path = (dir.path() / "db").string();
  auto built = BuildDatabase(source, path, bo);
  ASSERT_TRUE(built.ok()) << built.status();
  auto db = Database::Open(path);
  ASSERT_TRUE(db.ok()) << db.status();
  auto reader = (*db)->NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();

  constexpr double kRel = 1e-5;  // the key cube's padding, relative (tree/morton.h)
  const float tol = 1e-5f;
  std::vector<Receiver> receivers = testing::RandomReceivers(40, 7);
  for (size_t i = 0; i < 40; ++i) {
    const Surfel& s = cloud[(i * 4099) % cloud.size()];
    receivers.push_back({s.position + 1e-3f * s.normal, s.normal});
  }
  uint64_t clusters = 0, leaves = 0;
  // Whether `cell` is a cell of the octree over the declared cube, at `depth` when given.
  auto on_grid = [&](const Bounds& cell, int depth) {
    const int d = DepthOf(cell.hi.x - cell.lo.x, root);
    if (d < 0 || (depth >= 0 && d != std::min(depth, 21))) return false;
    const double side = root / std::exp2(d);
    for (int a = 0; a < 3; ++a) {
      if (std::abs(double(cell.hi[a] - cell.lo[a]) - side) > 1e-4 * side) return false;
      const double k = (double(cell.lo[a]) - origin[a]) / side;
      // The padding moves the origin by at most kRel * root: a fraction of a cell at depth d.
      if (std::abs(k - std::round(k)) > 1e-3 + kRel * root / side) return false;
    }
    return true;
  };
  for (const Receiver& r : receivers) {
    Gathered g;
    ASSERT_TRUE((*reader)->Gather(r, Cut{}, &g).ok());
    for (const Cluster& c : g.clusters) {
      ++clusters;
      ASSERT_FALSE(c.cell.Empty());
      EXPECT_TRUE(on_grid(c.cell, static_cast<int>(c.depth)))
          << "cluster at depth " << c.depth << ": cell (" << c.cell.lo.x << ", " << c.cell.lo.y
          << ", " << c.cell.lo.z << ") side " << c.cell.hi.x - c.cell.lo.x;
      EXPECT_TRUE(Holds(c.cell, c.bounds, tol)) << "cluster at depth " << c.depth;
    }
    ASSERT_EQ(g.surfel_leaf.size(), g.surfels.size());
    for (const Bounds& cell : g.leaf_cells) {
      ++leaves;
      EXPECT_TRUE(on_grid(cell, -1)) << "leaf cell side " << cell.hi.x - cell.lo.x;
    }
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      ASSERT_LT(g.surfel_leaf[i], g.leaf_cells.size());
      Bounds p;
      p.Extend(g.surfels[i].position);
      EXPECT_TRUE(Holds(g.leaf_cells[g.surfel_leaf[i]], p, tol)) << "surfel " << g.surfel_ids[i];
    }
  }
  EXPECT_GT(clusters, 100u);
  EXPECT_GT(leaves, 10u);
}

TEST(KeyCubeCellsRegressionTest, CellsAreTheOctreeCellsOfTheDeclaredBoundsCube) {
  // Points in the unit cube, bounds declared as [-1, 2]^3: the key cube has side 3 (and a
  // little padding), the points' own cube side 1 at most.
  const std::vector<Surfel> cloud = testing::RandomSceneSurfels(20000, 41);
  Bounds declared;
  declared.lo = glm::vec3(-1.0f);
  declared.hi = glm::vec3(2.0f);
  ExpectCellsOnTheKeyGrid(cloud, declared, 3.0, glm::dvec3(-1.0));
}

// A sampled scene's points stick out of its declared bounds by rounding (a point on a triangle's
// edge): the builder keeps such points (within KeyBoundsTolerance) and keys them in the declared
// box's cube, but the reader refused the key box because the points' box was not inside it, and
// fell back to the points' own cube (bug: key_box_refused_for_rounding: the forest's cells lay
// half a cell off the octree's, the ground under every tree came out 0.7 opaque, and a trunk's
// clusters lost their footprints' snap to their cells).
TEST(KeyCubeCellsRegressionTest, PointsOutsideTheDeclaredBoxByRoundingKeepTheKeyGrid) {
  std::vector<Surfel> cloud = testing::RandomSceneSurfels(20000, 43);
  // Declared: y from -0.5 (below every point: the key cube differs from the points' own), and
  // x up to just below the largest x, as rounding leaves it (1e-6 of the box, within the
  // builder's 1e-5).
  Bounds points;
  for (const Surfel& s : cloud) points.Extend(s.position);
  Bounds declared = points;
  declared.lo.y = -0.5f;
  declared.hi.x = points.hi.x - 1e-6f * (points.hi.x - points.lo.x);
  ASSERT_LT(declared.hi.x, points.hi.x);
  const glm::dvec3 lo(declared.lo), hi(declared.hi);
  const double side = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  ExpectCellsOnTheKeyGrid(cloud, declared, side, 0.5 * (lo + hi) - glm::dvec3(0.5 * side));
}

}  // namespace
}  // namespace pbgi
