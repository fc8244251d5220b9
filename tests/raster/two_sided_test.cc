// Two-sided surfels and the side rule on clusters (docs/design.md, "Two-sided surfels"): a
// closed object occludes the same with hitsides both as with front (its silhouette, once), and
// a two-sided card occludes and shines the same from either side, as a one-sided card seen
// from its front does. Each against an analytic answer, with surfels and with clusters, both
// footprints.
#include <cmath>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "pbgi/sh.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

using testing_raster::Aggregate;
using testing_raster::ClustersInCells;
using testing_raster::kPi;
using testing_raster::RectangleFormFactor;
using testing_raster::SphereSurfels;
using testing_raster::SquareSurfels;

ShadeResult MustShade(const Gathered& g, const glm::vec3& p, const RasterOptions& o) {
  MicroBuffer mb;
  ShadeReceiver r;
  r.position = p;
  r.normal = glm::vec3(0, 0, 1);
  ShadeResult out;
  const absl::Status s = Shade(g, r, o, &mb, &out);
  EXPECT_TRUE(s.ok()) << s;
  return out;
}

RasterOptions Options(Footprint footprint, HitSides sides, bool radiance = false) {
  RasterOptions o;
  o.footprint = footprint;
  o.hitsides = sides;
  o.compute_radiance = radiance;
  return o;
}

const char* Name(Footprint f) { return f == Footprint::kSplats ? "splats" : "polygons"; }
const char* Name(HitSides s) {
  return s == HitSides::kFront ? "front" : s == HitSides::kBack ? "back" : "both";
}

std::vector<Surfel> Flipped(std::vector<Surfel> surfels, bool two_sided) {
  for (Surfel& s : surfels) {
    s.normal = -s.normal;
    s.two_sided = two_sided;
  }
  return surfels;
}

// A closed sphere of outward surfels, fully above the horizon: the cosine-weighted occlusion
// is sin^2(alpha) cos(theta) (alpha its half angle, theta its centre's angle from the normal).
// As one cluster (N = 0, front and back areas equal) hitsides both used to count the
// silhouette twice; now both sides give the same, the analytic value.
TEST(TwoSidedTest, ClosedSphereOccludesTheSameWithBothSidesAsWithFront) {
  const glm::vec3 centre(1.0f, 1.0f, 2.0f);
  const float radius = 0.5f;
  const std::vector<Surfel> sphere = SphereSurfels(centre, radius, 4000, /*inward=*/false);
  const double d = glm::length(centre);
  const double want = (radius * radius) / (d * d) * (centre.z / d);
  Gathered one;
  one.clusters.push_back(Aggregate(sphere));
  one.clusters[0].cell.lo = centre - radius;
  one.clusters[0].cell.hi = centre + radius;
  Gathered cells;
  cells.clusters = ClustersInCells(sphere, 0.25f);
  for (Footprint fp : {Footprint::kSplats, Footprint::kPolygons}) {
    const double front = MustShade(one, glm::vec3(0.0f), Options(fp, HitSides::kFront)).occlusion;
    const double both = MustShade(one, glm::vec3(0.0f), Options(fp, HitSides::kBoth)).occlusion;
    // A box footprint of a sphere's projected area is not a disk: polygons are coarser here.
    const double tol = fp == Footprint::kSplats ? 0.03 : 0.08;
    EXPECT_NEAR(front, want, tol * want) << Name(fp);
    EXPECT_NEAR(both, front, 1e-3 * want) << Name(fp);
    const double cf = MustShade(cells, glm::vec3(0.0f), Options(fp, HitSides::kFront)).occlusion;
    const double cb = MustShade(cells, glm::vec3(0.0f), Options(fp, HitSides::kBoth)).occlusion;
    EXPECT_NEAR(cf, want, 0.1 * want) << Name(fp) << " cells";
    if (fp == Footprint::kPolygons) {
      // In cells, the far hemisphere's patches show their insides with hitsides both; behind
      // the near patches they add nothing (kSplatBack), where they filled what the near
      // patches' partial opacity left, about +50% (bug: back_faces_fill_front_gaps).
      EXPECT_NEAR(cb, want, 0.1 * want) << Name(fp) << " cells";
    } else {
      // Splats keep that residual (docs/eval.md, "Session 5"); still below the old front +
      // back rule's, which doubled it.
      EXPECT_GT(cb, cf) << Name(fp) << " cells";
      EXPECT_LT(cb, 1.6 * want) << Name(fp) << " cells";
    }
  }
}

// A square card 1 x 1 at height 1 over the receiver. A one-sided card facing the receiver
// occludes its form factor; turned away, nothing (hitsides front). A two-sided card occludes
// its form factor whichever way its normals point and whatever hitsides says, as surfels, as
// clusters (whose pairs cancel in N: flat about their second moment's axis) and as one cluster.
TEST(TwoSidedTest, TwoSidedCardOccludesTheSameFromBothSides) {
  const std::vector<Surfel> facing = SquareSurfels(0.5f, 1.0f, 0.02f);
  const double want = RectangleFormFactor(-0.5, 0.5, -0.5, 0.5, 1.0);
  auto gathered = [](const std::vector<Surfel>& s, int how) {
    Gathered g;
    if (how == 0) g.surfels = s;
    if (how == 1) g.clusters = ClustersInCells(s, 0.25f);
    if (how == 2) {
      g.clusters.push_back(Aggregate(s));
      g.clusters[0].cell.lo = glm::vec3(-0.5f, -0.5f, 0.5f);
      g.clusters[0].cell.hi = glm::vec3(0.5f, 0.5f, 1.5f);
    }
    return g;
  };
  for (int how = 0; how < 3; ++how) {
    for (Footprint fp : {Footprint::kSplats, Footprint::kPolygons}) {
      // One cluster as one cone splat is a coarse model of a card this near (a pre-existing
      // error of the splats, not of the sides).
      const double tol = how == 2 && fp == Footprint::kSplats ? 0.25 : 0.03;
      const double one_sided =
          MustShade(gathered(facing, how), glm::vec3(0.0f), Options(fp, HitSides::kFront))
              .occlusion;
      EXPECT_NEAR(one_sided, want, tol * want) << how << " " << Name(fp);
      EXPECT_LT(MustShade(gathered(Flipped(facing, false), how), glm::vec3(0.0f),
                          Options(fp, HitSides::kFront))
                    .occlusion,
                0.01 * want)
          << how << " " << Name(fp);
      for (bool flip : {false, true}) {
        std::vector<Surfel> card = flip ? Flipped(facing, true) : facing;
        for (Surfel& s : card) s.two_sided = true;
        for (HitSides sides : {HitSides::kFront, HitSides::kBack, HitSides::kBoth}) {
          const double got =
              MustShade(gathered(card, how), glm::vec3(0.0f), Options(fp, sides)).occlusion;
          EXPECT_NEAR(got, one_sided, 0.01 * want)
              << how << " " << Name(fp) << " " << Name(sides) << " flip " << flip;
        }
      }
    }
  }
}

// An emitting two-sided card seen from its back shows its radiance: the irradiance of a
// one-sided card of radiance L seen from its front, pi L times the form factor.
TEST(TwoSidedTest, TwoSidedCardShinesFromBothSides) {
  const glm::vec3 l(0.5f, 1.0f, 2.0f);
  const std::vector<Surfel> facing = SquareSurfels(0.5f, 1.0f, 0.02f, l);
  const double ff = RectangleFormFactor(-0.5, 0.5, -0.5, 0.5, 1.0);
  const std::vector<Surfel> away = Flipped(facing, true);
  for (Footprint fp : {Footprint::kSplats, Footprint::kPolygons}) {
    for (int how = 0; how < 2; ++how) {
      Gathered g;
      if (how == 0) g.surfels = away;
      if (how == 1) g.clusters = ClustersInCells(away, 0.25f);
      const ShadeResult r = MustShade(g, glm::vec3(0.0f), Options(fp, HitSides::kFront, true));
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(r.irradiance[c], kPi * ff * l[c], 0.03 * kPi * ff * l[c])
            << Name(fp) << " " << how << " channel " << c;
      }
    }
  }
}

// The second-moment flatness (sh::AxisDominates, sh::PrincipalAxis): a two-sided card is flat
// about its normal, a closed sphere is not; two one-sided facets are flat about their bisector
// exactly when the mean-normal test calls them flat (normals closer than 2 acos(0.8)), and
// about the axis across them when they face nearly opposite ways.
TEST(TwoSidedTest, SecondMomentFlatnessFindsTheCardsAxis) {
  constexpr float k = kClusterFlatness * kClusterFlatness;
  const glm::vec3 n = glm::normalize(glm::vec3(0.3f, -0.5f, 0.8f));
  std::vector<Surfel> card;
  for (int i = 0; i < 50; ++i) {
    Surfel s;
    s.position = glm::vec3(float(i), 0.0f, 0.0f);
    s.normal = i % 2 ? n : -n;
    s.radius = 0.1f + 0.01f * float(i % 7);
    s.two_sided = i % 3 != 0;
    card.push_back(s);
  }
  const Cluster c = Aggregate(card);
  EXPECT_TRUE(sh::AxisDominates(c.sh_area.data(), k));
  const glm::vec3 e = sh::PrincipalAxis(c.sh_area.data());
  EXPECT_NEAR(std::fabs(glm::dot(e, n)), 1.0, 1e-4);
  EXPECT_FALSE(sh::AxisDominates(
      Aggregate(SphereSurfels(glm::vec3(0.0f), 1.0f, 500, false)).sh_area.data(), k));
  const double limit = 2.0 * std::acos(double(kClusterFlatness));
  for (double angle : {0.2, 1.0, limit - 0.02, limit + 0.02, 1.57, 2.5}) {
    std::vector<Surfel> facets(2);
    facets[0].normal = glm::vec3(std::sin(angle / 2), 0.0f, std::cos(angle / 2));
    facets[1].normal = glm::vec3(-std::sin(angle / 2), 0.0f, std::cos(angle / 2));
    facets[0].radius = facets[1].radius = 1.0f;
    const Cluster f = Aggregate(facets);
    // Facets facing nearly opposite ways (a thin wedge) are flat about the axis across them.
    const bool near_z = angle<limit, near_x = angle> kPi - limit;
    EXPECT_EQ(sh::AxisDominates(f.sh_area.data(), k), near_z || near_x) << angle;
    if (near_z || near_x) {
      const glm::vec3 e = sh::PrincipalAxis(f.sh_area.data());
      EXPECT_NEAR(std::fabs(near_z ? e.z : e.x), 1.0, 1e-3) << angle;
    }
  }
}

}  // namespace
}  // namespace pbgi
