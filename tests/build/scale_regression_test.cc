// Regressions of issue 17, "Numbers at the edges of float": a scene scaled by 1e-12 or 1e12
// built, verified and shaded with exit 0 but gave occlusion 0.035 or 0.68 where the unscaled
// scene gives 0.83; at 1e-38 each receiver took about a second; radii of 1e20 or coordinates
// near 1e30 built a database whose node areas were infinite. Now a scene shades the same at
// every scale and position the float pipeline can hold, and anything outside that range is an
// input error naming the surfel (build/input_range.h, docs/format.md "Numeric range").
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/shade.h"
#include "pbgi/testing.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;

struct Scene {
  std::vector<Surfel> surfels;
  std::vector<ShadeReceiver> receivers;
};

// The random test scene (unit cube), receivers just above 80 of its surfels. With `grid`,
// positions are multiples of 2^-12, so that offsets by powers of two up to 2^11 are exact.
Scene MakeScene(bool grid) {
  Scene s;
  s.surfels = testing::RandomSceneSurfels(8000, 7);
  auto snap = [&](glm::vec3 p) {
    return grid ? glm::round(p * 4096.0f) / 4096.0f : p;
  };
  for (Surfel& x : s.surfels) x.position = snap(x.position);
  for (int i = 0; i < 80; ++i) {
    const Surfel& x = s.surfels[static_cast<size_t>(i) * 97];
    s.receivers.push_back({snap(x.position + x.normal * (x.radius * 0.25f)), x.normal, x.normal});
  }
  return s;
}

// Occlusion per receiver of the scene mapped by p -> (p + offset) * scale (radii * scale), or
// the build's error.
absl::StatusOr<std::vector<float>> Shade(const Scene& base, double scale, double offset) {
  std::vector<Surfel> surfels = base.surfels;
  auto map = [&](glm::vec3 p) {
    return glm::vec3((glm::dvec3(p) + offset) * scale);
  };
  for (Surfel& x : surfels) {
    x.position = map(x.position);
    x.radius = static_cast<float>(x.radius * scale);
  }
  std::vector<ShadeReceiver> receivers = base.receivers;
  for (ShadeReceiver& r : receivers) r.position = map(r.position);
  BuildOptions bo;
  bo.channels = Channels::kOcclusion;
  auto db = testing::TempDatabase::Create(surfels, bo);
  if (!db.ok()) return db.status();
  ShadeOptions so;
  so.raster.compute_radiance = false;
  so.threads = 1;
  std::vector<ShadeResult> out(receivers.size());
  absl::Status s = ShadeBatch((*db)->db(), receivers, so, absl::MakeSpan(out));
  if (!s.ok()) return s;
  std::vector<float> occ;
  for (const ShadeResult& r : out) occ.push_back(r.occlusion);
  return occ;
}

double MaxDiff(const std::vector<float>& a, const std::vector<float>& b) {
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, double(std::abs(a[i] - b[i])));
  return m;
}
double Mean(const std::vector<float>& a) {
  double m = 0;
  for (float v : a) m += v;
  return m / double(a.size());
}

void ExpectRangeRefusal(const absl::Status& s) {
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("input surfel "));
  EXPECT_THAT(std::string(s.message()), HasSubstr("Numeric range"));
}

TEST(ScaleRegressionTest, PowerOfTwoScalesShadeTheSameOrAreRefused) {
  const Scene base = MakeScene(false);
  auto ref = Shade(base, 1.0, 0.0);
  ASSERT_TRUE(ref.ok()) << ref.status();
  ASSERT_GT(Mean(*ref), 0.01);
  int accepted = 0, lo = 0, hi = 0;
  for (int e = -126; e <= 126; e += 6) {
    SCOPED_TRACE(absl::StrFormat("scale 2^%d", e));
    // Exact: every coordinate and radius keeps its bits, only the exponent moves.
    auto got = Shade(base, std::ldexp(1.0, e), 0.0);
    if (!got.ok()) {
      ExpectRangeRefusal(got.status());
      // The documented range holds this scene from 2^-22 to 2^30 (radii near 2^-8, a total
      // area near 1).
      EXPECT_TRUE(e < -22 || e > 30) << got.status();
      continue;
    }
    ++accepted;
    lo = std::min(lo, e);
    hi = std::max(hi, e);
    EXPECT_LE(MaxDiff(*got, *ref), 1e-3);
  }
  std::printf("scales: the same occlusion from 2^%d to 2^%d (steps of 2^6), refused beyond\n", lo,
              hi);
  EXPECT_GE(accepted, 8);
}

TEST(ScaleRegressionTest, DecimalScalesShadeTheSameOnAverageOrAreRefused) {
  // Not exact: every coordinate rounds, and the cut (a threshold) then takes other nodes for
  // a few receivers, so the figure compared is the mean over the receivers.
  const Scene base = MakeScene(false);
  auto ref = Shade(base, 1.0, 0.0);
  ASSERT_TRUE(ref.ok());
  int accepted = 0;
  for (int d = -30; d <= 30; d += 3) {
    SCOPED_TRACE(absl::StrFormat("scale 1e%d", d));
    auto got = Shade(base, std::pow(10.0, d), 0.0);
    if (!got.ok()) {
      ExpectRangeRefusal(got.status());
      continue;
    }
    ++accepted;
    EXPECT_NEAR(Mean(*got), Mean(*ref), 1e-3);
  }
  EXPECT_GE(accepted, 5);
}

TEST(ScaleRegressionTest, OffsetsShadeTheSameOrAreRefused) {
  const Scene base = MakeScene(true);
  auto ref = Shade(base, 1.0, 0.0);
  ASSERT_TRUE(ref.ok());
  int last = -1;
  for (int k = 0; k <= 24; ++k) {
    SCOPED_TRACE(absl::StrFormat("offset 2^%d", k));
    auto got = Shade(base, 1.0, std::ldexp(1.0, k));
    if (!got.ok()) {
      ExpectRangeRefusal(got.status());
      EXPECT_THAT(std::string(got.status().message()), HasSubstr("translate the scene"));
      EXPECT_GT(k, 6) << "refused although float places every disk exactly";
      continue;
    }
    EXPECT_LE(k, 12);
    EXPECT_LE(MaxDiff(*got, *ref), 1e-3);
    last = k;
  }
  std::printf("offsets: exact up to 2^%d times the scene's size, refused beyond\n", last);
  // 1e7 times the scene's size: floats there are 1 apart, the scene cannot exist.
  auto far = Shade(base, 1.0, 1e7);
  ASSERT_FALSE(far.ok());
  ExpectRangeRefusal(far.status());
}

TEST(ScaleRegressionTest, AggregatesThatOverflowAreInputErrorsNamingTheSurfel) {
  std::vector<Surfel> surfels = testing::RandomSceneSurfels(500, 3);
  BuildOptions bo;
  {
    std::vector<Surfel> v = surfels;
    v[57].radius = 1e20f;  // its area alone is 3e40: beyond float
    auto db = testing::TempDatabase::Create(v, bo);
    ASSERT_FALSE(db.ok()) << "built a database whose node areas are infinite";
    ExpectRangeRefusal(db.status());
    EXPECT_THAT(std::string(db.status().message()), HasSubstr("input surfel 57 "));
  }
  {
    std::vector<Surfel> v = surfels;
    v[12].position = glm::vec3(1e30f, 0.5f, 0.5f);
    auto db = testing::TempDatabase::Create(v, bo);
    ASSERT_FALSE(db.ok());
    ExpectRangeRefusal(db.status());
    EXPECT_THAT(std::string(db.status().message()), HasSubstr("input surfel 12 "));
  }
  {
    // Each surfel is fine, their sum is not.
    std::vector<Surfel> v = surfels;
    for (Surfel& x : v) x.radius = 3e8f;
    for (Surfel& x : v) x.position *= 1e9f;
    auto db = testing::TempDatabase::Create(v, bo);
    ASSERT_FALSE(db.ok());
    EXPECT_THAT(std::string(db.status().message()), HasSubstr("total area"));
  }
}

}  // namespace
}  // namespace pbgi
