// The micro-buffer's pixel tables against brute-force quadrature, and the cone bounds.
#include <cmath>
#include <random>

#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "pbgi/sh.h"
#include "raster/cube.h"

namespace pbgi {
namespace {

constexpr double kPi = sh::kPi;

TEST(MicroBufferTest, PixelSolidAnglesSumTo4PiAndWeightsToPi) {
  for (int res : {4, 5, 7, 12, 13, 16, 32, 64}) {
    MicroBuffer mb;
    ASSERT_TRUE(mb.Prepare(res).ok());
    ASSERT_EQ(mb.pixel_count(), 6 * res * res);
    double omega = 0.0, above = 0.0, weight = 0.0;
    for (int p = 0; p < mb.pixel_count(); ++p) {
      EXPECT_GT(mb.PixelSolidAngle(p), 0.0);
      EXPECT_LE(mb.PixelSolidAngleAbove(p), mb.PixelSolidAngle(p) * (1 + 1e-12));
      omega += mb.PixelSolidAngle(p);
      above += mb.PixelSolidAngleAbove(p);
      weight += mb.PixelCosineWeight(p);
      EXPECT_NEAR(glm::length(mb.PixelDirection(p)), 1.0f, 1e-6f);
    }
    EXPECT_NEAR(omega, 4.0 * kPi, 1e-9) << res;
    EXPECT_NEAR(above, 2.0 * kPi, 1e-9) << res;
    EXPECT_NEAR(weight, kPi, 1e-9) << res;
  }
}

// Midpoint quadrature over the pixel's face rectangle: dw = dA / (1 + a^2 + b^2)^(3/2), and
// cos(theta) = z / |v| for the cosine weight.
TEST(MicroBufferTest, PixelTablesMatchQuadrature) {
  for (int res : {5, 12}) {
    MicroBuffer mb;
    ASSERT_TRUE(mb.Prepare(res).ok());
    const int n = 200;
    const double step = 2.0 / res;
    for (int p = 0; p < mb.pixel_count(); p += 7) {
      const int face = p / (res * res), row = (p / res) % res, col = p % res;
      const internal::FaceAxes fa = internal::Face(face);
      double omega = 0.0, above = 0.0, weight = 0.0;
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const double a = -1.0 + (col + (i + 0.5) / n) * step;
          const double b = -1.0 + (row + (j + 0.5) / n) * step;
          glm::dvec3 v(0.0);
          v[fa.k] = fa.sign;
          v[fa.k1] = a;
          v[fa.k2] = b;
          const double len = glm::length(v);
          const double dw = step * step / (n * n) / (len * len * len);
          omega += dw;
          if (v.z >= 0.0) {
            above += dw;
            weight += dw * v.z / len;
          }
        }
      }
      EXPECT_NEAR(mb.PixelSolidAngle(p), omega, 1e-6 * omega + 1e-9) << p;
      EXPECT_NEAR(mb.PixelSolidAngleAbove(p), above, 2e-3 * omega + 1e-9) << p;
      EXPECT_NEAR(mb.PixelCosineWeight(p), weight, 2e-3 * omega + 1e-9) << p;
      // The pixel's direction points through its own face.
      const glm::vec3 d = mb.PixelDirection(p);
      EXPECT_GT(fa.sign * d[fa.k], std::fabs(d[fa.k1]));
      EXPECT_GT(fa.sign * d[fa.k], std::fabs(d[fa.k2]));
    }
  }
}

// Every pixel whose centre lies within a cone is inside the cone's FaceRange (brute force).
TEST(MicroBufferTest, FaceRangeIsConservative) {
  std::mt19937 rng(7);
  std::normal_distribution<float> g;
  std::uniform_real_distribution<float> u(0.0f, 1.5f);
  for (int res : {4, 12, 33}) {
    MicroBuffer mb;
    ASSERT_TRUE(mb.Prepare(res).ok());
    for (int trial = 0; trial < 300; ++trial) {
      const glm::vec3 d = glm::normalize(glm::vec3(g(rng), g(rng), g(rng)));
      const float chord = trial < 150 ? 0.1f * u(rng) : u(rng);
      // A face that claims to contain the whole cone: no pixel of another face is in it.
      int contained_face = -1;
      for (int f = 0; f < 6; ++f) {
        int c0, c1, r0, r1;
        bool contained = false;
        if (internal::FaceRange(internal::Face(f), d, chord, res, &c0, &c1, &r0, &r1, &contained) &&
            contained) {
          contained_face = f;
        }
      }
      for (int f = 0; f < 6; ++f) {
        int c0 = -1, c1 = -1, r0 = -1, r1 = -1;
        const bool any = internal::FaceRange(internal::Face(f), d, chord, res, &c0, &c1, &r0, &r1);
        for (int row = 0; row < res; ++row) {
          for (int col = 0; col < res; ++col) {
            const int p = (f * res + row) * res + col;
            if (glm::length(mb.PixelDirection(p) - d) > chord) continue;
            ASSERT_TRUE(any) << "face " << f << " trial " << trial;
            if (contained_face >= 0) {
              EXPECT_EQ(f, contained_face) << "trial " << trial;
            }
            EXPECT_TRUE(col >= c0 && col <= c1 && row >= r0 && row <= r1)
                << "face " << f << " trial " << trial << " pixel " << row << "," << col;
          }
        }
      }
    }
  }
}

// Every point of a disk that projects onto a face lies in the face's DiskFaceRange (brute force
// over points of random disks), and the range is tight: some point reaches each end.
TEST(MicroBufferTest, DiskFaceRangeIsExact) {
  std::mt19937 rng(11);
  std::normal_distribution<float> g;
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const int res = 12;
  int exact_faces = 0, tight_checked = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const glm::vec3 c = glm::vec3(g(rng), g(rng), g(rng)) * 2.0f;
    const glm::vec3 n = glm::normalize(glm::vec3(g(rng), g(rng), g(rng)));
    const glm::vec3 a = std::fabs(n.x) < 0.9f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0);
    const glm::vec3 e1 = glm::normalize(glm::cross(a, n)), e2 = glm::cross(n, e1);
    const float r = 0.05f + u(rng);
    for (int f = 0; f < 6; ++f) {
      const internal::FaceAxes fa = internal::Face(f);
      int c0 = -1, c1 = -1, r0 = -1, r1 = -1;
      const internal::DiskRange range =
          internal::DiskFaceRange(fa, c, e1, e2, r, res, &c0, &c1, &r0, &r1);
      if (range == internal::DiskRange::kUnknown) continue;
      if (range == internal::DiskRange::kExact) ++exact_faces;
      int seen_c0 = res, seen_c1 = -1, seen_r0 = res, seen_r1 = -1;
      for (int i = 0; i < 4000; ++i) {
        const float rho = r * std::sqrt(u(rng)), phi = 6.2831853f * u(rng);
        const glm::vec3 p = c + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
        const float z = fa.sign * p[fa.k];
        if (!(z > 0.0f)) continue;
        const float x = p[fa.k1] / z, y = p[fa.k2] / z;
        if (std::fabs(x) > 1.0f || std::fabs(y) > 1.0f) continue;  // another face
        ASSERT_EQ(range, internal::DiskRange::kExact) << "trial " << trial << " face " << f;
        const int col = std::min(res - 1, static_cast<int>((x + 1.0f) * 0.5f * res));
        const int row = std::min(res - 1, static_cast<int>((y + 1.0f) * 0.5f * res));
        EXPECT_TRUE(col >= c0 && col <= c1 && row >= r0 && row <= r1)
            << "trial " << trial << " face " << f;
        seen_c0 = std::min(seen_c0, col);
        seen_c1 = std::max(seen_c1, col);
        seen_r0 = std::min(seen_r0, row);
        seen_r1 = std::max(seen_r1, row);
      }
      if (seen_c1 >= 0 && c0 > 0 && c1 < res - 1 && r0 > 0 && r1 < res - 1) {
        // Not clipped by the face's border: tight up to the sampling, within one pixel of what
        // 4000 points reached.
        ++tight_checked;
        EXPECT_GE(seen_c0, c0);
        EXPECT_LE(seen_c0 - c0, 1);
        EXPECT_LE(c1 - seen_c1, 1);
        EXPECT_LE(seen_r0 - r0, 1);
        EXPECT_LE(r1 - seen_r1, 1);
      }
    }
  }
  EXPECT_GT(exact_faces, 100);
  EXPECT_GT(tight_checked, 20);
}

TEST(MicroBufferTest, RejectsResolutionOutOfRange) {
  MicroBuffer mb;
  EXPECT_EQ(mb.Prepare(3).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(mb.Prepare(65).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(mb.Prepare(4).ok());
  EXPECT_TRUE(mb.Prepare(64).ok());
  EXPECT_EQ(mb.resolution(), 64);
}

}  // namespace
}  // namespace pbgi
