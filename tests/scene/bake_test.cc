// Direct light baked into surfels: exact answers for the sun and the sky, shadows, and a closed
// box that only its interior light reaches.
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

}  // namespace
}  // namespace pbgi
