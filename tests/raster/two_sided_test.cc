// Two-sided surfels and the side rule on clusters (docs/design.md, "Two-sided surfels"): a
// closed object occludes the same with hitsides both as with front (its silhouette, once), and
// a two-sided card occludes and shines the same from either side, as a one-sided card seen
// from its front does. Each against an analytic answer, with surfels and with clusters, both
// footprints.
#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>
#include <utility>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "pbgi/sh.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

using testing_raster::Aggregate;
using testing_raster::ClustersInCells;
using testing_raster::CosineRayFraction;
using testing_raster::kPi;
using testing_raster::RectangleFormFactor;
using testing_raster::Rotation;
using testing_raster::SphereSurfels;
using testing_raster::SquareSurfels;
using testing_raster::Transform;

ShadeResult MustShade(const Gathered& g, const glm::vec3& p, const RasterOptions& o,
                      uint8_t sheet = 0) {
  MicroBuffer mb;
  ShadeReceiver r;
  r.position = p;
  r.normal = glm::vec3(0, 0, 1);
  r.sheet = sheet;
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

// A two-sided card shows its front radiance from the front and its back radiance from behind
// (Surfel::back_radiance): the irradiance of a one-sided card of that radiance seen from its
// front, pi L times the form factor. As surfels (one disk each, or the leaf's co-planar
// groups) and as clusters (the power SH's band 1 holds front minus back).
TEST(TwoSidedTest, TwoSidedCardShowsEachSidesRadiance) {
  const glm::vec3 front(0.5f, 1.0f, 2.0f), back(1.5f, 0.25f, 0.0f);
  const std::vector<Surfel> facing = SquareSurfels(0.5f, 1.0f, 0.02f, front);
  const double ff = RectangleFormFactor(-0.5, 0.5, -0.5, 0.5, 1.0);
  for (bool from_behind : {false, true}) {
    // The side the receiver sees carries `front` and the other `back`. Seen from behind, the
    // card's normal points away from the receiver, so its back radiance is `front`.
    std::vector<Surfel> card = from_behind ? Flipped(facing, true) : facing;
    for (Surfel& s : card) {
      s.two_sided = true;
      s.radiance = from_behind ? back : front;
      s.back_radiance = from_behind ? front : back;
    }
    const glm::vec3 want = front;
    for (Footprint fp : {Footprint::kSplats, Footprint::kPolygons}) {
      for (int how = 0; how < 2; ++how) {
        Gathered g;
        if (how == 0) g.surfels = card;
        if (how == 1) g.clusters = ClustersInCells(card, 0.25f);
        const ShadeResult r = MustShade(g, glm::vec3(0.0f), Options(fp, HitSides::kFront, true));
        for (int c = 0; c < 3; ++c) {
          EXPECT_NEAR(r.irradiance[c], kPi * ff * want[c], 0.03 * kPi * ff * front[c])
              << Name(fp) << " " << how << " behind " << from_behind << " channel " << c;
        }
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

// `surfels` in leaf cells of edge `cell` (Gathered::surfel_leaf, leaf_cells), as Gather hands a
// leaf's surfels to the rasterizer, which groups co-planar ones into polygons: each leaf's
// surfels together, in their leaves' order of first appearance.
Gathered InLeafCells(const std::vector<Surfel>& in, float cell) {
  Gathered g;
  std::map<std::tuple<int, int, int>, uint32_t> index;
  std::vector<std::vector<Surfel>> leaves;
  for (const Surfel& s : in) {
    const glm::vec3 q = glm::floor(s.position / cell);
    const auto key =
        std::make_tuple(static_cast<int>(q.x), static_cast<int>(q.y), static_cast<int>(q.z));
    auto [it, fresh] = index.emplace(key, static_cast<uint32_t>(leaves.size()));
    if (fresh) leaves.emplace_back();
    leaves[it->second].push_back(s);
  }
  index.clear();
  std::vector<Surfel> surfels;
  for (const std::vector<Surfel>& leaf : leaves)
    surfels.insert(surfels.end(), leaf.begin(), leaf.end());
  for (const Surfel& s : surfels) {
    const glm::vec3 q = glm::floor(s.position / cell);
    const auto key =
        std::make_tuple(static_cast<int>(q.x), static_cast<int>(q.y), static_cast<int>(q.z));
    auto [it, fresh] = index.emplace(key, static_cast<uint32_t>(g.leaf_cells.size()));
    if (fresh) {
      Bounds b;
      b.lo = q * cell;
      b.hi = b.lo + cell;
      g.leaf_cells.push_back(b);
    }
    g.surfel_leaf.push_back(it->second);
    g.surfel_ids.push_back(g.surfel_ids.size());
    g.surfels.push_back(s);
  }
  return g;
}

// A receiver on top of a convex sphere sees nothing of it, whichever sides count: with
// hitsides both, the nearest surfel's disk, whose plane passes just above the receiver, was
// drawn from behind and covered the whole hemisphere (bug: own_surface_seen_from_behind;
// tests/shade/convergence_test.cc has the co-planar groups' share of it on a mesh). Inside a
// half-pipe, where the receiver lies behind its neighbourhood's planes, both sides give what
// rays cast at the cylinder give; and a one-sided card turned away from the receiver still
// occludes with hitsides both: only the receiver's own surface is dropped.
TEST(TwoSidedTest, OwnSurfaceSeenFromBehind) {
  const std::vector<Surfel> sphere =
      SphereSurfels(glm::vec3(0.0f, 0.0f, -1.0f), 1.0f, 40000, /*inward=*/false);
  const Gathered g = InLeafCells(sphere, 0.1f);
  for (HitSides sides : {HitSides::kFront, HitSides::kBoth}) {
    const double got =
        MustShade(g, glm::vec3(0.0f), Options(Footprint::kPolygons, sides)).occlusion;
    EXPECT_LT(got, 0.005) << Name(sides);
  }
  // The half-pipe: axis x at height 1, radius 1, 8 long, inward normals; the receiver at its
  // bottom.
  std::vector<Surfel> pipe;
  const float pitch = 0.02f;
  for (float x = -4.0f + 0.5f * pitch; x < 4.0f; x += pitch) {
    for (float a = -0.5f * static_cast<float>(kPi) + 0.5f * pitch;
         a < 0.5f * static_cast<float>(kPi); a += pitch) {
      Surfel sf;
      sf.position = glm::vec3(x, std::sin(a), 1.0f - std::cos(a));
      sf.normal = glm::vec3(0.0f, -std::sin(a), std::cos(a));
      sf.radius = pitch / std::sqrt(static_cast<float>(kPi));
      pipe.push_back(sf);
    }
  }
  const double pipe_want = CosineRayFraction(300, [](const glm::dvec3& w) {
    const double t = 2.0 * w.z / (w.y * w.y + w.z * w.z);  // |(t w.y, t w.z - 1)| = 1
    return t * w.z <= 1.0 && std::fabs(t * w.x) <= 4.0;
  });
  const Gathered pg = InLeafCells(pipe, 0.25f);
  const double pipe_front =
      MustShade(pg, glm::vec3(0.0f), Options(Footprint::kPolygons, HitSides::kFront)).occlusion;
  EXPECT_NEAR(pipe_front, pipe_want, 0.03);
  EXPECT_NEAR(
      MustShade(pg, glm::vec3(0.0f), Options(Footprint::kPolygons, HitSides::kBoth)).occlusion,
      pipe_front, 0.01);
  const std::vector<Surfel> away = Flipped(SquareSurfels(0.5f, 1.0f, 0.02f), false);
  const double want = RectangleFormFactor(-0.5, 0.5, -0.5, 0.5, 1.0);
  EXPECT_NEAR(MustShade(InLeafCells(away, 0.25f), glm::vec3(0.0f),
                        Options(Footprint::kPolygons, HitSides::kBoth))
                  .occlusion,
              want, 0.03 * want);
}

// A thin sheet bent convexly through the receiver (an open pipe, a sheet folded over an edge:
// Material::thin, so two-sided surfels) hides nothing from a receiver on it: every other part
// of it lies behind the receiver's tangent plane. A neighbour's disk, tilted by the bend,
// passes just above the receiver, and drawn from its back (two-sided surfels show both sides
// whatever hitsides says) it covered most of the hemisphere: 2CylinderEngine.glb had twenty
// of 300 receivers at +0.1 to +0.99 (bug: convex_thin_sheet_covers_its_receiver). A separate
// two-sided card closer above the receiver than a spacing still occludes its form factor.
TEST(TwoSidedTest, ConvexThinSheetDoesNotCoverItsReceiver) {
  // A coarsely sampled two-sided sphere of radius 1 below the receiver (a spacing of 0.2,
  // about as coarse against its curvature as the engine's pipes), turned eight ways so that
  // the receiver sits at different places among its surfels.
  const std::vector<Surfel> shell =
      Flipped(SphereSurfels(glm::vec3(0.0f), 1.0f, 300, /*inward=*/true), /*two_sided=*/true);
  double worst = 0.0;
  for (int k = 0; k < 8; ++k) {
    const glm::mat3 rot = Rotation(glm::vec3(1.0f, 2.0f, 3.0f), 0.37f * static_cast<float>(k));
    const Gathered g = InLeafCells(Transform(shell, rot, 1.0f, glm::vec3(0.0f, 0.0f, -1.0f)), 0.5f);
    for (HitSides sides : {HitSides::kFront, HitSides::kBoth}) {
      const double got =
          MustShade(g, glm::vec3(0.0f, 0.0f, 1e-4f), Options(Footprint::kPolygons, sides))
              .occlusion;
      worst = std::max(worst, got);
    }
  }
  EXPECT_LT(worst, 0.01);
  // A sheet folded over a convex edge: the receiver on its flat top (z = 0, x < 0) near the
  // edge at x = 0, where the sheet turns down (x = 0, z < 0). The first row of surfels lies a
  // tenth of a pitch from the edge (the sampler's centres fall anywhere), so the side's disks
  // reach above the top's plane by 0.46 of a pitch.
  std::vector<Surfel> fold;
  const float pitch = 0.1f;
  for (float u = 0.1f * pitch; u < 1.0f; u += pitch) {
    for (float y = -1.0f + 0.5f * pitch; y < 1.0f; y += pitch) {
      Surfel top, side;
      top.position = glm::vec3(-u, y, 0.0f);
      top.normal = glm::vec3(0.0f, 0.0f, 1.0f);
      side.position = glm::vec3(0.0f, y, -u);
      side.normal = glm::vec3(1.0f, 0.0f, 0.0f);
      top.radius = side.radius = pitch / std::sqrt(static_cast<float>(kPi));
      top.two_sided = side.two_sided = true;
      fold.push_back(top);
      fold.push_back(side);
    }
  }
  // Within a spacing of the edge (what the rule reaches; farther out the side's disks still
  // show: 0.034 at a pitch, 0.014 at 1.7 pitches). Untagged, and with both faces and the
  // receiver tagged as the one sheet they are (Surfel::sheet).
  for (uint8_t sheet : {0, 5}) {
    for (Surfel& sf : fold) sf.sheet = sheet;
    const Gathered fg = InLeafCells(fold, 0.25f);
    for (float x : {-0.02f, -0.05f}) {
      const double got = MustShade(fg, glm::vec3(x, 0.013f, 1e-4f),
                                   Options(Footprint::kPolygons, HitSides::kFront), sheet)
                             .occlusion;
      EXPECT_LT(got, 0.01) << x << " sheet " << int{sheet};
    }
  }
  // A two-sided card a third of its spacing above the receiver (a decal over a panel).
  const float card_pitch = 0.06f, h = 0.02f;
  const double want = RectangleFormFactor(-0.5, 0.5, -0.5, 0.5, h);
  for (bool down : {true, false}) {
    std::vector<Surfel> card = SquareSurfels(0.5f, h, card_pitch);
    for (Surfel& sf : card) {
      sf.two_sided = true;
      if (!down) sf.normal = -sf.normal;
    }
    EXPECT_NEAR(MustShade(InLeafCells(card, 0.25f), glm::vec3(0.013f, 0.021f, 0.0f),
                          Options(Footprint::kPolygons, HitSides::kFront))
                    .occlusion,
                want, 0.03 * want)
        << down;
  }
}

// A leaf that passes through the receiver's leaf (the forest's leaves cross each other) is
// locally the picture of the receiver's own sheet folded over a convex edge: surfel centres
// below the receiver's tangent plane, their plane within a spacing of the receiver. Culled as
// a fold, their disks' parts above the receiver were missing (bug:
// crossing_leaves_culled_as_a_fold; the forest's worst receivers, 0.74 for rays' 0.997). With
// sheet tags (Surfel::sheet) that differ the leaf is another sheet, and the receiver sees what
// rays cast at the leaf find; untagged, or with the leaf's own tag, it is culled as a fold is
// (ConvexThinSheetDoesNotCoverItsReceiver).
TEST(TwoSidedTest, ACrossingLeafIsNotTheReceiversOwnFold) {
  // The leaf: the points (d + t ux, y, t uz), |t|, |y| <= 0.12, crossing z = 0 along x = d and
  // leaning over the receiver at the origin (ux < 0 above the plane); 3 x 3 surfels on a
  // lattice over it, each alone in its leaf cell, as coarse against the leaf as the forest's at
  // 2 M surfels. Each is a piece of the leaf near the receiver, drawn as its core, the square a
  // spacing wide about its centre (SheetCore): the squares tile the leaf. Drawn as their disks,
  // they matched rays at the disks and fell short of the leaf's (0.527 for 0.575 at d 0.04).
  // (A disk that passes over the receiver within a third of its radius is drawn up to a fifth
  // short of what rays find, with or without tags: docs/eval.md, "Session 19"; these leaves keep
  // their pieces farther.)
  for (const auto& at :
       {std::pair{0.04f, 1.05f}, std::pair{-0.03f, 1.3f}, std::pair{-0.05f, 0.7f}}) {
    const float d = at.first, theta = at.second;  // a lambda below captures d (not a binding)
    const glm::vec3 u(-std::cos(theta), 0.0f, std::sin(theta));
    const glm::vec3 n = glm::normalize(glm::cross(u, glm::vec3(0.0f, 1.0f, 0.0f)));
    const float pitch = 0.08f, half = 0.12f;
    std::vector<Surfel> leaf;
    for (float t = -half + 0.5f * pitch; t < half; t += pitch) {
      for (float y = -half + 0.5f * pitch; y < half; y += pitch) {
        Surfel sf;
        sf.position = glm::vec3(d, 0.0f, 0.0f) + t * u + glm::vec3(0.0f, y, 0.0f);
        sf.normal = n;
        sf.radius = pitch / std::sqrt(static_cast<float>(kPi));
        sf.two_sided = true;
        sf.sheet = 9;
        leaf.push_back(sf);
      }
    }
    // Rays: cosine-weighted directions from the receiver at the leaf the lattice samples (every
    // point of a ray lies above z = 0, so only what is above the receiver's plane is hit).
    const double want = CosineRayFraction(400, [&](const glm::dvec3& w) {
      const glm::dvec3 c(d, 0.0, 0.0), dn(n);
      const double wn = glm::dot(w, dn);
      if (std::fabs(wn) < 1e-12) return false;
      const double s = glm::dot(c, dn) / wn;
      const glm::dvec3 q = s * w - c;
      return s > 0.0 && std::fabs(glm::dot(q, glm::dvec3(u))) <= half && std::fabs(q.y) <= half;
    });
    const Gathered g = InLeafCells(leaf, 0.03f);
    const RasterOptions o = Options(Footprint::kPolygons, HitSides::kFront);
    const glm::vec3 p(0.0f, 0.0f, 1e-4f);
    const double other = MustShade(g, p, o, /*sheet=*/3).occlusion;
    const double unknown = MustShade(g, p, o, /*sheet=*/0).occlusion;
    const double own = MustShade(g, p, o, /*sheet=*/9).occlusion;
    EXPECT_NEAR(other, want, 0.02 + 0.03 * want) << d << " " << theta;
    EXPECT_EQ(own, unknown) << d << " " << theta;
    EXPECT_LT(unknown, 0.7 * want) << d << " " << theta;
  }
}

// The same for a leaf drawn as a co-planar group (a leaf cell holding all of its surfels):
// the concave own-sheet rule (InsideOwnSheet) culled a group whose plane passes within its
// thickness (at least kOwnSheetReach of a spacing) of the receiver whatever its tag, and a
// leaf crossing the receiver's leaf right at the receiver was not drawn at all (the forest at
// 8 M surfels: a receiver 0.01 under such a leaf at 0.86 for rays' 0.99; bug:
// crossing_leaf_culled_as_the_receivers_concave_sheet). Tags known and different now keep it,
// as OwnSurfaceFromBehind does; equal or unknown tags keep the rule.
TEST(TwoSidedTest, ACrossingLeafGroupIsNotTheReceiversOwnSheet) {
  for (const float theta : {0.6f, 0.9f, 1.2f}) {
    // The leaf: a 0.24 square of 4 x 4 surfels through (0, 0, h), turned theta about y, its
    // normal with a +z component (turned the receiver's way), the receiver h / cos(theta)
    // behind its plane, under kOwnSheetReach of a spacing.
    const float pitch = 0.06f, half = 0.12f, h = 0.002f;
    const glm::vec3 u(std::cos(theta), 0.0f, -std::sin(theta));
    const glm::vec3 v(0.0f, 1.0f, 0.0f);
    const glm::vec3 n = glm::normalize(glm::cross(u, v));  // z > 0
    const glm::vec3 c(0.0f, 0.0f, h);
    std::vector<Surfel> leaf;
    for (float a = -half + 0.5f * pitch; a < half; a += pitch) {
      for (float b = -half + 0.5f * pitch; b < half; b += pitch) {
        Surfel sf;
        sf.position = c + a * u + b * v;
        sf.normal = n;
        sf.radius = pitch / std::sqrt(static_cast<float>(kPi));
        sf.two_sided = true;
        sf.sheet = 9;
        leaf.push_back(sf);
      }
    }
    const double want = CosineRayFraction(400, [&](const glm::dvec3& w) {
      const double wn = glm::dot(w, glm::dvec3(n));
      if (std::fabs(wn) < 1e-12) return false;
      const double s = glm::dot(glm::dvec3(c), glm::dvec3(n)) / wn;
      const glm::dvec3 q = s * w - glm::dvec3(c);
      return s > 0.0 && std::fabs(glm::dot(q, glm::dvec3(u))) <= half &&
             std::fabs(glm::dot(q, glm::dvec3(v))) <= half;
    });
    // One leaf cell around the leaf, so that it is one group.
    const glm::vec3 shift(0.5f, 0.5f, 0.5f);
    for (Surfel& sf : leaf) sf.position += shift;
    const Gathered g = InLeafCells(leaf, 1.0f);
    const RasterOptions o = Options(Footprint::kPolygons, HitSides::kFront);
    const double other = MustShade(g, shift, o, /*sheet=*/3).occlusion;
    const double own = MustShade(g, shift, o, /*sheet=*/9).occlusion;
    // Before: 0 for rays' 0.68 to 0.91 whatever the tags; now within 0.0005.
    EXPECT_NEAR(other, want, 0.01 + 0.02 * want) << theta;
    EXPECT_LT(own, 0.5 * want) << theta;
  }
}

// The same for a two-sided sheet, which is visible from both sides whatever hitsides says: in
// a two-sided half-pipe the co-planar group of the receiver's own cell, whose mean plane passes a
// hair above the receiver at the bottom of the curve, was drawn from behind and covered most of
// the hemisphere (bug: own_sheet_seen_from_behind; on Wuson.ply's ears +0.7). A parallel sheet
// a fifth of a spacing above the receiver is another layer, not its own, and still closes it.
TEST(TwoSidedTest, OwnSheetSeenFromBehind) {
  std::vector<Surfel> pipe;
  const float pitch = 0.02f;
  for (float x = -4.0f + 0.5f * pitch; x < 4.0f; x += pitch) {
    for (float a = -0.5f * static_cast<float>(kPi) + 0.5f * pitch;
         a < 0.5f * static_cast<float>(kPi); a += pitch) {
      Surfel sf;
      sf.position = glm::vec3(x, std::sin(a), 1.0f - std::cos(a));
      sf.normal = glm::vec3(0.0f, -std::sin(a), std::cos(a));
      sf.radius = pitch / std::sqrt(static_cast<float>(kPi));
      sf.two_sided = true;
      pipe.push_back(sf);
    }
  }
  // Rays from the receiver (the origin, normal +z) against the cylinder y^2 + (z - 1)^2 = 1,
  // |x| <= 4, z <= 1, cosine-distributed.
  int hits = 0;
  const int n = 300;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double u = (i + 0.5) / n, v = (j + 0.5) / n, r = std::sqrt(u);
      const double dx = r * std::cos(2.0 * kPi * v), dy = r * std::sin(2.0 * kPi * v);
      const double dz = std::sqrt(1.0 - u);
      const double t = 2.0 * dz / (dy * dy + dz * dz);
      hits += t * dz <= 1.0 && std::fabs(t * dx) <= 4.0;
    }
  }
  const double want = static_cast<double>(hits) / (n * n);
  // The bottom of the pipe in the middle of a leaf cell, so that the cell's group is the curve's
  // both sides and its mean plane lies above the receiver.
  for (float cell : {0.1f, 0.25f}) {
    const glm::vec3 at(0.5f * cell, 0.5f * cell, 0.0f);
    std::vector<Surfel> moved = pipe;
    for (Surfel& s : moved) s.position += at;
    const Gathered g = InLeafCells(moved, cell);
    for (HitSides sides : {HitSides::kFront, HitSides::kBoth}) {
      const double got = MustShade(g, at, Options(Footprint::kPolygons, sides)).occlusion;
      EXPECT_NEAR(got, want, 0.03) << "cell " << cell << " " << Name(sides);
    }
  }
  // A two-sided square sheet 0.2 spacings above the receiver, facing the receiver's way, is
  // another layer; and so is one 0.6 spacings above the receiver's own sheet with a third 0.6
  // below it, all in the same leaf cells (a folded part, like Wuson.ply's ears): the leaf's
  // surfels form one group per layer, the own one is culled and the one above still closes the
  // hemisphere (bug: layered_sheets_in_one_group: one group across the three, whose mean plane
  // is the receiver's, was culled as its own).
  // One leaf cell, [0, 0.1]^3, holding 5 x 5 surfels per layer; the receiver in its middle.
  const float z0 = 0.05f;
  const glm::vec3 mid(0.05f, 0.05f, 0.0f);
  for (float h : {0.2f, 0.6f}) {
    std::vector<Surfel> sheets = SquareSurfels(0.05f, z0 + h * pitch, pitch);
    if (h > 0.5f) {
      for (float z : {z0, z0 - h * pitch}) {
        const std::vector<Surfel> more = SquareSurfels(0.05f, z, pitch);
        sheets.insert(sheets.end(), more.begin(), more.end());
      }
    }
    for (Surfel& s : sheets) {
      s.position += mid;
      s.two_sided = true;
      s.normal = glm::vec3(0.0f, 0.0f, 1.0f);
    }
    const glm::vec3 at = mid + glm::vec3(0.0f, 0.0f, z0);
    // The square above: 0.1 wide at height h spacings.
    const double want = RectangleFormFactor(-0.05, 0.05, -0.05, 0.05, h * pitch);
    const double got =
        MustShade(InLeafCells(sheets, 0.1f), at, Options(Footprint::kPolygons, HitSides::kFront))
            .occlusion;
    EXPECT_NEAR(got, want, 0.05) << "sheet " << h << " spacings above";
  }
}

// With hitsides both, a cluster of the receiver's own surface turning away past a convex crease
// is seen from behind, and its footprint (its box grown to its cell's sides) reaches above the
// receiver's tangent plane although its content lies below it: drawn, it covered what rays
// give as open sky (bug: own_surface_clusters_seen_from_behind). The case as spider.obj's
// database gave it: a depth-9 cluster of three surfels of a face 45 degrees from the receiver's,
// all 0.002-0.15 below its tangent plane, spacing half the cell's side, 0.26 for rays' 0.0005
// (the mesh's both-bias +0.006). A cluster seen from behind whose box centre lies behind the
// receiver's tangent plane now shows nothing; a wall beside the receiver seen from behind (its
// centre in front of that plane) still occludes.
TEST(TwoSidedTest, OwnConvexSurfaceClustersSeenFromBehindShowNothing) {
  const glm::vec3 nb(0.82298559f, 0.567671359f, 0.0210679788f);
  std::vector<Surfel> face;
  for (const glm::vec3 q : {glm::vec3(-9.99863434f, 27.2464142f, 34.3750458f),
                            glm::vec3(-9.89453125f, 27.0992432f, 34.2752686f),
                            glm::vec3(-9.89886475f, 27.0961075f, 34.5307922f)}) {
    Surfel s;
    s.position = q;
    s.normal = nb;
    s.radius = 0.101745605f;
    face.push_back(s);
  }
  Gathered g;
  g.clusters.push_back(testing_raster::Aggregate(face));
  g.clusters.back().cell.lo = glm::vec3(-10.183201f, 27.095693f, 34.190945f);
  g.clusters.back().cell.hi = glm::vec3(-9.805501f, 27.473394f, 34.568645f);
  MicroBuffer mb;
  ShadeReceiver r;
  r.position = glm::vec3(-10.2597f, 27.31348f, 34.39374f);
  r.normal = glm::vec3(0.246821f, 0.875552f, 0.415317f);
  ShadeResult out;
  ASSERT_TRUE(Shade(g, r, Options(Footprint::kPolygons, HitSides::kBoth), &mb, &out).ok());
  EXPECT_LT(out.occlusion, 0.01);
  // A wall standing beside a receiver at the origin (normal +z), its back towards it.
  std::vector<Surfel> wall;
  const float pitch = 0.05f;
  for (float y = -1.0f + 0.5f * pitch; y < 1.0f; y += pitch) {
    for (float z = 0.5f * pitch; z < 1.0f; z += pitch) {
      Surfel s;
      s.position = glm::vec3(0.5f, y, z);
      s.normal = glm::vec3(1.0f, 0.0f, 0.0f);
      s.radius = pitch / std::sqrt(static_cast<float>(kPi));
      wall.push_back(s);
    }
  }
  Gathered w;
  w.clusters = ClustersInCells(wall, 0.5f);
  EXPECT_LT(
      MustShade(w, glm::vec3(0.0f), Options(Footprint::kPolygons, HitSides::kFront)).occlusion,
      0.01);
  EXPECT_GT(MustShade(w, glm::vec3(0.0f), Options(Footprint::kPolygons, HitSides::kBoth)).occlusion,
            0.1);
}

// A two-sided sheet that goes on across its leaf cells (an open part of a mesh marked thin, a
// card larger than its cells) is closed where its cells meet: a receiver under it occludes the
// sheet's form factor. Each cell's footprint ended half a spacing past its outermost centres,
// where a piece of a leaf ends; stratified centres fall anywhere in their strata, so the
// footprints left gaps of up to a spacing along the cell sides, and a receiver a few spacings
// below looked through them (Wuson.ply: receivers in the wedges under its thin parts at 0.93 for
// rays' 0.99; bug: two_sided_sheet_gaps_between_cells). A stratified disk of radius 12
// pitches, in leaf cells 2.3 pitches wide off its strata, at 1.5 to 6 pitches above the
// receiver; level, and with the receiver turned with it 20 degrees about a diagonal (the cells
// then cut it obliquely): within 0.004 and 0.015 of the disk's form factor (before: 0.08 to 0.15
// short). The pieces of a sheet that ends inside its cells (leaves) keep their own rule:
// porous_test.cc.
TEST(TwoSidedTest, ASheetAcrossItsCellsHasNoGaps) {
  const float pitch = 0.1f, radius = 12.0f * pitch, cell = 2.3f * pitch;
  const glm::vec3 off(0.37f * pitch, 0.61f * pitch, 0.29f * pitch);  // the receiver, off the cells
  for (float h : {1.5f * pitch, 3.0f * pitch, 6.0f * pitch}) {
    for (float angle : {0.0f, 0.35f}) {
      const glm::mat3 rot = Rotation(glm::vec3(1.0f, 1.0f, 0.0f), angle);
      std::vector<Surfel> sheet = Transform(
          testing_raster::DiskSurfels(glm::vec3(0.0f, 0.0f, h), glm::vec3(0.0f, 0.0f, -1.0f),
                                      radius, pitch, glm::vec3(0.0f), /*jitter=*/true),
          rot, 1.0f, off);
      for (Surfel& s : sheet) s.two_sided = true;
      const Gathered g = InLeafCells(sheet, cell);
      const double want = radius * radius / (h * h + radius * radius);
      for (HitSides sides : {HitSides::kFront, HitSides::kBoth}) {
        MicroBuffer mb;
        ShadeReceiver r;
        r.position = off;
        r.normal = rot * glm::vec3(0.0f, 0.0f, 1.0f);
        ShadeResult out;
        ASSERT_TRUE(Shade(g, r, Options(Footprint::kPolygons, sides), &mb, &out).ok());
        // Turned, the oblique cells cut slivers of one or two surfels off the sheet, which keep
        // a leaf's rule (kSheetMinCount): 0.011 short at 3 pitches, 0.002 level.
        EXPECT_NEAR(out.occlusion, want, angle == 0.0f ? 0.004 : 0.015)
            << h << " " << angle << " " << Name(sides);
      }
    }
  }
}

// A leaf of the forest: a two-sided quad 0.36 x 0.24, its surfels at its pieces' centres (at
// 2 M surfels one at each triangle's centroid), disks that hold its area. Drawn as the plane
// inside the world-axis box of its centres grown to hold their area, a tilted leaf's footprint
// was the box's oblique section, up to twice the leaf's length along the plane's slope at a
// lower opacity: a receiver under the leaf saw it translucent and one beside it saw it where it
// is not (the forest's two worst receivers at 2 M: 0.30 for rays' 0.12, 0.79 for 0.59; bug:
// a_leafs_pair_drawn_as_its_boxs_section). A two-sided group that ends in its cell is drawn in
// its own plane's axes instead: a pair as a rhombus along it (PairFootprint), more as the
// rectangle of their centres along their principal axes (InPlaneFootprint). Receivers facing up
// 0.12 and 0.25 under the leaf's centre and beside it, eight tilts, against rays at the quad.
TEST(TwoSidedTest, ALeafIsDrawnInItsOwnPlanesAxes) {
  const float lw = 0.18f, lh = 0.12f;
  const glm::vec3 c(0.33f, 0.33f, 0.40f);  // inside the leaf cell [0, 0.66]^3
  // Surfels per leaf: 2 (one at each triangle's centroid, as at 2 M surfels), 4 and 8 (the
  // quad's pieces as a 2 x 2 and a 4 x 2 grid, as at 4 M and 8 M).
  for (const int count : {2, 4, 8}) {
    const float r = std::sqrt(4.0f * lw * lh / (count * static_cast<float>(kPi)));
    double err = 0.0, under = 0.0;
    int receivers = 0;
    for (int k = 0; k < 8; ++k) {
      const float a = 0.7f + 0.77f * k, e = 0.35f + 0.13f * k;
      const glm::vec3 n(std::cos(a) * std::sin(e), std::sin(a) * std::sin(e), std::cos(e));
      const glm::vec3 t = glm::normalize(glm::cross(n, glm::vec3(0.3f, 0.9f, 0.1f)));
      const glm::vec3 b = glm::cross(n, t);
      std::vector<glm::vec3> at;
      if (count == 2) {
        const glm::vec3 p0 = c - lw * t - lh * b, p1 = c + lw * t - lh * b,
                        p2 = c + lw * t + lh * b, p3 = c - lw * t + lh * b;
        at = {(p0 + p1 + p2) / 3.0f, (p0 + p2 + p3) / 3.0f};
      } else {
        const int cols = count / 2;
        for (int i = 0; i < cols; ++i) {
          for (int j = 0; j < 2; ++j) {
            at.push_back(c + ((i + 0.5f) / cols * 2.0f - 1.0f) * lw * t +
                         ((j + 0.5f) / 2.0f * 2.0f - 1.0f) * lh * b);
          }
        }
      }
      std::vector<Surfel> leaf;
      for (const glm::vec3& x : at) {
        Surfel sf;
        sf.position = x;
        sf.normal = n;
        sf.radius = r;
        sf.two_sided = true;
        leaf.push_back(sf);
      }
      const Gathered g = InLeafCells(leaf, 0.66f);
      for (const float h : {0.12f, 0.25f}) {
        for (const glm::vec2 off : {glm::vec2(0.0f), glm::vec2(0.2f, 0.0f), glm::vec2(0.0f, -0.2f),
                                    glm::vec2(-0.15f, 0.15f)}) {
          const glm::vec3 p = c + glm::vec3(off, -h);
          const double want = CosineRayFraction(300, [&](const glm::dvec3& w) {
            const glm::dvec3 q0 = glm::dvec3(c) - glm::dvec3(p);
            const double wn = glm::dot(w, glm::dvec3(n));
            if (std::fabs(wn) < 1e-12) return false;
            const double s = glm::dot(q0, glm::dvec3(n)) / wn;
            const glm::dvec3 q = s * w - q0;
            return s > 0.0 && std::fabs(glm::dot(q, glm::dvec3(t))) <= lw &&
                   std::fabs(glm::dot(q, glm::dvec3(b))) <= lh;
          });
          const double got =
              MustShade(g, p, Options(Footprint::kPolygons, HitSides::kFront)).occlusion;
          err += std::fabs(got - want);
          ++receivers;
          if (off == glm::vec2(0.0f) && h < 0.2f) under = std::max(under, std::fabs(got - want));
        }
      }
    }
    // Under the leaf's centre 0.12 below it, before: 0.046 to 0.115 short with 2 surfels, up
    // to 0.156 and 0.164 with 4 and 8; now within 0.019, 0.008, 0.012. Mean |error| over the
    // 64 receivers, before: 0.0242, 0.0277, 0.0255; now 0.0158, 0.0090, 0.0062 (a receiver at
    // the edge of a leaf of two surfels still sees a rhombus where the leaf is a rectangle).
    EXPECT_LT(under, count == 2 ? 0.03 : 0.02) << count << " surfels";
    EXPECT_LT(err / receivers, count == 2 ? 0.019 : 0.012) << count << " surfels";
    RecordProperty("mean_abs_error_" + std::to_string(count), std::to_string(err / receivers));
    RecordProperty("under_abs_error_" + std::to_string(count), std::to_string(under));
  }
}

// A two-sided sheet sampled as the scene sampler samples a mesh's thin part: one point in each
// of nu x nv lattice squares of edge `pitch` spanned by du, dv from o (a hash of the square and
// `salt` places it), each a disk of the square's area.
std::vector<Surfel> LatticeSheet(const glm::vec3& o, const glm::vec3& du, const glm::vec3& dv,
                                 int nu, int nv, float pitch, const glm::vec3& normal,
                                 uint32_t salt) {
  std::vector<Surfel> out;
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      const uint32_t key = (uint32_t(i) * 73856093u ^ uint32_t(j) * 19349663u) + salt;
      Surfel s;
      s.position = o + (i + testing_raster::Hash01(key ^ 0x9e3779b9u)) * pitch * du +
                   (j + testing_raster::Hash01(key ^ 0x85ebca6bu)) * pitch * dv;
      s.normal = normal;
      s.radius = pitch / std::sqrt(static_cast<float>(kPi));
      s.two_sided = true;
      out.push_back(s);
    }
  }
  return out;
}

// Rays from a receiver at the origin (normal +z) at the parallelogram o + u du + v dv, u in
// [u0, u1], v in [v0, v1] (du, dv unit and in the plane of unit `normal`): its cosine-weighted
// share of the hemisphere.
double ParallelogramRayFraction(const glm::vec3& o, const glm::vec3& normal, const glm::vec3& du,
                                const glm::vec3& dv, double u0, double u1, double v0, double v1) {
  return CosineRayFraction(300, [&](const glm::dvec3& w) {
    const double wn = glm::dot(w, glm::dvec3(normal));
    if (std::fabs(wn) < 1e-12) return false;
    const double t = glm::dot(glm::dvec3(o), glm::dvec3(normal)) / wn;
    if (!(t > 0.0)) return false;
    const glm::dvec3 q = t * w - glm::dvec3(o);
    const double u = glm::dot(q, glm::dvec3(du)), v = glm::dot(q, glm::dvec3(dv));
    return u >= u0 && u <= u1 && v >= v0 && v <= v1;
  });
}

// The occlusion of a receiver at `move` (normal +z) by a sheet moved with it, in leaf cells of
// side `cell`: another cut of the same sheet and receiver by the same cells.
double MovedSheetOcclusion(const std::vector<Surfel>& part, const glm::vec3& move, float cell) {
  std::vector<Surfel> sheet = part;
  for (Surfel& s : sheet) s.position += move;
  return MustShade(InLeafCells(sheet, cell), move, Options(Footprint::kPolygons, HitSides::kFront))
      .occlusion;
}

// A wedge under a thin part of a mesh: a two-sided sheet rising at 30 and 42 degrees from a
// crease 1.5 and 2.5 pitches beside the receiver passes over it, sampled as the scene sampler
// samples (one point in each lattice square), in leaf cells 2.1 pitches wide: a cell holds
// two to six surfels where 4.45 are expected. The pieces along the crease end
// there, so they do not fill their cells, and each piece's opacity was its count over its
// section, clamped at 1: three surfels drew 0.67, a pair 0.45, six 1, and the receiver looked
// through the poorer pieces (Wuson.ply: a receiver in such a wedge at 0.897 for rays' 0.940;
// bug: going_on_sheet_pieces_translucent_by_sampling_noise). A piece of a sheet that goes on
// past two or more of its cell's sides (a pair: three), alone in the cell and a few surfels'
// areas wide, is opaque. Against rays at the sheet, the cells shifted across it three ways: before,
// 0.070 to 0.190 short (mean 0.113); now within 0.014 (mean 0.006).
TEST(TwoSidedTest, AThinPartsPiecesOverAWedgeAreOpaque) {
  const float pitch = 0.1f, cell = 2.1f * pitch, length = 16.0f * pitch, half_width = 8.0f * pitch;
  double worst = 0.0, sum = 0.0;
  int n = 0;
  for (const float crease : {1.5f * pitch, 2.5f * pitch}) {
    for (const float degrees : {30.0f, 42.0f}) {
      const float a = degrees * static_cast<float>(kPi) / 180.0f;
      const glm::vec3 o(-crease, 0.0f, 0.0f), du(std::cos(a), 0.0f, std::sin(a)),
          dv(0.0f, 1.0f, 0.0f), normal(-std::sin(a), 0.0f, std::cos(a));
      const double want =
          ParallelogramRayFraction(o, normal, du, dv, 0.0, length, -half_width, half_width);
      const std::vector<Surfel> part =
          LatticeSheet(o - half_width * dv, du, dv, static_cast<int>(length / pitch + 0.5f),
                       static_cast<int>(2.0f * half_width / pitch + 0.5f), pitch, normal, 0u);
      for (const glm::vec2 shift :
           {glm::vec2(0.37f, 0.61f), glm::vec2(0.13f, 0.22f), glm::vec2(0.82f, 0.47f)}) {
        const double got = MovedSheetOcclusion(
            part, glm::vec3(shift.x * pitch, shift.y * pitch, 0.31f * pitch), cell);
        worst = std::max(worst, std::fabs(got - want));
        sum += std::fabs(got - want);
        ++n;
        EXPECT_NEAR(got, want, 0.02) << crease << " " << degrees << " " << shift.x;
      }
    }
  }
  RecordProperty("worst_abs_error", std::to_string(worst));
  RecordProperty("mean_abs_error", std::to_string(sum / n));
}

// A two-sided sheet turned from every world axis, its normal 27 degrees off z (|n_z| 0.89, just
// under the in-plane test's 0.9), 2.8 pitches over the receiver, in leaf cells 4.2 pitches
// wide: each cell's piece holds 12 to 22 surfels where about 20 fit its section, more than a
// few surfels' areas. Whether the sheet goes on past a side was judged only by the next
// samples' span along the world axes, z among them: beyond a side they are a thin slab of the
// plane and span little of z where the piece spans the plane's rise across the cell, so the
// sheet was taken to end in cells that it crosses, and its pieces were drawn at their count
// over their section (Wuson.ply's receiver in a slot under a thin part: 0.86 for rays' 0.98;
// bug: surrounded_sheet_pieces_translucent_by_their_count). Against rays at the parallelogram.
TEST(TwoSidedTest, ATurnedSheetOverAReceiverIsOpaque) {
  const float pitch = 0.1f, cell = 4.2f * pitch, h = 2.8f * pitch;
  const float half_u = 10.0f * pitch, half_v = 12.0f * pitch;
  const glm::vec3 normal = glm::normalize(glm::vec3(0.429f, -0.145f, 0.892f));
  const glm::vec3 du = glm::normalize(glm::cross(glm::vec3(0, 1, 0), normal));
  const glm::vec3 dv = glm::cross(normal, du);
  const glm::vec3 centre(0.0f, 0.0f, h);
  const double want =
      ParallelogramRayFraction(centre, normal, du, dv, -half_u, half_u, -half_v, half_v);
  const std::vector<Surfel> part = LatticeSheet(
      centre - half_u * du - half_v * dv, du, dv, static_cast<int>(2.0f * half_u / pitch + 0.5f),
      static_cast<int>(2.0f * half_v / pitch + 0.5f), pitch, normal, 3u);
  double worst = 0.0, sum = 0.0;
  int n = 0;
  for (const glm::vec3 shift : {glm::vec3(0.37f, 0.61f, 0.29f), glm::vec3(0.13f, 0.22f, 0.71f),
                                glm::vec3(0.82f, 0.47f, 0.05f), glm::vec3(2.4f, 1.3f, 3.6f)}) {
    const double got = MovedSheetOcclusion(part, shift * pitch, cell);
    worst = std::max(worst, std::fabs(got - want));
    sum += std::fabs(got - want);
    ++n;
    EXPECT_NEAR(got, want, 0.02) << shift.x << " " << shift.y << " " << shift.z;
  }
  RecordProperty("worst_abs_error", std::to_string(worst));
  RecordProperty("mean_abs_error", std::to_string(sum / n));
}

// The mean and the worst |error| of a test's cases, recorded as the test's properties.
struct ErrorTally {
  double sum = 0.0, worst = 0.0;
  int n = 0;
  void Add(double got, double want) {
    sum += std::fabs(got - want), worst = std::max(worst, std::fabs(got - want)), ++n;
  }
  double Mean() const { return sum / n; }
  void Record() const {
    ::testing::Test::RecordProperty("worst_abs_error", std::to_string(worst));
    ::testing::Test::RecordProperty("mean_abs_error", std::to_string(Mean()));
  }
};

// A leaf of 6 x 4 lattice squares of `pitch` at three tilts, receivers 0.4 to 1 pitches under
// five points of it, the cells (3.3 pitches) shifted across it two ways, against rays at the
// rectangle. One-sided, its surfels face the receiver.
ErrorTally NearLeafErrors(bool two_sided) {
  const float pitch = 0.06f, cell = 3.3f * pitch;
  const float half_u = 3.0f * pitch, half_v = 2.0f * pitch;
  ErrorTally errors;
  for (const float tilt : {0.0f, 0.35f, 0.7f}) {
    const glm::vec3 normal(0.0f, -std::sin(tilt), std::cos(tilt));
    const glm::vec3 du(1.0f, 0.0f, 0.0f), dv = glm::cross(normal, du);
    for (const float h : {0.4f, 0.7f, 1.0f}) {
      for (const glm::vec2 at : {glm::vec2(0.0f), glm::vec2(1.3f, 0.6f), glm::vec2(-2.1f, -0.9f),
                                 glm::vec2(2.2f, -1.2f), glm::vec2(-0.7f, 1.3f)}) {
        // The leaf's point `at` (in pitches along du, dv) lies h pitches above the receiver.
        const glm::vec3 centre = h * pitch * normal - at.x * pitch * du - at.y * pitch * dv;
        const double want =
            ParallelogramRayFraction(centre, normal, du, dv, -half_u, half_u, -half_v, half_v);
        std::vector<Surfel> part = LatticeSheet(centre - half_u * du - half_v * dv, du, dv, 6, 4,
                                                pitch, two_sided ? normal : -normal, 7u);
        for (Surfel& sf : part) sf.two_sided = two_sided;
        for (const glm::vec3 shift :
             {glm::vec3(0.37f, 0.61f, 0.29f), glm::vec3(1.82f, 2.47f, 0.55f)}) {
          errors.Add(MovedSheetOcclusion(part, shift * pitch, cell), want);
        }
      }
    }
  }
  return errors;
}

// A leaf a receiver lies just under (the forest's crowns at 8 M surfels: a leaf of 0.36 x 0.24
// sampled by about ten surfels, cut by leaf cells about three spacings wide): each piece's
// footprint is snapped to where its sheet goes on, or grown past its centres, and was drawn at
// its surfels' area over its section, so a receiver 0.6 spacings under a leaf saw it at 0.69
// opacity where rays see it whole (the forest's worst receiver at 8 M surfels, 0.917 for rays'
// 0.996; bug: near_sheet_pieces_translucent_inside_their_centres). A piece near the receiver
// has an opaque core, its centres' hull (carried to the sides where its sheet goes on) grown by
// half a spacing (SheetCore), the rest of its footprint holding what is left of its area (at
// least half its opacity where its sheet goes on). A leaf of 6 x 4 lattice squares at three tilts,
// receivers 0.4 to 1 spacings under five points of it, the cells shifted across it two ways,
// against rays at the rectangle: mean |error| 0.082 before, 0.038 now; the worst 0.323 and 0.291 (a
// receiver 0.4 spacings under a corner of the leaf tilted 40 degrees: a neighbouring cell's core
// need not reach the side the two share). The core shrinks from 3 to 6 spacings away at res 12
// (6 to 12 at res 24): a receiver moving through that band in steps of 0.02 spacings under a
// fixed leaf steps by at most 0.002 more than the rays do (0.028 if the core ended at 6 spacings
// without shrinking; 0.0006 at res 24).
TEST(TwoSidedTest, ANearLeafsPiecesAreOpaqueInside) {
  const ErrorTally errors = NearLeafErrors(/*two_sided=*/true);
  errors.Record();
  EXPECT_LT(errors.Mean(), 0.045);
  EXPECT_LT(errors.worst, 0.31);

  // Continuity through the core's fade: the leaf tilted 20 degrees and fixed in its cells, the
  // receiver moving down from 2 to 7 spacings under it, near its corner.
  const float pitch = 0.06f, cell = 3.3f * pitch;
  const float half_u = 3.0f * pitch, half_v = 2.0f * pitch;
  const glm::vec3 normal(0.0f, -std::sin(0.35f), std::cos(0.35f)), du(1.0f, 0.0f, 0.0f),
      dv = glm::cross(normal, du);
  const glm::vec3 centre =
      2.1f * pitch * du + 0.9f * pitch * dv + glm::vec3(0.37f, 0.61f, 0.29f) * pitch;
  const Gathered leaf = InLeafCells(
      LatticeSheet(centre - half_u * du - half_v * dv, du, dv, 6, 4, pitch, normal, 7u), cell);
  // The fade's band scales with the raster's resolution (twice as far at res 24): the receiver
  // moves through it at both.
  for (const int res : {12, 24}) {
    RasterOptions o = Options(Footprint::kPolygons, HitSides::kFront);
    o.resolution = res;
    double prev_got = -1.0, prev_want = -1.0, step = 0.0, ray_step = 0.0;
    const float scale = static_cast<float>(res) / 12.0f;
    for (float h = 2.0f * scale; h <= 7.0f * scale; h += 0.02f) {
      const glm::vec3 p = -h * pitch * normal;
      const double want =
          ParallelogramRayFraction(centre - p, normal, du, dv, -half_u, half_u, -half_v, half_v);
      const double got = MustShade(leaf, p, o).occlusion;
      if (prev_got >= 0.0) {
        step = std::max(step, std::fabs((got - prev_got) - (want - prev_want)));
        ray_step = std::max(ray_step, std::fabs(want - prev_want));
      }
      prev_got = got, prev_want = want;
    }
    RecordProperty("largest_step_past_the_rays_" + std::to_string(res), std::to_string(step));
    RecordProperty("rays_largest_step_" + std::to_string(res), std::to_string(ray_step));
    EXPECT_LT(step, 0.005) << res;
  }
}

// The same for a one-sided panel facing the receiver (a wall, a ceiling, the ground beside a
// trunk's foot): a piece that holds less than its footprint was drawn at its surfels' area over
// its section, a hedge of where in its cell the panel is. Near the receiver its centres' hull grown
// by half a spacing is drawn opaque, the rest holding what is left (from three members: a
// pair's rectangle overshot a wall's open end in the city). The panel of the test above, its
// surfels one-sided and facing the receiver, against rays at the rectangle: mean |error| 0.105
// before, 0.059 now; the worst 0.421 and 0.249.
TEST(TwoSidedTest, AOneSidedPanelsNearPiecesAreOpaqueInside) {
  const ErrorTally errors = NearLeafErrors(/*two_sided=*/false);
  errors.Record();
  EXPECT_LT(errors.Mean(), 0.07);
  EXPECT_LT(errors.worst, 0.3);
}

// Three small plates of a two-sided part, one surfel each, 2.7 spacings apart in one leaf cell
// (2CylinderEngine: three of a plate's surfels in a cell, their hull over sky that rays see). A
// piece near the receiver has an opaque core, its centres' hull grown by half a spacing: here the
// hull spans the gaps between the plates, and the receivers under it saw the gaps covered. Centres
// whose grown hull spans more than kCoreMaxSpan (1.5) times their surfels' area have no core (bug:
// sparse_pieces_core_spans_their_gaps). Receivers 0.7 to 1.5 spacings under three points of the
// triangle, flat and tilted 20 degrees, the cells shifted two ways, against rays at the three
// plates (squares a spacing wide): mean |error| 0.541 before, 0.078 now; the worst 0.761 and
// 0.146.
TEST(TwoSidedTest, ASparsePiecesHullIsNotItsSurface) {
  const float pitch = 0.06f, cell = 8.0f * pitch, side = 2.7f * pitch;
  ErrorTally errors;
  for (const float tilt : {0.0f, 0.35f}) {
    const glm::vec3 normal(0.0f, -std::sin(tilt), std::cos(tilt));
    const glm::vec3 du(1.0f, 0.0f, 0.0f), dv = glm::cross(normal, du);
    for (const float h : {0.7f, 1.0f, 1.5f}) {
      for (const glm::vec2 at : {glm::vec2(0.0f), glm::vec2(0.4f, 0.3f), glm::vec2(-0.5f, 0.2f)}) {
        const glm::vec3 centre = h * pitch * normal - at.x * pitch * du - at.y * pitch * dv;
        std::vector<Surfel> part;
        for (int k = 0; k < 3; ++k) {
          const float angle = 2.0f * static_cast<float>(kPi) / 3.0f * k + 0.3f;
          Surfel sf;
          sf.position =
              centre + side / std::sqrt(3.0f) * (std::cos(angle) * du + std::sin(angle) * dv);
          sf.normal = normal;
          sf.radius = pitch / std::sqrt(static_cast<float>(kPi));
          sf.two_sided = true;
          part.push_back(sf);
        }
        const double want = CosineRayFraction(300, [&](const glm::dvec3& w) {
          const double wn = glm::dot(w, glm::dvec3(normal));
          if (std::fabs(wn) < 1e-12) return false;
          const double t = glm::dot(glm::dvec3(centre), glm::dvec3(normal)) / wn;
          if (!(t > 0.0)) return false;
          for (const Surfel& sf : part) {
            const glm::dvec3 q = t * w - glm::dvec3(sf.position);
            if (std::fabs(glm::dot(q, glm::dvec3(du))) <= 0.5 * pitch &&
                std::fabs(glm::dot(q, glm::dvec3(dv))) <= 0.5 * pitch)
              return true;
          }
          return false;
        });
        for (const glm::vec3 shift :
             {glm::vec3(2.37f, 2.61f, 2.29f), glm::vec3(3.82f, 3.47f, 3.55f)}) {
          errors.Add(MovedSheetOcclusion(part, shift * pitch, cell), want);
        }
      }
    }
  }
  errors.Record();
  EXPECT_LT(errors.Mean(), 0.1);
  EXPECT_LT(errors.worst, 0.2);
}

// Narrow leaves, one and two lattice squares wide and four or six long (grass, a willow's
// leaves), sampled one point per square: a cell's piece of a leaf a square wide is a few centres
// near a line, often a thin triangle whose sharpest corner the core's mitre would carry more than
// 3.2 half spacings out. Such a group had no core, and a receiver under it saw its hedge (the
// forest at 8 M surfels and res 24: a receiver under a leaf's thin triangle of centres, 0.038
// short of its rays, 0.019 now; bug: sharp_hull_corner_leaves_no_core). A two-sided group's
// sharp corner is bevelled: cut square half a spacing past the centre. Receivers 0.4 to 1
// squares under three points of each leaf at three tilts, three samplings, the cells (3.3
// squares) shifted two ways, against rays at the leaf: mean |error| 0.0897 before, 0.0776 now.
// A leaf this narrow is at the sampling's limit: the worst is 0.58 before and after.
TEST(TwoSidedTest, ANarrowLeafsPiecesHaveCoresAtSharpCorners) {
  const float pitch = 0.06f, cell = 3.3f * pitch;
  ErrorTally errors;
  for (const float tilt : {0.0f, 0.35f, 0.7f}) {
    const glm::vec3 normal(0.0f, -std::sin(tilt), std::cos(tilt));
    const glm::vec3 du(1.0f, 0.0f, 0.0f), dv = glm::cross(normal, du);
    for (const int wide : {1, 2}) {
      for (const int len : {4, 6}) {
        const float half_u = 0.5f * len * pitch, half_v = 0.5f * wide * pitch;
        for (const float h : {0.4f, 0.7f, 1.0f}) {
          for (const float at : {0.0f, 1.1f, -1.6f}) {
            const glm::vec3 centre = h * pitch * normal - at * pitch * du;
            const double want =
                ParallelogramRayFraction(centre, normal, du, dv, -half_u, half_u, -half_v, half_v);
            for (const uint32_t salt : {7u, 11u, 23u}) {
              const std::vector<Surfel> part = LatticeSheet(centre - half_u * du - half_v * dv, du,
                                                            dv, len, wide, pitch, normal, salt);
              for (const glm::vec3 shift :
                   {glm::vec3(0.37f, 0.61f, 0.29f), glm::vec3(1.82f, 2.47f, 0.55f)}) {
                errors.Add(MovedSheetOcclusion(part, shift * pitch, cell), want);
              }
            }
          }
        }
      }
    }
  }
  errors.Record();
  EXPECT_LT(errors.Mean(), 0.083);
}

// A thin-walled part's corner (an L of two two-sided sheets, as 2CylinderEngine's brackets and
// CesiumMilkTruck's panels are): a panel 1 and 1.5 pitches above the receiver's plane ends
// where a lip 2 pitches deep hangs from it, and leaf cells 2.1 pitches wide hold pieces of both.
// Each piece was its plane across its cell, the lip's standing past the panel and the panel's
// reaching past the lip, where neither is: a receiver just outside the corner saw them over its
// zenith (2CylinderEngine: 0.272 for rays' 0.218; bug: sheet_pieces_reach_past_their_junction).
// A two-sided group's footprint ends at the plane of another two-sided group of its cell that
// it meets (ClipAtSheetJunctions). Receivers 0.5, 1 and 2 pitches outside the corner, the
// sheets sampled one point per lattice square, cut by the cells twelve ways: against rays at
// the two rectangles, mean |error| 0.040 before and 0.015 now, the worst 0.144 and 0.070.
// Where the panel's last centres lie within a spacing of its cell's side and the lip stands in
// the next cell, the panel's piece, grown to hold its area, reached past that side and past the
// lip, over the receiver (2CylinderEngine: a flange over a receiver inside a cylinder, 0.263
// for rays' 0.220; bug: sheet_pieces_reach_past_a_junction_in_the_next_cell). A piece also
// ends at the plane of another cell's sheet that it meets when that plane lies outside its own
// cell (CrossLeafSheetPair): 0.0147 -> 0.0105 (the fold rule, AFoldsPiecesAreOpaque, gave 0.0133
// of it), the worst 0.062 (what is left: lone surfels' disks at the junction).
TEST(TwoSidedTest, AThinCornersPiecesEndAtTheJunction) {
  const float pitch = 0.1f, cell = 2.1f * pitch;
  const float lip = 2.0f * pitch, length = 12.0f * pitch, half = 6.0f * pitch;
  double worst = 0.0, sum = 0.0;
  int n = 0;
  for (const float h : {1.0f * pitch, 1.5f * pitch}) {
    // The panel: z = h, x in [-length, 0], |y| <= half; the lip: x = 0, z in [h - lip, h].
    const int across = static_cast<int>(2.0f * half / pitch + 0.5f);
    std::vector<Surfel> part = LatticeSheet(
        glm::vec3(-length, -half, h), glm::vec3(1, 0, 0), glm::vec3(0, 1, 0),
        static_cast<int>(length / pitch + 0.5f), across, pitch, glm::vec3(0, 0, 1), 0u);
    const std::vector<Surfel> lip_part =
        LatticeSheet(glm::vec3(0.0f, -half, h - lip), glm::vec3(0, 0, 1), glm::vec3(0, 1, 0),
                     static_cast<int>(lip / pitch + 0.5f), across, pitch, glm::vec3(1, 0, 0), 7u);
    part.insert(part.end(), lip_part.begin(), lip_part.end());
    for (const float out_by : {0.5f * pitch, 1.0f * pitch, 2.0f * pitch}) {
      const glm::dvec3 p(out_by, 0.0, 0.0);
      const double want = CosineRayFraction(300, [&](const glm::dvec3& w) {
        if (w.z > 0.0) {  // the panel
          const glm::dvec3 q = p + ((h - p.z) / w.z) * w;
          if (q.x >= -length && q.x <= 0.0 && std::fabs(q.y) <= half) return true;
        }
        if (w.x < 0.0) {  // the lip
          const glm::dvec3 q = p + (-p.x / w.x) * w;
          if (q.z >= h - lip && q.z <= h && std::fabs(q.y) <= half) return true;
        }
        return false;
      });
      for (uint32_t k = 0; k < 12; ++k) {
        // The part and the receiver move together: other cuts of them by the same cells.
        const glm::vec3 move(testing_raster::Hash01(k * 977u + 1u) * 3.0f * pitch,
                             testing_raster::Hash01(k * 331u + 7u) * 3.0f * pitch, 0.31f * pitch);
        std::vector<Surfel> moved = part;
        for (Surfel& s : moved) s.position += move;
        const double got = MustShade(InLeafCells(moved, cell), glm::vec3(p) + move,
                                     Options(Footprint::kPolygons, HitSides::kFront))
                               .occlusion;
        worst = std::max(worst, std::fabs(got - want));
        sum += std::fabs(got - want);
        ++n;
      }
    }
  }
  EXPECT_LT(sum / n, 0.012);
  EXPECT_LT(worst, 0.066);
  RecordProperty("worst_abs_error", std::to_string(worst));
  RecordProperty("mean_abs_error", std::to_string(sum / n));
}

// A fold of a thin part (two two-sided sheets meeting at a ridge, as Wuson.ply's ears fold): a
// panel 0.3 and 0.6 pitches over the receiver's plane ends at a crease a pitch past the
// receiver, and a second sheet falls from it at 35 and 60 degrees, so that the receiver lies
// behind both; leaf cells 3 pitches wide hold pieces of both. ClipAtSheetJunctions ends each
// piece at the other's plane, but a piece so ended kept its count over its section as its
// opacity (six surfels where 6.6 fit: 0.91), and a receiver within a spacing behind the panel
// saw the sky through it (Wuson.ply: 0.909 for rays' 1; bug:
// sheet_junction_pieces_translucent_by_sampling_noise). A piece ended at a junction is its
// sheet's where it is: a section a few surfels' areas wide is opaque, as a convex solid's face
// is. The receiver lies on a sheet of its own (another tag). Against rays at the two rectangles,
// the part and the receiver cut by the cells twelve ways: mean |error| 0.0449 before, 0.0219
// now. What is left (the worst, 0.24 short before, 0.23 now): a cell that the panel enters by less
// than a spacing before the crease holds one or two of its surfels, or none, and its piece
// leaves most of that strip open.
TEST(TwoSidedTest, AFoldsPiecesAreOpaque) {
  const float pitch = 0.1f, cell = 3.0f * pitch;
  const float length = 10.0f * pitch, fall = 6.0f * pitch, half = 6.0f * pitch;
  const int across = static_cast<int>(2.0f * half / pitch + 0.5f);
  double worst = 0.0, sum = 0.0;
  int n = 0;
  for (const float h : {0.3f * pitch, 0.6f * pitch}) {
    for (const float degrees : {35.0f, 60.0f}) {
      const float a = degrees * static_cast<float>(kPi) / 180.0f;
      // The panel: z = h, x in [-length, 0], |y| <= half; the second sheet falls from the
      // crease x = 0, z = h along du.
      const glm::vec3 crease(0.0f, 0.0f, h), du(std::cos(a), 0.0f, -std::sin(a));
      const glm::vec3 nb(std::sin(a), 0.0f, std::cos(a));
      std::vector<Surfel> part = LatticeSheet(
          glm::vec3(-length, -half, h), glm::vec3(1, 0, 0), glm::vec3(0, 1, 0),
          static_cast<int>(length / pitch + 0.5f), across, pitch, glm::vec3(0, 0, 1), 0u);
      const std::vector<Surfel> fold =
          LatticeSheet(crease - glm::vec3(0.0f, half, 0.0f), du, glm::vec3(0, 1, 0),
                       static_cast<int>(fall / pitch + 0.5f), across, pitch, nb, 7u);
      part.insert(part.end(), fold.begin(), fold.end());
      for (Surfel& s : part) s.sheet = 1;
      const glm::dvec3 p(-pitch, 0.0, 0.0);
      const double want = CosineRayFraction(300, [&](const glm::dvec3& w) {
        if (w.z > 0.0) {  // the panel
          const glm::dvec3 q = p + ((h - p.z) / w.z) * w;
          if (q.x >= -length && q.x <= 0.0 && std::fabs(q.y) <= half) return true;
        }
        const double wn = glm::dot(w, glm::dvec3(nb));
        if (wn != 0.0) {  // the second sheet
          const double t = glm::dot(glm::dvec3(crease) - p, glm::dvec3(nb)) / wn;
          const glm::dvec3 q = p + t * w - glm::dvec3(crease);
          const double u = glm::dot(q, glm::dvec3(du));
          if (t > 0.0 && u >= 0.0 && u <= fall && std::fabs(q.y) <= half) return true;
        }
        return false;
      });
      for (uint32_t k = 0; k < 12; ++k) {
        // The part and the receiver move together: other cuts of them by the same cells.
        const glm::vec3 move(testing_raster::Hash01(k * 977u + 1u) * 3.0f * pitch,
                             testing_raster::Hash01(k * 331u + 7u) * 3.0f * pitch,
                             testing_raster::Hash01(k * 613u + 3u) * 3.0f * pitch);
        std::vector<Surfel> moved = part;
        for (Surfel& s : moved) s.position += move;
        const double got = MustShade(InLeafCells(moved, cell), glm::vec3(p) + move,
                                     Options(Footprint::kPolygons, HitSides::kFront), 2)
                               .occlusion;
        worst = std::max(worst, std::fabs(got - want));
        sum += std::fabs(got - want);
        ++n;
      }
    }
  }
  EXPECT_LT(sum / n, 0.03);
  RecordProperty("worst_abs_error", std::to_string(worst));
  RecordProperty("mean_abs_error", std::to_string(sum / n));
}

// Something more in front of a sheet never shows less of it. A small crumpled two-sided bit (a
// curved porous cluster, drawn as its box at an even opacity) just under a two-sided ceiling
// came first in the pixels over it and opened their layer without a coverage mask; the
// ceiling's pieces, which tile those pixels, then came as leaves beside a layer without
// masks, each filling what the others left at independent places, 1 - (1 - a)(1 - b)...: the
// ceiling leaked where the bit lay (CesiumMilkTruck: 0.65 for rays' 1 in pixels of a receiver's
// zenith; bug: a_translucent_bit_makes_a_sheet_a_leaf). A piece with a mask now takes such a
// layer over: the bit's coverage closes as a leaf's, and the sheet's pieces tile after it.
// Four bits under a ceiling 3 wide, 0.2 over the receiver (form factor 0.9857, 0.9793 drawn
// alone): 0.9745 before, as much as alone now.
TEST(TwoSidedTest, ABitUnderASheetDoesNotOpenIt) {
  const float pitch = 0.02f, cell = 2.1f * pitch, h = 0.2f;
  std::vector<Surfel> ceiling = testing_raster::SquareSurfels(1.5f, h, pitch);
  for (Surfel& s : ceiling) s.two_sided = true;
  Gathered g = InLeafCells(ceiling, cell);
  const double alone =
      MustShade(g, glm::vec3(0.0f), Options(Footprint::kPolygons, HitSides::kFront)).occlusion;
  for (const glm::vec2 at : {glm::vec2(0.0f, 0.0f), glm::vec2(0.06f, -0.04f),
                             glm::vec2(-0.08f, 0.05f), glm::vec2(0.03f, 0.09f)}) {
    std::vector<Surfel> bit;
    for (int i = 0; i < 24; ++i) {
      Surfel s;
      const uint32_t key = 977u * static_cast<uint32_t>(i) + 13u;
      s.position = glm::vec3(at.x + 0.012f * (testing_raster::Hash01(key) - 0.5f),
                             at.y + 0.012f * (testing_raster::Hash01(key ^ 0x5bd1e995u) - 0.5f),
                             h - 0.004f - 0.006f * testing_raster::Hash01(key ^ 0x27d4eb2fu));
      s.normal = glm::normalize(glm::vec3(testing_raster::Hash01(key ^ 0x165667b1u) - 0.5f,
                                          testing_raster::Hash01(key ^ 0x85ebca6bu) - 0.5f,
                                          testing_raster::Hash01(key ^ 0xc2b2ae35u) - 0.5f));
      s.radius = 0.002f;
      s.two_sided = true;
      bit.push_back(s);
    }
    Cluster c = testing_raster::Aggregate(bit);
    c.cell.lo = glm::floor(c.bounds.lo / 0.02f) * 0.02f;
    c.cell.hi = c.cell.lo + 0.02f;
    g.clusters.push_back(c);
  }
  const double got =
      MustShade(g, glm::vec3(0.0f), Options(Footprint::kPolygons, HitSides::kFront)).occlusion;
  EXPECT_GE(got, alone - 0.001);
  EXPECT_NEAR(got, RectangleFormFactor(-1.5, 1.5, -1.5, 1.5, h), 0.01);
  RecordProperty("alone", std::to_string(alone));
  RecordProperty("with_bits", std::to_string(got));
}

}  // namespace
}  // namespace pbgi
