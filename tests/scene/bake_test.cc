// Direct light baked into surfels: exact answers for the sun and the sky, shadows, and a closed
// box that only its interior light reaches.
#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/scene.h"

namespace pbgi {
namespace {

std::vector<Surfel> Sample(const Scene& scene, int64_t count, uint64_t seed = 1) {
  SamplerOptions o;
  o.count = count;
  o.seed = seed;
  // The roof below is a floating one-sided sheet: with drop_hidden the ground under it would
  // count as the inside of a solid. These tests are about the baking, so keep every sample.
  o.drop_hidden = false;
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(scene), o);
  EXPECT_TRUE(source.ok()) << source.status();
  if (!source.ok()) return {};
  std::vector<Surfel> out(static_cast<size_t>(count));
  auto n = (*source)->Next(absl::MakeSpan(out));
  EXPECT_TRUE(n.ok());
  out.resize(n.ok() ? *n : 0);
  return out;
}

// A quad [0,1]^2 in the plane z = 0 turned by `xf`, facing its +z.
Scene Quad(const glm::mat4& xf, glm::vec3 albedo) {
  Scene s;
  s.name = "quad";
  s.materials.push_back({albedo, glm::vec3(0.0f)});
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  m.materials = {0, 0};
  s.meshes.push_back(m);
  s.instances.push_back({0, xf, -1});
  return s;
}

TEST(BakeTest, SurfelFacingTheSunGetsAlbedoTimesSunTimesCos) {
  // Tilt the quad by 35 degrees about x; the sun comes from another direction.
  glm::mat4 xf(1.0f);
  const float a = 35.0f * 3.14159265f / 180.0f;
  xf[1] = glm::vec4(0.0f, std::cos(a), std::sin(a), 0.0f);
  xf[2] = glm::vec4(0.0f, -std::sin(a), std::cos(a), 0.0f);
  const glm::vec3 albedo(0.5f, 0.6f, 0.7f);
  Scene s = Quad(xf, albedo);
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::normalize(glm::vec3(0.2f, -0.5f, 0.8f));
  s.lights.sun.radiance = glm::vec3(3.0f, 2.0f, 1.0f);
  std::vector<Surfel> surfels = Sample(s, 500);
  ASSERT_EQ(surfels.size(), 500u);
  const glm::vec3 n(0.0f, -std::sin(a), std::cos(a));
  const float cosine = glm::dot(n, s.lights.sun.direction);
  ASSERT_GT(cosine, 0.1f);
  for (const Surfel& sf : surfels) {
    ASSERT_NEAR(glm::length(sf.normal - n), 0.0f, 1e-6f);
    for (int c = 0; c < 3; ++c) {
      EXPECT_FLOAT_EQ(sf.radiance[c], albedo[c] * s.lights.sun.radiance[c] * cosine);
    }
  }
}

TEST(BakeTest, SunBehindTheSurfaceGivesNothing) {
  Scene s = Quad(glm::mat4(1.0f), glm::vec3(0.5f));
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::normalize(glm::vec3(0.1f, 0.2f, -1.0f));
  s.lights.sun.radiance = glm::vec3(3.0f);
  for (const Surfel& sf : Sample(s, 100)) EXPECT_EQ(sf.radiance, glm::vec3(0.0f));
}

TEST(BakeTest, OpenSkyGivesAlbedoTimesSky) {
  Scene s = Quad(glm::mat4(1.0f), glm::vec3(0.25f, 0.5f, 1.0f));
  s.lights.sky = glm::vec3(2.0f, 1.0f, 0.5f);
  s.lights.sky_rays = 8;
  for (const Surfel& sf : Sample(s, 200)) {
    EXPECT_FLOAT_EQ(sf.radiance.x, 0.5f);
    EXPECT_FLOAT_EQ(sf.radiance.y, 0.5f);
    EXPECT_FLOAT_EQ(sf.radiance.z, 0.5f);
  }
}

TEST(BakeTest, OccluderCastsAnExactShadow) {
  // Ground [0,1]^2 and a roof [0.25,0.75]^2 at z = 0.5, facing up; the sun overhead.
  Scene s = Quad(glm::mat4(1.0f), glm::vec3(0.5f));
  glm::mat4 roof(1.0f);
  roof[0][0] = roof[1][1] = 0.5f;
  roof[3] = glm::vec4(0.25f, 0.25f, 0.5f, 1.0f);
  s.instances.push_back({0, roof, -1});
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::vec3(0.0f, 0.0f, 1.0f);
  s.lights.sun.radiance = glm::vec3(2.0f);
  int shadowed = 0, lit = 0;
  for (const Surfel& sf : Sample(s, 4000)) {
    if (sf.position.z > 0.25f) {
      EXPECT_FLOAT_EQ(sf.radiance.x, 1.0f);  // the roof itself
      continue;
    }
    const glm::vec3& p = sf.position;
    const float margin = 1e-3f;
    bool under = p.x > 0.25f + margin && p.x < 0.75f - margin && p.y > 0.25f + margin &&
                 p.y < 0.75f - margin;
    bool outside = p.x < 0.25f - margin || p.x > 0.75f + margin || p.y < 0.25f - margin ||
                   p.y > 0.75f + margin;
    if (under) {
      ++shadowed;
      EXPECT_EQ(sf.radiance.x, 0.0f) << p.x << "," << p.y;
    } else if (outside) {
      ++lit;
      EXPECT_FLOAT_EQ(sf.radiance.x, 1.0f) << p.x << "," << p.y;
    }
  }
  // Ground area 1 and roof 0.25 share 4000 surfels: 3200 on the ground, a quarter shadowed.
  EXPECT_NEAR(shadowed, 800, 30);
  EXPECT_NEAR(lit, 2400, 30);
}

TEST(BakeTest, ClosedBoxSeesOnlyItsInteriorLight) {
  auto with = MakeScene("sphere-in-box");
  ASSERT_TRUE(with.ok());
  ASSERT_TRUE(with->lights.has_sun);
  Scene without = *with;
  without.lights.has_sun = false;
  without.lights.sky = glm::vec3(0.0f);
  std::vector<Surfel> a = Sample(*with, 3000), b = Sample(without, 3000);
  ASSERT_EQ(a.size(), b.size());
  int lit_walls = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].position, b[i].position);
    EXPECT_EQ(a[i].radiance, b[i].radiance) << "surfel " << i << " saw the sun or the sky";
    if (glm::length(a[i].position) > 1.0f && a[i].radiance.x > 0.0f) ++lit_walls;
  }
  EXPECT_GT(lit_walls, 2000);  // the walls do see the sphere
  // And with the sphere dark, every wall is black.
  Scene dark = *with;
  dark.materials[1].emission = glm::vec3(0.0f);
  for (const Surfel& s : Sample(dark, 1000)) EXPECT_EQ(s.radiance, glm::vec3(0.0f));
}

TEST(BakeTest, AreaLightMatchesTheSphereFormFactor) {
  auto scene = MakeScene("sphere-in-box");
  ASSERT_TRUE(scene.ok());
  auto tracer = Tracer::Create(*scene);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  // A point on the floor under the sphere (R = 0.5, d = 2): irradiance / pi = Le * (R/d)^2.
  const glm::vec3 p(0.0f, 0.0f, -2.0f), n(0.0f, 0.0f, 1.0f);
  double sum = 0.0;
  const int kKeys = 2000;
  for (int k = 0; k < kKeys; ++k) sum += (*tracer)->DirectLight(p, n, k).x;
  EXPECT_NEAR(sum / kKeys, 0.0625, 0.0625 * 0.03);
  // And the surfel convention: albedo 0.5 times that.
  glm::vec3 l = (*tracer)->SurfaceRadiance(p, n, 0, 3);
  EXPECT_FLOAT_EQ(l.x, 0.5f * (*tracer)->DirectLight(p, n, 3).x);
}

// The cosine-weighted share of the hemisphere over p (normal +z) that the convex polygon
// `v` (in order) covers: the contour integral (1 / 2 pi) sum of the edges' angles times the
// z of their planes' unit normals (Lambert).
double PolygonFormFactor(const glm::dvec3& p, const std::vector<glm::dvec3>& v) {
  double sum = 0.0;
  for (size_t i = 0; i < v.size(); ++i) {
    const glm::dvec3 a = glm::normalize(v[i] - p), b = glm::normalize(v[(i + 1) % v.size()] - p);
    const glm::dvec3 c = glm::cross(a, b);
    sum += std::acos(std::clamp(glm::dot(a, b), -1.0, 1.0)) * c.z / glm::length(c);
  }
  return std::abs(sum) / (2.0 * 3.14159265358979);
}

// The sixteen points of a baking group share one random shift of their light samples, each
// keeps a stratified set of its own: where they share a place (neighbours on a wall's strip),
// their mean is an estimate of 16 times the samples. Before, every point of a group drew the
// same directions and the same points on the lights, so the group's points all made one error,
// which no cluster of them averages away (the city's irradiance: a wall 3.5 away seen at 0.088
// where rays see 0.03, a receiver +0.07 of 0.29).
double GroupErrorRatio(const Tracer& tracer, const glm::vec3& p, const glm::vec3& n, double exact,
                       double* mean_single) {
  constexpr int kKeys = 400, kP = Tracer::kGroup;
  const std::vector<glm::vec3> ps(kP, p), ns(kP, n);
  const std::vector<uint32_t> materials(kP, 0);
  std::vector<glm::vec3> out(kP);
  double single2 = 0.0, group2 = 0.0, single = 0.0;
  for (int k = 0; k < kKeys; ++k) {
    tracer.SurfaceRadiance(ps, ns, materials, static_cast<uint64_t>(k) + 17, absl::MakeSpan(out));
    double mean = 0.0;
    for (const glm::vec3& l : out) mean += l.x / kP;
    for (const glm::vec3& l : out) single += l.x / (kKeys * kP);
    single2 += (out[3].x - exact) * (out[3].x - exact) / kKeys;
    group2 += (mean - exact) * (mean - exact) / kKeys;
  }
  *mean_single = single;
  return std::sqrt(group2 / single2);
}

// The back of a thin sheet is a surface of its own, lit from its side: the reference's rays
// that meet it see albedo * DirectLight(p, -n). Before, every back side was 0, so a receiver
// under a card lit from below saw nothing; the inside of a solid stays dark.
TEST(ReferenceTest, AThinSheetsBackIsLitFromItsOwnSide) {
  // The unit quad at z = 0 facing +z (Quad), thin, albedo 0.5; the sun straight below.
  Scene s = Quad(glm::mat4(1.0f), glm::vec3(0.5f));
  s.materials[0].thin = true;
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::vec3(0.0f, 0.0f, -1.0f);
  s.lights.sun.radiance = glm::vec3(2.0f);
  // A receiver 0.3 under the quad's centre, facing up at its back side. The quad does not shade
  // its own back from the sun: the sheet's back radiance is 0.5 * 2 = 1.
  const glm::dvec3 p(0.5, 0.5, -0.3);
  const double f = PolygonFormFactor(glm::dvec3(0.5, 0.5, 0.3),
                                     {{0, 0, 0.6}, {1, 0, 0.6}, {1, 1, 0.6}, {0, 1, 0.6}});
  auto tracer = Tracer::Create(s);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  const glm::vec3 e =
      (*tracer)->ReferenceIrradiance(glm::vec3(p), glm::vec3(0.0f, 0.0f, 1.0f), 16384, 5);
  EXPECT_NEAR(e.x, 3.14159265 * 1.0 * f, 0.01 * 3.14159265 * f);
  // Not thin: the back is the inside of a solid, dark.
  s.materials[0].thin = false;
  auto solid = Tracer::Create(s);
  ASSERT_TRUE(solid.ok());
  EXPECT_EQ((*solid)->ReferenceIrradiance(glm::vec3(p), glm::vec3(0.0f, 0.0f, 1.0f), 4096, 5).x,
            0.0f);
}

// A thin sheet's surfels are two-sided, and each side is baked with its own light
// (Surfel::back_radiance), as the reference shades it: the unit quad facing +z with the sun
// below it at 36.87 degrees from the axis (cos 0.8) lights its back, albedo * sun * 0.8, and
// not its front; an emission shows on the front only. A one-sided quad's back is not baked.
TEST(BakeTest, AThinSheetsBackIsBakedFromItsOwnSide) {
  const glm::vec3 albedo(0.5f, 0.25f, 1.0f), emission(0.125f, 0.0f, 0.0f);
  Scene s = Quad(glm::mat4(1.0f), albedo);
  s.materials[0].emission = emission;
  s.materials[0].thin = true;
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::vec3(0.6f, 0.0f, -0.8f);
  s.lights.sun.radiance = glm::vec3(2.0f);
  const std::vector<Surfel> surfels = Sample(s, 256);
  ASSERT_EQ(surfels.size(), 256u);
  for (const Surfel& sf : surfels) {
    ASSERT_TRUE(sf.two_sided);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(sf.radiance[c], emission[c], 1e-5f) << c;
      EXPECT_NEAR(sf.back_radiance[c], albedo[c] * 2.0f * 0.8f, 1e-4f) << c;
    }
  }
  // The sun above: the front is lit, the back is dark.
  s.lights.sun.direction = glm::vec3(0.6f, 0.0f, 0.8f);
  for (const Surfel& sf : Sample(s, 64)) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(sf.radiance[c], albedo[c] * 2.0f * 0.8f + emission[c], 1e-4f) << c;
      EXPECT_EQ(sf.back_radiance[c], 0.0f) << c;
    }
  }
  s.materials[0].thin = false;
  for (const Surfel& sf : Sample(s, 64)) {
    EXPECT_FALSE(sf.two_sided);
    EXPECT_EQ(sf.back_radiance, glm::vec3(0.0f));
  }
}

TEST(BakeTest, AGroupsPointsDrawTheirOwnSkySamples) {
  // A ground point under a square roof [-0.5, 0.5]^2 at height 0.4; a sky of radiance 1 and
  // albedo 1: the radiance is the cosine-weighted open share of the sky.
  glm::mat4 roof(1.0f);
  roof[3] = glm::vec4(-0.5f, -0.5f, 0.4f, 1.0f);
  Scene s = Quad(roof, glm::vec3(1.0f));
  s.lights.sky = glm::vec3(1.0f);
  s.lights.sky_rays = 4;
  auto tracer = Tracer::Create(s);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  const double exact =
      1.0 -
      PolygonFormFactor(glm::dvec3(0.1, 0.05, 0.0),
                        {{-0.5, -0.5, 0.4}, {0.5, -0.5, 0.4}, {0.5, 0.5, 0.4}, {-0.5, 0.5, 0.4}});
  ASSERT_GT(exact, 0.2);
  ASSERT_LT(exact, 0.8);
  double mean = 0.0;
  const double ratio = GroupErrorRatio(**tracer, glm::vec3(0.1f, 0.05f, 0.0f),
                                       glm::vec3(0.0f, 0.0f, 1.0f), exact, &mean);
  EXPECT_NEAR(mean, exact, 0.01);  // unbiased
  EXPECT_LT(ratio, 0.25) << "the group's mean errs as much as one point: shared samples";
}

TEST(BakeTest, AGroupsPointsDrawTheirOwnPointsOnTheLights) {
  auto scene = MakeScene("sphere-in-box");
  ASSERT_TRUE(scene.ok());
  scene->materials[0].albedo = glm::vec3(1.0f);
  auto tracer = Tracer::Create(*scene);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  // The floor under the sphere (R = 0.5, d = 2): Le (R / d)^2 = 0.0625, see above.
  double mean = 0.0;
  const double ratio = GroupErrorRatio(**tracer, glm::vec3(0.0f, 0.0f, -2.0f),
                                       glm::vec3(0.0f, 0.0f, 1.0f), 0.0625, &mean);
  EXPECT_NEAR(mean, 0.0625, 0.0625 * 0.03);
  EXPECT_LT(ratio, 0.25) << "the group's mean errs as much as one point: shared light samples";
}

}  // namespace
}  // namespace pbgi
