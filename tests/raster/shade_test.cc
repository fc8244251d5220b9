// Shade() against analytic answers: form factors of disks, closed spheres, planes, emitters.
#include <cmath>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "tests/raster/scenes.h"

namespace pbgi {
namespace {

using testing_raster::Aggregate;
using testing_raster::Clusters;
using testing_raster::DiskSurfels;
using testing_raster::kPi;
using testing_raster::Rotation;
using testing_raster::SphereSurfels;
using testing_raster::Transform;

// Form factor of a disk of radius r seen on its axis from distance h.
double DiskFormFactor(double r, double h) { return r * r / (h * h + r * r); }

ShadeResult MustShade(const Gathered& g, const ShadeReceiver& r, const RasterOptions& o,
                      MicroBuffer* mb) {
  ShadeResult out;
  absl::Status s = Shade(g, r, o, mb, &out);
  EXPECT_TRUE(s.ok()) << s;
  return out;
}

ShadeReceiver Up(const glm::vec3& p = glm::vec3(0.0f)) {
  ShadeReceiver r;
  r.position = p;
  r.normal = glm::vec3(0, 0, 1);
  return r;
}

// A disk of radius 1 facing down at height h above the origin.
std::vector<Surfel> DiskAbove(float h, float radius = 1.0f, float pitch = 0.02f,
                              glm::vec3 radiance = glm::vec3(0.0f)) {
  return DiskSurfels(glm::vec3(0, 0, h), glm::vec3(0, 0, -1), radius, pitch, radiance);
}

void ExpectFinite(const ShadeResult& r) {
  EXPECT_TRUE(std::isfinite(r.occlusion));
  EXPECT_TRUE(std::isfinite(r.coverage));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(std::isfinite(r.irradiance[i]));
    EXPECT_TRUE(std::isfinite(r.glossy[i]));
  }
  EXPECT_GE(r.occlusion, 0.0f);
  EXPECT_LE(r.occlusion, 1.0f);
}

TEST(ShadeTest, EmptyInputGivesZero) {
  Gathered g;
  MicroBuffer mb;
  RasterOptions o;
  o.lobe = GlossyLobe::kPhong;
  const ShadeResult r = MustShade(g, Up(), o, &mb);
  EXPECT_EQ(r.occlusion, 0.0f);
  EXPECT_EQ(r.coverage, 0.0f);
  EXPECT_EQ(r.irradiance, glm::vec3(0.0f));
  EXPECT_EQ(r.glossy, glm::vec3(0.0f));
  EXPECT_EQ(r.clusters_drawn + r.surfels_drawn + r.near_disks_drawn + r.culled, 0u);
}

// Fine cut: every surfel of the disk.
TEST(ShadeTest, DiskOnAxisFineCutMatchesFormFactor) {
  MicroBuffer mb;
  for (int res : {12, 13, 16, 32}) {  // 13: odd, the side faces' middle row straddles
    for (float h : {0.5f, 1.0f, 2.0f}) {
      Gathered g;
      g.surfels = DiskAbove(h);
      RasterOptions o;
      o.resolution = res;
      o.compute_radiance = false;
      const ShadeResult r = MustShade(g, Up(), o, &mb);
      const double want = DiskFormFactor(1.0, h);
      EXPECT_NEAR(r.occlusion, want, 0.01 * want) << "res " << res << " h " << h;
      EXPECT_EQ(r.surfels_drawn, g.surfels.size());
    }
  }
}

// Default cut: clusters aggregated from tiles of the disk, each below the query's default
// max_solid_angle (0.03 sr).
TEST(ShadeTest, DiskOnAxisClustersMatchFormFactor) {
  MicroBuffer mb;
  for (float h : {0.5f, 1.0f, 2.0f}) {
    Gathered g;
    g.clusters = Clusters(DiskAbove(h), 0.15f * h);
    double max_omega = 0.0;
    for (const Cluster& c : g.clusters) {
      const glm::vec3 rel = c.bounds.Center();
      max_omega = std::max(max_omega, static_cast<double>(c.area / glm::dot(rel, rel)));
    }
    ASSERT_LE(max_omega, 0.03);
    ASSERT_GE(max_omega, 0.01);
    RasterOptions o;
    o.compute_radiance = false;
    const ShadeResult r = MustShade(g, Up(), o, &mb);
    const double want = DiskFormFactor(1.0, h);
    EXPECT_NEAR(r.occlusion, want, 0.03 * want) << "h " << h;
    EXPECT_EQ(r.clusters_drawn, g.clusters.size());
  }
}

// Mixed: surfels near the axis, clusters farther out, as a real cut produces.
TEST(ShadeTest, DiskMixedCutMatchesFormFactor) {
  const std::vector<Surfel> disk = DiskAbove(1.0f);
  std::vector<Surfel> inner, outer;
  for (const Surfel& s : disk) {
    (glm::length(glm::vec2(s.position)) < 0.4f ? inner : outer).push_back(s);
  }
  Gathered g;
  g.surfels = inner;
  g.clusters = Clusters(outer, 0.15f);
  MicroBuffer mb;
  const ShadeResult r = MustShade(g, Up(), RasterOptions{}, &mb);
  EXPECT_NEAR(r.occlusion, 0.5, 0.015);
}

TEST(ShadeTest, ClosedSphereFullyOccludes) {
  MicroBuffer mb;
  RasterOptions o;
  o.compute_radiance = false;
  // Inward normals: the receiver sees their fronts.
  Gathered in;
  in.surfels = SphereSurfels(glm::vec3(0), 1.0f, 20000, /*inward=*/true);
  for (glm::vec3 p : {glm::vec3(0.0f), glm::vec3(0.3f, -0.2f, 0.4f)}) {
    EXPECT_NEAR(MustShade(in, Up(p), o, &mb).occlusion, 1.0, 0.02);
  }
  Gathered cl;
  cl.clusters = Clusters(in.surfels, 0.2f);
  EXPECT_NEAR(MustShade(cl, Up(), o, &mb).occlusion, 1.0, 0.03);
  // Outward normals: the receiver inside sees only backs.
  Gathered out;
  out.surfels = SphereSurfels(glm::vec3(0), 1.0f, 20000, /*inward=*/false);
  EXPECT_EQ(MustShade(out, Up(), o, &mb).occlusion, 0.0f);
  o.hitsides = HitSides::kBack;
  EXPECT_NEAR(MustShade(out, Up(), o, &mb).occlusion, 1.0, 0.02);
  o.hitsides = HitSides::kBoth;
  EXPECT_NEAR(MustShade(out, Up(), o, &mb).occlusion, 1.0, 0.02);
}

// A disk of clusters facing away from the receiver: invisible from the front only, and the
// same form factor as a facing one from the back or both sides.
TEST(ShadeTest, HitSidesOnClusters) {
  Gathered g;
  g.clusters = Clusters(DiskSurfels(glm::vec3(0, 0, 1), glm::vec3(0, 0, 1), 1.0f, 0.02f), 0.15f);
  MicroBuffer mb;
  RasterOptions o;
  o.compute_radiance = false;
  EXPECT_LT(MustShade(g, Up(), o, &mb).occlusion, 1e-6f);  // float rounding of E - |N.w|
  o.hitsides = HitSides::kBack;
  EXPECT_NEAR(MustShade(g, Up(), o, &mb).occlusion, 0.5, 0.015);
  o.hitsides = HitSides::kBoth;
  EXPECT_NEAR(MustShade(g, Up(), o, &mb).occlusion, 0.5, 0.015);
}

// A closed unit box of emitting walls (inward normals) seen from its floor, with a mixed cut:
// surfels within 0.15 of the receiver, clusters of 0.1 cells beyond. Everything is covered
// once: occlusion 1 and irradiance pi L.
TEST(ShadeTest, ClosedBoxMixedCut) {
  std::vector<Surfel> walls;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side : {0, 1}) {
      glm::vec3 n(0.0f), c(0.5f);
      n[axis] = side ? -1.0f : 1.0f;
      c[axis] = static_cast<float>(side);
      glm::vec3 t, b;
      testing_raster::Basis(n, &t, &b);
      const float pitch = 0.02f;
      for (int j = 0; j < 50; ++j) {
        for (int i = 0; i < 50; ++i) {
          Surfel s;
          s.position = c + (-0.5f + (i + 0.5f) * pitch) * t + (-0.5f + (j + 0.5f) * pitch) * b;
          s.normal = n;
          s.radius = pitch / std::sqrt(static_cast<float>(kPi));
          s.radiance = glm::vec3(1.0f, 0.5f, 0.25f);
          walls.push_back(s);
        }
      }
    }
  }
  MicroBuffer mb;
  RasterOptions o;
  o.bias = 1e-4f;
  for (glm::vec3 p : {glm::vec3(0.5f, 0.5f, 0.0f), glm::vec3(0.1f, 0.2f, 0.0f)}) {
    Gathered g;
    std::vector<Surfel> far;
    for (const Surfel& s : walls) {
      (glm::length(s.position - p) < 0.15f ? g.surfels : far).push_back(s);
    }
    g.clusters = Clusters(far, 0.1f);
    const ShadeResult r = MustShade(g, Up(p), o, &mb);
    EXPECT_NEAR(r.occlusion, 1.0, 0.01);
    EXPECT_NEAR(r.irradiance.x, kPi, 0.015 * kPi);
    EXPECT_NEAR(r.irradiance.z, 0.25 * kPi, 0.015 * 0.25 * kPi);
  }
}

TEST(ShadeTest, FlatPlaneDoesNotOccludeReceiverOnIt) {
  MicroBuffer mb;
  RasterOptions o;
  const std::vector<Surfel> plane =
      DiskSurfels(glm::vec3(0), glm::vec3(0, 0, 1), 3.0f, 0.05f, glm::vec3(1.0f));
  Gathered g;
  g.surfels = plane;
  // The receiver sits exactly on a surfel of the plane (and between surfels).
  for (glm::vec3 p : {plane[plane.size() / 2].position, glm::vec3(0.0f)}) {
    const ShadeResult r = MustShade(g, Up(p), o, &mb);
    EXPECT_EQ(r.occlusion, 0.0f);
    EXPECT_EQ(r.irradiance, glm::vec3(0.0f));
  }
  Gathered c;
  c.clusters = Clusters(plane, 0.5f);
  EXPECT_EQ(MustShade(c, Up(), o, &mb).occlusion, 0.0f);
  // Rotated off the axes, positions and normals carry rounding noise out of the plane.
  const glm::mat3 rot = Rotation(glm::vec3(1, 2, 3), 0.7f);
  Gathered gr;
  gr.surfels = Transform(plane, rot, 1.0f, glm::vec3(0.0f));
  gr.clusters = Clusters(Transform(plane, rot, 1.0f, glm::vec3(5.0f, 0, 0)), 0.5f);
  ShadeReceiver rr;
  rr.position = gr.surfels[plane.size() / 2].position;
  rr.normal = rot * glm::vec3(0, 0, 1);
  EXPECT_LT(MustShade(gr, rr, o, &mb).occlusion, 1e-3f);
}

// Occlusion of the disk scene after a similarity transform of scene and receiver.
double TransformedDisk(const glm::mat3& rot, float scale, const glm::vec3& shift, bool clusters) {
  const std::vector<Surfel> disk = Transform(DiskAbove(1.0f), rot, scale, shift);
  Gathered g;
  if (clusters) {
    // Group in the untransformed frame so that the grouping is the same.
    const std::vector<Surfel> base = DiskAbove(1.0f);
    std::map<std::pair<int, int>, std::vector<Surfel>> groups;
    for (size_t i = 0; i < base.size(); ++i) {
      groups[{static_cast<int>(std::floor(base[i].position.x / 0.15f)),
              static_cast<int>(std::floor(base[i].position.y / 0.15f))}]
          .push_back(disk[i]);
    }
    for (const auto& [key, group] : groups) g.clusters.push_back(Aggregate(group));
  } else {
    g.surfels = disk;
  }
  ShadeReceiver r;
  r.position = shift;
  r.normal = rot * glm::vec3(0, 0, 1);
  MicroBuffer mb;
  RasterOptions o;
  return MustShade(g, r, o, &mb).occlusion;
}

TEST(ShadeTest, InvariantUnderTranslationScaleRotation) {
  const glm::mat3 id(1.0f);
  for (bool clusters : {false, true}) {
    const double base = TransformedDisk(id, 1.0f, glm::vec3(0.0f), clusters);
    EXPECT_NEAR(base, 0.5, 0.015);
    EXPECT_NEAR(TransformedDisk(id, 1.0f, glm::vec3(1e5f, -1e5f, 1e5f), clusters), base, 0.005);
    EXPECT_NEAR(TransformedDisk(id, 1e-3f, glm::vec3(0.0f), clusters), base, 1e-4);
    EXPECT_NEAR(TransformedDisk(id, 1e3f, glm::vec3(0.0f), clusters), base, 1e-4);
    for (float angle : {0.3f, 1.1f, 2.5f}) {
      const glm::mat3 rot = Rotation(glm::vec3(0.2f, -1.0f, 0.5f), angle);
      EXPECT_NEAR(TransformedDisk(rot, 1.0f, glm::vec3(0.0f), clusters), base, 0.01)
          << "angle " << angle;
    }
  }
}

TEST(ShadeTest, NoNanOrInfInDegenerateConfigurations) {
  MicroBuffer mb;
  RasterOptions o;
  o.lobe = GlossyLobe::kGgx;
  Surfel s;
  s.radius = 0.1f;
  s.radiance = glm::vec3(1.0f);
  Gathered g;
  // A surfel exactly at the receiver, in every orientation; a zero-radius one; one at the
  // horizon; a cluster centred on the receiver and one whose box contains it.
  for (glm::vec3 n : {glm::vec3(0, 0, 1), glm::vec3(0, 0, -1), glm::vec3(1, 0, 0),
                      glm::normalize(glm::vec3(1, 1, 1))}) {
    s.position = glm::vec3(0.0f);
    s.normal = n;
    g.surfels.push_back(s);
  }
  Surfel zero = s;
  zero.radius = 0.0f;
  zero.position = glm::vec3(0.5f, 0, 0.5f);
  g.surfels.push_back(zero);
  Surfel horizon = s;
  horizon.position = glm::vec3(2.0f, 0, 0);
  horizon.normal = glm::vec3(-1, 0, 0);
  g.surfels.push_back(horizon);
  std::vector<Surfel> blob = SphereSurfels(glm::vec3(0.0f), 0.05f, 50, false, glm::vec3(1.0f));
  g.clusters.push_back(Aggregate(blob));
  blob = SphereSurfels(glm::vec3(0.01f, 0, 0.01f), 0.5f, 50, false, glm::vec3(1.0f));
  g.clusters.push_back(Aggregate(blob));
  for (HitSides sides : {HitSides::kFront, HitSides::kBack, HitSides::kBoth}) {
    o.hitsides = sides;
    for (glm::vec3 n : {glm::vec3(0, 0, 1), glm::vec3(1, 0, 0), glm::vec3(0, 0, -1),
                        glm::vec3(1e-20f, 0, 1e-20f)}) {
      ShadeReceiver r;
      r.normal = n;
      r.reflection = glm::vec3(1, 0, 0);
      const ShadeResult out = MustShade(g, r, o, &mb);
      ExpectFinite(out);
    }
  }
  // Grazing: a disk edge-on to the receiver, exactly in its tangent plane and just above it.
  for (float z : {0.0f, 1e-6f, 1e-3f}) {
    Gathered edge;
    edge.surfels =
        DiskSurfels(glm::vec3(3, 0, z), glm::vec3(0, 0, 1), 1.0f, 0.05f, glm::vec3(1.0f));
    edge.clusters = Clusters(edge.surfels, 0.3f);
    const ShadeResult out = MustShade(edge, Up(), o, &mb);
    ExpectFinite(out);
    EXPECT_LT(out.occlusion, 0.01f);
  }
}

// The exact-disk path, alone: one big surfel near the receiver.
TEST(ShadeTest, ExactDiskPathDrawsTheDiskSolidAngle) {
  MicroBuffer mb;
  for (int res : {4, 12, 32}) {
    for (float h : {0.5f, 1.0f, 3.0f}) {
      Gathered g;
      Surfel s;
      s.position = glm::vec3(0, 0, h);
      s.normal = glm::vec3(0, 0, -1);
      s.radius = 1.0f;
      g.surfels.push_back(s);
      RasterOptions o;
      o.resolution = res;
      o.near_field_factor = 10.0f;
      o.near_field_samples = 8;
      const ShadeResult r = MustShade(g, Up(), o, &mb);
      ASSERT_EQ(r.near_disks_drawn, 1u);
      ASSERT_EQ(r.surfels_drawn, 0u);
      const double omega = 2.0 * kPi * (1.0 - h / std::sqrt(h * h + 1.0));
      EXPECT_GT(r.coverage, 0.0f);
      EXPECT_NEAR(r.coverage * 2.0 * kPi, omega, 0.02 * omega) << "res " << res << " h " << h;
      // At res 4 a pixel spans ~30 degrees: its single cosine weight is too coarse for 2%.
      if (res >= 12) {
        EXPECT_NEAR(r.occlusion, DiskFormFactor(1.0, h), 0.02 * DiskFormFactor(1.0, h))
            << "res " << res << " h " << h;
      }
      // The pixels agree with the total: sum of coverage * solid angle over the cube.
      double sum = 0.0;
      for (int p = 0; p < mb.pixel_count(); ++p) sum += mb.PixelCoverage(p) * mb.PixelSolidAngle(p);
      EXPECT_NEAR(sum, omega, 0.02 * omega);
    }
  }
  // The far path on the same disk uses the cone of solid angle A cos / d^2 instead, which is
  // far from the truth this close: proof that the exact path above is what drew.
  Gathered g;
  Surfel s;
  s.position = glm::vec3(0, 0, 1);
  s.normal = glm::vec3(0, 0, -1);
  s.radius = 1.0f;
  g.surfels.push_back(s);
  RasterOptions far;
  far.near_field_factor = 0.0f;
  const ShadeResult r = MustShade(g, Up(), far, &mb);
  EXPECT_EQ(r.near_disks_drawn, 0u);
  EXPECT_EQ(r.surfels_drawn, 1u);
  EXPECT_NEAR(r.coverage * 2.0 * kPi, kPi, 0.02 * kPi);
}

// A disk crossing the horizon: only its part above the tangent plane counts.
TEST(ShadeTest, ExactDiskCrossingTheHorizon) {
  MicroBuffer mb;
  Gathered g;
  Surfel s;
  s.position = glm::vec3(1, 0, 0);  // centred on the horizon, facing the receiver
  s.normal = glm::vec3(-1, 0, 0);
  s.radius = 1.0f;
  g.surfels.push_back(s);
  RasterOptions o;
  o.near_field_samples = 8;
  o.resolution = 16;
  const ShadeResult r = MustShade(g, Up(), o, &mb);
  ASSERT_EQ(r.near_disks_drawn, 1u);
  // Half of the disk's solid angle 2 pi (1 - 1/sqrt 2) lies above the horizon.
  const double half = kPi * (1.0 - 1.0 / std::sqrt(2.0));
  EXPECT_NEAR(r.coverage * 2.0 * kPi, half, 0.03 * half);
}

TEST(ShadeTest, UniformEmittingSphereGivesPiLAndGlossyL) {
  const glm::vec3 radiance(1.0f, 0.5f, 0.25f);
  Gathered g;
  g.surfels = SphereSurfels(glm::vec3(0), 1.0f, 20000, true, radiance);
  MicroBuffer mb;
  for (GlossyLobe lobe : {GlossyLobe::kPhong, GlossyLobe::kGgx}) {
    RasterOptions o;
    o.lobe = lobe;
    ShadeReceiver r = Up();
    r.reflection = glm::normalize(glm::vec3(1, 0, 1));
    const ShadeResult out = MustShade(g, r, o, &mb);
    for (int ch = 0; ch < 3; ++ch) {
      EXPECT_NEAR(out.irradiance[ch], kPi * radiance[ch], 0.02 * kPi * radiance[ch]);
      EXPECT_NEAR(out.glossy[ch], radiance[ch], 0.02 * radiance[ch]);
    }
  }
  // The same from clusters: radiance = power / area exactly for a uniform emitter.
  Gathered c;
  c.clusters = Clusters(g.surfels, 0.25f);
  const ShadeResult out = MustShade(c, Up(), RasterOptions{}, &mb);
  for (int ch = 0; ch < 3; ++ch) {
    EXPECT_NEAR(out.irradiance[ch], kPi * radiance[ch], 0.03 * kPi * radiance[ch]);
  }
}

// Depth test: a black disk in front of a bright sphere hides exactly its own form factor.
TEST(ShadeTest, NearerElementsHideFartherOnes) {
  Gathered g;
  g.surfels = SphereSurfels(glm::vec3(0), 3.0f, 30000, true, glm::vec3(1.0f));
  const std::vector<Surfel> disk = DiskAbove(1.0f, 1.0f, 0.02f, glm::vec3(0.0f));
  g.surfels.insert(g.surfels.end(), disk.begin(), disk.end());
  MicroBuffer mb;
  RasterOptions o;
  const ShadeResult out = MustShade(g, Up(), o, &mb);
  EXPECT_NEAR(out.occlusion, 1.0, 0.02);
  EXPECT_NEAR(out.irradiance.x, kPi * (1.0 - 0.5), 0.02 * kPi);
  // The same with the disk given as clusters, listed before the sphere.
  Gathered c;
  c.clusters = Clusters(disk, 0.15f);
  c.surfels = SphereSurfels(glm::vec3(0), 3.0f, 30000, true, glm::vec3(1.0f));
  const ShadeResult oc = MustShade(c, Up(), o, &mb);
  EXPECT_NEAR(oc.irradiance.x, kPi * (1.0 - 0.5), 0.03 * kPi);
}

TEST(ShadeTest, GlossyLobeTowardAnEmitterSeesMoreThanAway) {
  const glm::vec3 dir = glm::normalize(glm::vec3(1, 0, 1));
  Gathered g;
  g.surfels = DiskSurfels(3.0f * dir, -dir, 0.5f, 0.02f, glm::vec3(2.0f));
  MicroBuffer mb;
  for (GlossyLobe lobe : {GlossyLobe::kPhong, GlossyLobe::kGgx}) {
    RasterOptions o;
    o.lobe = lobe;
    ShadeReceiver toward = Up(), away = Up();
    toward.reflection = dir;
    away.reflection = glm::vec3(-dir.x, dir.y, dir.z);
    const float a = MustShade(g, toward, o, &mb).glossy.x;
    const float b = MustShade(g, away, o, &mb).glossy.x;
    EXPECT_GT(a, 0.1f);
    EXPECT_GT(a, 10.0f * b);
  }
}

// A disk behind another (twice as far, so their depth ranges in a pixel do not overlap): with
// clamp the nearer one hides the farther one; without it their coverages add up.
TEST(ShadeTest, ClampSaturatesOverlappingLayers) {
  Gathered g;
  g.surfels = DiskAbove(1.0f);
  const std::vector<Surfel> behind = DiskAbove(2.0f);
  g.surfels.insert(g.surfels.end(), behind.begin(), behind.end());
  MicroBuffer mb;
  RasterOptions o;
  EXPECT_NEAR(MustShade(g, Up(), o, &mb).occlusion, 0.5, 0.01);
  o.clamp = false;
  EXPECT_NEAR(MustShade(g, Up(), o, &mb).occlusion, 0.5 + DiskFormFactor(1.0, 2.0), 0.01);
}

// Regression (hidden_surface_overcount): a nearer layer whose splats add up to more than 1 in a
// pixel (here: a black disk given twice, as a surface and a coincident hidden copy, like a
// floor that runs on under a box) kept its full sum even with a surface behind it, so the
// pixel counted more than once. In `pbgi eval cornell` this over-occluded receivers that see
// the floor under the blocks. With something behind, the first layer is now clamped at 1 too.
TEST(ShadeTest, HiddenSurfaceOvercountRegression) {
  // An emitting disk (radiance 1, form factor 0.5) twice over, in front of a black disk of
  // radius 6 at height 3 (form factor 0.8): occlusion 0.8 and irradiance pi * 0.5; before the
  // fix, 1.0 (0.5 + 0.5, then the final clamp) and about 2 pi * 0.5.
  const std::vector<Surfel> front = DiskAbove(1.0f, 1.0f, 0.02f, glm::vec3(1.0f));
  const std::vector<Surfel> back = DiskAbove(3.0f, 6.0f, 0.06f, glm::vec3(0.0f));
  Gathered g;
  g.surfels = front;
  g.surfels.insert(g.surfels.end(), front.begin(), front.end());
  g.surfels.insert(g.surfels.end(), back.begin(), back.end());
  MicroBuffer mb;
  RasterOptions o;
  const ShadeResult out = MustShade(g, Up(), o, &mb);
  // The doubled rim still counts twice in the pixels that it covers partly: about 4% here.
  EXPECT_NEAR(out.occlusion, DiskFormFactor(6.0, 3.0), 0.015);
  EXPECT_NEAR(out.irradiance.x, kPi * 0.5, 0.05 * kPi * 0.5);
  // The same with the front disk as clusters (a cut's view of it).
  Gathered c;
  const std::vector<Cluster> once = Clusters(front, 0.15f);
  c.clusters = once;
  c.clusters.insert(c.clusters.end(), once.begin(), once.end());
  c.surfels = back;
  const ShadeResult oc = MustShade(c, Up(), o, &mb);
  EXPECT_NEAR(oc.occlusion, DiskFormFactor(6.0, 3.0), 0.02);
  EXPECT_NEAR(oc.irradiance.x, kPi * 0.5, 0.08 * kPi * 0.5);
  // With nothing behind it, a layer still adds up freely (its overlaps make up for its gaps):
  // the doubled disk alone gives twice the disk's irradiance.
  Gathered lone;
  lone.surfels = front;
  lone.surfels.insert(lone.surfels.end(), front.begin(), front.end());
  EXPECT_NEAR(MustShade(lone, Up(), o, &mb).irradiance.x, 2.0 * kPi * 0.5, 0.02 * kPi);
}

// Regression (chained_surfaces_overcount): a layer's depth range grew with every fragment that
// overlapped it, so a chain of fragments of different surfaces, each overlapping the previous
// in depth, merged them into one layer that added up. In `pbgi eval cornell` a block's top,
// the clusters on its edges, the floor and the next block chained into one layer of coverage
// 3.3 in some pixels (MAE 0.027 at the default cut, +0.017 mean over-occlusion). Here an
// emitting disk (radius 1, height 1), an emitting wall going up from its rim to height 1.6
// (inward normals, hidden behind the disk) and a black disk of radius 2.4 at height 1.6, all as
// clusters of 0.15 cells (the rim cells hold disk and wall: curved clusters): the union seen
// from below is the big disk, occlusion 2.4^2 / (1.6^2 + 2.4^2), and only the small disk
// shows, irradiance pi * 0.5. Before the fix: occlusion 0.773.
TEST(ShadeTest, ChainedSurfacesOvercountRegression) {
  std::vector<Surfel> surfels = DiskAbove(1.0f, 1.0f, 0.02f, glm::vec3(1.0f));
  const std::vector<Surfel> back = DiskAbove(1.6f, 2.4f, 0.04f);
  surfels.insert(surfels.end(), back.begin(), back.end());
  const float pitch = 0.02f;
  const int around = static_cast<int>(2.0 * kPi / pitch);
  for (int j = 0; j < 30; ++j) {
    for (int i = 0; i < around; ++i) {
      const float phi = 2.0f * static_cast<float>(kPi) * (i + 0.5f) / around;
      const glm::vec3 radial(std::cos(phi), std::sin(phi), 0.0f);
      Surfel s;
      s.position = radial + glm::vec3(0.0f, 0.0f, 1.0f + (j + 0.5f) * pitch);
      s.normal = -radial;
      s.radius = pitch / std::sqrt(static_cast<float>(kPi));
      s.radiance = glm::vec3(1.0f);
      surfels.push_back(s);
    }
  }
  Gathered g;
  g.clusters = Clusters(surfels, 0.15f);
  MicroBuffer mb;
  RasterOptions o;
  const ShadeResult out = MustShade(g, Up(), o, &mb);
  EXPECT_NEAR(out.occlusion, DiskFormFactor(2.4, 1.6), 0.02);
  EXPECT_NEAR(out.irradiance.x, kPi * 0.5, 0.03 * kPi * 0.5);
}

TEST(ShadeTest, MaxDistanceAndBias) {
  Gathered g;
  g.surfels = DiskAbove(1.0f);
  MicroBuffer mb;
  RasterOptions o;
  o.max_distance = 0.9f;
  EXPECT_EQ(MustShade(g, Up(), o, &mb).occlusion, 0.0f);
  o.max_distance = 1.5f;  // the disk's rim is at sqrt(2)
  EXPECT_NEAR(MustShade(g, Up(), o, &mb).occlusion, 0.5, 0.01);
  o.max_distance = 1.2f;  // only the surfels within radius sqrt(1.2^2 - 1)
  EXPECT_NEAR(MustShade(g, Up(), o, &mb).occlusion, DiskFormFactor(std::sqrt(0.44), 1.0), 0.01);
  // Bias moves the receiver up by 0.5: the disk is then at h = 0.5.
  RasterOptions b;
  b.bias = 0.5f;
  EXPECT_NEAR(MustShade(g, Up(), b, &mb).occlusion, 0.8, 0.01);
}

TEST(ShadeTest, RejectsInvalidInput) {
  Gathered g;
  MicroBuffer mb;
  ShadeResult out;
  RasterOptions o;
  o.resolution = 3;
  EXPECT_EQ(Shade(g, Up(), o, &mb, &out).code(), absl::StatusCode::kInvalidArgument);
  o.resolution = 65;
  EXPECT_THAT(Shade(g, Up(), o, &mb, &out).message(), ::testing::HasSubstr("resolution = 65"));
  o = RasterOptions{};
  o.near_field_samples = 0;
  EXPECT_EQ(Shade(g, Up(), o, &mb, &out).code(), absl::StatusCode::kInvalidArgument);
  o = RasterOptions{};
  o.ggx_roughness = 0.0f;
  EXPECT_EQ(Shade(g, Up(), o, &mb, &out).code(), absl::StatusCode::kInvalidArgument);
  ShadeReceiver r = Up();
  r.normal = glm::vec3(0.0f);
  EXPECT_THAT(Shade(g, r, RasterOptions{}, &mb, &out).message(), ::testing::HasSubstr("normal"));
  EXPECT_EQ(Shade(g, Up(), RasterOptions{}, nullptr, &out).code(),
            absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace pbgi
