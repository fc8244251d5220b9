// Tracer::ReferenceGlossy and its lobe sampling against analytic answers and brute-force
// quadrature of the definition in pbgi/raster.h (ShadeResult::glossy).
#include <cmath>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/scene.h"
#include "pbgi/sh.h"
#include "scene/sample_math.h"

namespace pbgi {
namespace {

constexpr double kPi = sh::kPi;

// D(x) of pbgi/raster.h, x = cos(angle to r), written out here independently of the sampler.
double Lobe(const GlossyParams& l, double x) {
  if (!(x > 0.0)) return 0.0;
  if (l.lobe == GlossyLobe::kPhong) return std::pow(x, l.phong_exponent);
  const double a2 = double(l.ggx_roughness) * l.ggx_roughness;
  const double q = (a2 - 1.0) * x * x + 1.0;
  return a2 / (kPi * q * q);
}

// The integral of D over x in [x0, x1] by Simpson's rule (fine enough for alpha >= 0.1).
double LobeIntegral(const GlossyParams& l, double x0, double x1) {
  const int n = 20000;
  const double h = (x1 - x0) / n;
  double s = Lobe(l, x0) + Lobe(l, x1);
  for (int i = 1; i < n; ++i) s += Lobe(l, x0 + i * h) * (i % 2 ? 4.0 : 2.0);
  return s * h / 3.0;
}

GlossyParams Phong(float e) { return {GlossyLobe::kPhong, e, 0.2f}; }
GlossyParams Ggx(float a) { return {GlossyLobe::kGgx, 32.0f, a}; }

TEST(GlossyLobeSamplingTest, InverseCdfsMatchQuadrature) {
  for (const GlossyParams& l :
       {Phong(0), Phong(8), Phong(32), Phong(128), Ggx(0.1f), Ggx(0.3f), Ggx(0.6f), Ggx(1.0f)}) {
    const double total = LobeIntegral(l, 0.0, 1.0);
    double prev = -1.0;
    for (double u = 0.0; u <= 1.0; u += 0.05) {
      const double x = l.lobe == GlossyLobe::kGgx ? internal::GgxLobeCosine(u, l.ggx_roughness)
                                                  : internal::PhongLobeCosine(u, l.phong_exponent);
      ASSERT_GE(x, 0.0);
      ASSERT_LE(x, 1.0);
      EXPECT_GE(x, prev);  // monotone
      prev = x;
      EXPECT_NEAR(LobeIntegral(l, 0.0, x) / total, u, 2e-5)
          << "lobe " << int(l.lobe) << " e " << l.phong_exponent << " alpha " << l.ggx_roughness;
    }
  }
}

// A closed cube [-1, 1]^3 whose faces point inwards and emit `le`, albedo 0.
Scene EmittingBox(glm::vec3 le) {
  Scene s;
  s.name = "emitting-box";
  Mesh m;
  for (int i = 0; i < 8; ++i) {
    m.positions.push_back({i & 1 ? 1.0f : -1.0f, i & 2 ? 1.0f : -1.0f, i & 4 ? 1.0f : -1.0f});
  }
  // Quads (a, b, c, d) wound so that (a, c, b) points into the box.
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.triangles.push_back(glm::uvec3(q[0], q[2], q[1]));
    m.triangles.push_back(glm::uvec3(q[0], q[3], q[2]));
  }
  m.materials.assign(m.triangles.size(), 0);
  s.meshes.push_back(m);
  s.instances.push_back({});
  Material mat;
  mat.albedo = glm::vec3(0.0f);
  mat.emission = le;
  s.materials.push_back(mat);
  return s;
}

TEST(ReferenceGlossyTest, InsideAUniformEmitterIsTheEmittedRadiance) {
  const glm::vec3 le(1.0f, 0.5f, 0.25f);
  Scene box = EmittingBox(le);
  ASSERT_TRUE(box.Validate().ok());
  auto tracer = Tracer::Create(box);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  // Every direction sees a front face of radiance le: any lobe, any reflection (also one whose
  // lobe reaches below the horizon), gives le.
  const glm::vec3 n = glm::normalize(glm::vec3(0.2f, -0.3f, 1.0f));
  for (const GlossyParams& l : {Phong(0), Phong(32), Ggx(0.1f), Ggx(0.3f), Ggx(1.0f)}) {
    for (const glm::vec3& r : {n, glm::normalize(glm::vec3(1.0f, 0.0f, 0.2f)),
                               glm::normalize(glm::vec3(0.0f, 1.0f, -0.1f))}) {
      const glm::vec3 g = (*tracer)->ReferenceGlossy({0.1f, 0.2f, -0.3f}, n, r, l, 256, 3);
      EXPECT_NEAR(g.x, le.x, 1e-5f);
      EXPECT_NEAR(g.y, le.y, 1e-5f);
      EXPECT_NEAR(g.z, le.z, 1e-5f);
    }
  }
  // No reflection direction, no glossy light (as the rasterizer).
  EXPECT_EQ((*tracer)->ReferenceGlossy({0, 0, 0}, n, glm::vec3(0.0f), Phong(8), 64),
            glm::vec3(0.0f));
}

// The disk scene: a receiver at (0, 0, -h) facing +z sees the emitter (radius 1, emission 1)
// within the cone cos(theta) >= h / sqrt(h^2 + 1).
TEST(ReferenceGlossyTest, DiskOnTheLobeAxisIsTheLobeFractionOfTheCone) {
  Scene disk = MakeDiskScene(1.0f, 512);
  auto tracer = Tracer::Create(disk);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  const glm::vec3 n(0.0f, 0.0f, 1.0f);
  for (float h : {0.5f, 1.0f, 2.0f}) {
    const double c0 = h / std::sqrt(h * h + 1.0);
    for (const GlossyParams& l :
         {Phong(8), Phong(32), Phong(128), Ggx(0.1f), Ggx(0.3f), Ggx(0.6f)}) {
      // Phong in closed form, 1 - c0^(e + 1); both lobes by quadrature of the definition.
      const double want = LobeIntegral(l, c0, 1.0) / LobeIntegral(l, 0.0, 1.0);
      if (l.lobe == GlossyLobe::kPhong) {
        ASSERT_NEAR(want, 1.0 - std::pow(c0, l.phong_exponent + 1.0), 1e-6);
      }
      const glm::vec3 g = (*tracer)->ReferenceGlossy({0.0f, 0.0f, -h}, n, n, l, 4096, 11);
      EXPECT_NEAR(g.x, want, 0.01) << "h " << h << " lobe " << int(l.lobe) << " e "
                                   << l.phong_exponent << " alpha " << l.ggx_roughness;
    }
  }
}

// A lobe tilted towards the horizon: only the part above the receiver's tangent plane counts,
// in the numerator and the denominator alike. Brute-force quadrature over the hemisphere.
TEST(ReferenceGlossyTest, ALobeAcrossTheHorizonIsNormalisedOverTheHemisphere) {
  Scene disk = MakeDiskScene(1.0f, 512);
  auto tracer = Tracer::Create(disk);
  ASSERT_TRUE(tracer.ok()) << tracer.status();
  const double h = 0.6;
  const glm::vec3 n(0.0f, 0.0f, 1.0f);
  for (const GlossyParams& l : {Phong(4), Phong(32), Ggx(0.3f), Ggx(0.6f)}) {
    for (double tilt : {0.6, 1.2}) {  // radians from the normal
      const glm::dvec3 r(std::sin(tilt), 0.0, std::cos(tilt));
      double num = 0.0, den = 0.0, whole = 0.0;
      const int nt = 1000, np = 2000;
      for (int i = 0; i < nt; ++i) {
        const double th = (i + 0.5) * (kPi / 2) / nt;
        for (int j = 0; j < np; ++j) {
          const double ph = (j + 0.5) * 2 * kPi / np;
          const glm::dvec3 w(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph),
                             std::cos(th));
          const double d = Lobe(l, glm::dot(w, r)) * std::sin(th);
          den += d;
          const double t = h / w.z;
          if (t * t * (w.x * w.x + w.y * w.y) <= 1.0) num += d;
        }
      }
      // The whole lobe's integral, over r's hemisphere: 2 pi integral_0^1 D(x) dx.
      whole = 2.0 * kPi * LobeIntegral(l, 0.0, 1.0);
      const double want = num / den;
      const glm::vec3 g =
          (*tracer)->ReferenceGlossy({0.0f, 0.0f, float(-h)}, n, glm::vec3(r), l, 4096, 5);
      EXPECT_NEAR(g.x, want, 0.012) << "tilt " << tilt << " lobe " << int(l.lobe);
      // Normalised over the whole lobe (below the horizon too) the answer would differ by more
      // than the tolerance: the test tells the two definitions apart.
      if (tilt > 1.0) {
        EXPECT_GT(std::abs(num / whole - want), 0.03) << int(l.lobe);
      }
    }
  }
}

TEST(ReferenceGlossyTest, BatchIsDeterministicAndMatchesTheSingleForm) {
  auto scene = MakeScene("cornell");
  ASSERT_TRUE(scene.ok());
  auto tracer = Tracer::Create(*scene);
  ASSERT_TRUE(tracer.ok());
  std::vector<ShadeReceiver> r;
  for (int i = 0; i < 32; ++i) {
    ShadeReceiver s;
    s.position = {0.1f + 0.025f * i, 0.08f, 0.001f};
    s.normal = {0, 0, 1};
    s.reflection = glm::normalize(glm::vec3(0.3f, 0.5f, 1.0f));
    r.push_back(s);
  }
  const GlossyParams l = Ggx(0.3f);
  auto a = (*tracer)->ReferenceGlossy(r, l, 64, 9), b = (*tracer)->ReferenceGlossy(r, l, 64, 9);
  ASSERT_EQ(a.size(), r.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i], b[i]);
    EXPECT_GT(a[i].x, 0.0f);  // the floor sees the lit walls and ceiling
  }
}

}  // namespace
}  // namespace pbgi
