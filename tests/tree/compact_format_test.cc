// Format version 4's compact records (tree/format.h): every field within its stated bound, node
// bounds that hold their points after quantization, the two-sided flag and sheet tag, and damaged
// pages as DataLoss naming the page (tree/decoded_page.h).
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tree/decoded_page.h"
#include "tree/format.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

using ::testing::HasSubstr;

PositionGrid TestGrid() {
  Bounds b;
  b.Extend(glm::vec3(-3.0f, -2.0f, -1.0f));
  b.Extend(glm::vec3(7.0f, 5.0f, 2.0f));
  return GridOfCube(MortonCube(b));
}

float LogUniform(std::mt19937& rng, float lo_exp, float hi_exp) {
  return std::exp2(std::uniform_real_distribution<float>(lo_exp, hi_exp)(rng));
}

glm::vec3 RandomUnit(std::mt19937& rng) {
  std::normal_distribution<float> g;
  for (;;) {
    glm::vec3 v(g(rng), g(rng), g(rng));
    if (glm::length(v) > 1e-3f) return glm::normalize(v);
  }
}

struct Encoded {
  uint8_t bytes[kPointRecordBothSidesBytes];  // the largest record
};

Encoded EncodeSurfel(const Surfel& s, Channels c, const PositionGrid& g) {
  Encoded e{};
  EncodeSurfelRecord(s, c, g, e.bytes);
  return e;
}

TEST(CompactFormatTest, RoundHalfAwayIsLlround) {
  // Ties both ways, values next to ties, the 2^52 edge and beyond it, and random values in the
  // ranges the encoders round (grid cells, octahedral normals, scaled radiance).
  std::vector<double> xs = {0.0,
                            -0.0,
                            0.5,
                            -0.5,
                            1.5,
                            -1.5,
                            2.5,
                            -2.5,
                            0.49999999999999994,
                            -0.49999999999999994,
                            32767.0,
                            -32767.0,
                            2097151.5,
                            4503599627370495.5,
                            4503599627370496.0,
                            -4503599627370497.0,
                            1e17,
                            -1e17};
  for (double x : {0.5, 1.5, 1e6 + 0.5, 2097150.5}) {
    xs.push_back(std::nextafter(x, 0.0));
    xs.push_back(std::nextafter(x, 1e300));
    xs.push_back(-std::nextafter(x, 0.0));
  }
  std::mt19937_64 rng(20);
  std::uniform_real_distribution<double> u(-2.2e6, 2.2e6);
  for (int i = 0; i < 100000; ++i) {
    xs.push_back(u(rng));
    xs.push_back(std::floor(u(rng)) + 0.5);
  }
  for (double x : xs) EXPECT_EQ(RoundHalfAway(x), std::llround(x)) << std::hexfloat << x;
}

// EncodeScaled as it was written before it computed two codes at a time: the largest magnitude,
// then each code by std::llround and a clamp, one coefficient at a time.
template <typename Int, int kMax>
float ScalarEncodeScaled(const float* c, int n, Int* q) {
  float s = 0.0f;
  for (int k = 0; k < n; ++k) s = std::max(s, std::fabs(c[k]));
  if (!(s > 0.0f) || !std::isfinite(s)) {
    for (int k = 0; k < n; ++k) q[k] = 0;
    return std::isfinite(s) ? 0.0f : s;
  }
  for (int k = 0; k < n; ++k) {
    q[k] = static_cast<Int>(
        std::clamp<int64_t>(std::llround(double{c[k]} / double{s} * kMax), -kMax, kMax));
  }
  return s;
}

template <typename Int, int kMax>
void ExpectEncodeScaledIsScalar(const std::vector<float>& c) {
  const int n = static_cast<int>(c.size());
  std::vector<Int> got(n, Int{99}), want(n, Int{-99});
  const float s_got = EncodeScaled<Int, kMax>(c.data(), n, got.data());
  const float s_want = ScalarEncodeScaled<Int, kMax>(c.data(), n, want.data());
  std::string in;
  for (float x : c) in += absl::StrFormat(" %a", x);
  ASSERT_EQ(std::memcmp(&s_got, &s_want, sizeof s_got), 0) << kMax << in;
  for (int k = 0; k < n; ++k) ASSERT_EQ(int{got[k]}, int{want[k]}) << kMax << " k " << k << in;
}

TEST(CompactFormatTest, EncodeScaledIsTheScalarFormula) {
  std::mt19937 rng(15);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  const float kInf = std::numeric_limits<float>::infinity();
  const float kMaxF = std::numeric_limits<float>::max();
  const float kDenorm = std::numeric_limits<float>::denorm_min();
  std::vector<std::vector<float>> inputs = {
      {0, 0, 0, 0, 0, 0, 0, 0, 0},
      {-0.0f, 0, -0.0f, 0, 0, 0, 0, 0, -0.0f},
      {1, -1, 1, -1, 0.5f, -0.5f, 0.25f, -0.25f, 1},
      {kMaxF, -kMaxF, 1, -1, kDenorm, -kDenorm, 0, 3e38f, -3e38f},
      {kDenorm, -kDenorm, kDenorm, 0, 0, 0, 0, 0, 0},
      {kNaN, 1, 0.5f, -0.25f, 0.3f, 0.7f, -0.9f, 0.1f, 0.2f},
      {1, 0.5f, kNaN, kNaN, 0.3f, 0.7f, -0.9f, 0.1f, kNaN},
      {1, 0.5f, kInf, -0.25f, 0.3f, 0.7f, -0.9f, 0.1f, 0.2f},
      {1, 0.5f, -kInf, -0.25f, 0.3f, 0.7f, -0.9f, 0.1f, 0.2f},
      {0.5f},
      {-0.5f, 0.25f},
      {0.5f, 0.25f, -0.125f},
      {0.5f, 0.25f, -0.125f, 0.1f, 0.2f, 0.3f, 0.4f, -0.5f},
      {0.5f, 0.25f, -0.125f, 0.1f, kNaN, 0.3f, 0.4f, -0.5f, 0.7f},
      {0.5f, 0.25f, -0.125f, 0.1f, 0.2f, 0.3f, 0.4f, -0.5f, kNaN},
      {kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, -0.75f},
      {kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN},
      {-kInf, kNaN, 0, 0, 0, 0, 0, 0, 0},
      {0, 0, 0, 0, 0, 0, 0, 0, kInf},
      {kDenorm, 0, 0, 0, 0, 0, 0, 0, -2 * kDenorm},
  };
  // Codes next to rounding ties, for both code widths: s * (j + 1/2) / kMax and its neighbours.
  for (float s : {1.0f, 0.001f, 3.7f, 1e20f, 1e-30f}) {
    for (int kmax : {127, 32767}) {
      for (int rep = 0; rep < 50; ++rep) {
        std::vector<float> c = {s};
        for (int k = 1; k < 9; ++k) {
          const int j = std::uniform_int_distribution<int>(-kmax, kmax - 1)(rng);
          float x = static_cast<float>(double{s} * (j + 0.5) / kmax);
          const int step = std::uniform_int_distribution<int>(-2, 2)(rng);
          for (int i = 0; i < std::abs(step); ++i) x = std::nextafter(x, step < 0 ? -kInf : kInf);
          c.push_back(std::clamp(x, -s, s));
        }
        std::shuffle(c.begin(), c.end(), rng);
        inputs.push_back(c);
      }
    }
  }
  // Random coefficient vectors over many magnitudes, of every length up to 9.
  for (int rep = 0; rep < 100000; ++rep) {
    const int n = rep % 10 == 0 ? std::uniform_int_distribution<int>(1, 9)(rng) : 9;
    const float scale = std::exp2(std::uniform_real_distribution<float>(-40.0f, 40.0f)(rng));
    std::vector<float> c(n);
    for (float& x : c) x = u(rng) * scale;
    // Now and then a NaN or an infinity anywhere: the largest magnitude skips a NaN.
    if (rep % 97 == 0) c[rng() % n] = rep % 2 ? kNaN : (rep % 3 ? kInf : -kInf);
    inputs.push_back(c);
  }
  for (const std::vector<float>& c : inputs) {
    ExpectEncodeScaledIsScalar<int16_t, 32767>(c);
    ExpectEncodeScaledIsScalar<int8_t, 127>(c);
  }
}

TEST(CompactFormatTest, RecordSizes) {
  EXPECT_EQ(PointRecordSize(Channels::kOcclusion), 14u);
  EXPECT_EQ(PointRecordSize(Channels::kRadiance), 20u);
  EXPECT_EQ(NodeRecordSize(Channels::kOcclusion), 60u);
  EXPECT_EQ(NodeRecordSize(Channels::kRadiance), 100u);
}

// A node's radiance contrast: rounded up, by at most one step of 1/16 octave of 1 + c; 0 and
// NaN store 0; the largest code saturates.
TEST(CompactFormatTest, NodeContrastRoundsUpWithinAStep) {
  EXPECT_EQ(ContrastCode(0.0), 0);
  EXPECT_EQ(ContrastCode(std::nan("")), 0);
  EXPECT_EQ(ContrastValue(0), 0.0f);
  EXPECT_EQ(ContrastCode(1e30), 255);
  for (double c = 1e-4; c < 6e4; c *= 1.01) {
    const uint8_t code = ContrastCode(c);
    const double v = ContrastValue(code);
    EXPECT_GE(v, c * (1.0 - 1e-6)) << c;
    EXPECT_LE(std::log2(1.0 + v) - std::log2(1.0 + c), 1.0 / 16.0 + 1e-6) << c;
  }
  // The record carries it: radiance databases only.
  const PositionGrid g = TestGrid();
  NodeRecordRadiance r{};
  r.common.flags = kNodeFlagLeaf;
  r.common.children = kNoNodeRef;
  r.contrast = 2.5f;
  uint8_t bytes[kNodeRecordRadianceBytes];
  EncodeNodeRecord(r, Channels::kRadiance, g, bytes);
  EXPECT_EQ(DecodeNodeRecord(bytes, Channels::kRadiance, g).contrast,
            ContrastValue(ContrastCode(2.5)));
  EncodeNodeRecord(r, Channels::kOcclusion, g, bytes);
  EXPECT_EQ(DecodeNodeRecord(bytes, Channels::kOcclusion, g).contrast, 0.0f);
}

// Position: within half a cell (plus float rounding of the cell centre); normal: within 1e-4 rad
// and unit; radius: relative 2^-11; radiance: relative 2^-10 with its sign; the flag exact.
TEST(CompactFormatTest, PointFieldsRoundTripWithinTheirBounds) {
  const PositionGrid g = TestGrid();
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int i = 0; i < 20000; ++i) {
    Surfel s;
    s.position = glm::vec3(-3.0f + 10 * u(rng), -2.0f + 7 * u(rng), -1.0f + 3 * u(rng));
    s.normal = RandomUnit(rng);
    s.radius = LogUniform(rng, -30.0f, 30.0f);
    for (int k = 0; k < 3; ++k) {
      s.radiance[k] = (u(rng) < 0.1f ? -1.0f : 1.0f) * LogUniform(rng, -30.0f, 30.0f);
      s.back_radiance[k] = (u(rng) < 0.1f ? -1.0f : 1.0f) * LogUniform(rng, -30.0f, 30.0f);
    }
    s.two_sided = u(rng) < 0.5f;
    s.sheet = static_cast<uint8_t>(rng() % 256);
    for (Channels c : {Channels::kOcclusion, Channels::kRadiance, Channels::kRadianceBothSides}) {
      const Encoded e = EncodeSurfel(s, c, g);
      const Surfel d = DecodePointRecord(e.bytes, c, g);
      for (int k = 0; k < 3; ++k) {
        const float tol = 0.5f * g.step + 4 * std::numeric_limits<float>::epsilon() * 16.0f;
        ASSERT_LE(std::fabs(d.position[k] - s.position[k]), tol) << i << " axis " << k;
      }
      ASSERT_NEAR(glm::length(d.normal), 1.0f, 1e-6f);
      // The chord: the angle, nearly. Two-sided normals have 12-bit coordinates (the sheet
      // tag takes the rest): up to about 1.0e-3 (1.0003e-3 seen).
      ASSERT_LE(glm::length(d.normal - s.normal), s.two_sided ? 1.05e-3f : 1e-4f) << i;
      ASSERT_LE(std::fabs(d.radius - s.radius), s.radius * 0x1p-11f * 1.0001f) << s.radius;
      ASSERT_EQ(d.two_sided, s.two_sided);
      ASSERT_EQ(d.sheet, s.two_sided ? s.sheet : 0) << i;
      for (int k = 0; k < 3; ++k) {
        if (c == Channels::kOcclusion) {
          ASSERT_EQ(d.radiance[k], 0.0f);
          ASSERT_EQ(d.back_radiance[k], 0.0f);
        } else {
          ASSERT_LE(std::fabs(d.radiance[k] - s.radiance[k]),
                    std::fabs(s.radiance[k]) * 0x1p-10f * 1.0001f)
              << s.radiance[k];
          // The back: its own where stored, else the front's; none on one-sided surfels.
          if (!s.two_sided) {
            ASSERT_EQ(d.back_radiance[k], 0.0f);
          } else if (c == Channels::kRadiance) {
            ASSERT_EQ(d.back_radiance[k], d.radiance[k]);
          } else {
            ASSERT_LE(std::fabs(d.back_radiance[k] - s.back_radiance[k]),
                      std::fabs(s.back_radiance[k]) * 0x1p-10f * 1.0001f)
                << s.back_radiance[k];
          }
        }
      }
      // Decoding what was decoded and encoded again changes nothing.
      const Encoded again = EncodeSurfel(d, c, g);
      const Surfel d2 = DecodePointRecord(again.bytes, c, g);
      ASSERT_EQ(d2.position, d.position);
      ASSERT_EQ(d2.normal, d.normal);
      ASSERT_EQ(d2.radius, d.radius);
      ASSERT_EQ(d2.radiance, d.radiance);
      ASSERT_EQ(d2.back_radiance, d.back_radiance);
      ASSERT_EQ(d2.sheet, d.sheet);
    }
  }
}

TEST(CompactFormatTest, RadiusAtAndBeyondTheRangeStaysPositiveAndFinite) {
  for (float r : {0x1p-30f, 0x1p-31f, 1e-12f, 1e-30f, 0x1p31f, 1e12f, 3e38f}) {
    const float d = DecodeRadius16(EncodeRadius16(r));
    EXPECT_GT(d, 0.0f) << r;
    EXPECT_TRUE(std::isfinite(d)) << r;
  }
  EXPECT_EQ(DecodeRadius16(EncodeRadius16(0x1p-30f)), 0x1p-30f);
  EXPECT_EQ(DecodeRadius16(EncodeRadius16(1.0f)), 1.0f);
  // Radiance: zero and tiny values are zero, large ones clamp to the largest code.
  EXPECT_EQ(DecodeRadiance16(EncodeRadiance16(0.0f)), 0.0f);
  EXPECT_EQ(DecodeRadiance16(EncodeRadiance16(1e-20f)), 0.0f);
  EXPECT_EQ(DecodeRadiance16(EncodeRadiance16(-2.5f)), -2.5f);
  EXPECT_GT(DecodeRadiance16(EncodeRadiance16(1e30f)), 1e9f);
}

TEST(CompactFormatTest, TwoSidedFlagRoundTripsAtEveryCorner) {
  const PositionGrid g = TestGrid();
  for (bool two : {false, true}) {
    for (float x : {-1e9f, -3.0f, 0.0f, 7.0f, 1e9f}) {  // clamped to the grid beyond it
      Surfel s;
      s.position = glm::vec3(x, x, x);
      s.radius = 0.25f;
      s.two_sided = two;
      for (Channels c : {Channels::kOcclusion, Channels::kRadiance}) {
        const Encoded e = EncodeSurfel(s, c, g);
        const Surfel d = DecodePointRecord(e.bytes, c, g);
        EXPECT_EQ(d.two_sided, two) << x;
        EXPECT_EQ(d.radius, 0.25f);
      }
    }
  }
}

// A two-sided surfel's sheet tag (Surfel::sheet) travels in its sort record's radius
// (EncodeRadius: the stored radius, the tag in the low mantissa bits) and in its point record's
// normal (EncodeOctahedralSheet): every tag, on normals at the octahedron's folds and edges,
// with radii across the range; the radius it carries is the one stored, and a one-sided
// surfel's radius and tag are as before (the radius unrounded, the tag 0).
TEST(CompactFormatTest, SheetTagsRoundTripOnTwoSidedRecords) {
  const PositionGrid g = TestGrid();
  const glm::vec3 normals[] = {{0, 0, 1}, {0, 0, -1},  {1, 0, 0},         {0, -1, 0},
                               {1, 1, 0}, {-1, 1, -1}, {0.3f, -0.2f, -5}, {1e-7f, 0, -1}};
  for (int sheet = 0; sheet < 256; ++sheet) {
    for (const glm::vec3& n : normals) {
      for (float radius : {0x1p-31f, 1e-3f, 0.1234567f, 3.0f, 1e9f}) {
        Surfel s;
        s.position = glm::vec3(1.0f, 2.0f, 0.5f);
        s.normal = glm::normalize(n);
        s.radius = radius;
        s.two_sided = true;
        s.sheet = static_cast<uint8_t>(sheet);
        const float r = EncodeRadius(s.radius, true, s.sheet);
        ASSERT_TRUE(RadiusTwoSided(r));
        ASSERT_EQ(RadiusSheet(r), sheet);
        ASSERT_EQ(EncodeRadius16(r), EncodeRadius16(radius)) << radius;
        ASSERT_EQ(RadiusValue(r), DecodeRadius16(EncodeRadius16(radius))) << radius;
        for (Channels c : {Channels::kOcclusion, Channels::kRadiance}) {
          const Surfel d = DecodePointRecord(EncodeSurfel(s, c, g).bytes, c, g);
          ASSERT_TRUE(d.two_sided);
          ASSERT_EQ(d.sheet, sheet) << n.x << " " << n.y << " " << n.z;
          ASSERT_LE(glm::length(d.normal - s.normal), 1e-3f) << n.x << " " << n.y << " " << n.z;
          ASSERT_EQ(d.radius, DecodeRadius16(EncodeRadius16(radius)));
        }
      }
    }
  }
  EXPECT_EQ(EncodeRadius(0.1234567f, false, 7), 0.1234567f);
  EXPECT_EQ(RadiusSheet(EncodeRadius(0.1234567f, false, 7)), 0);
}

NodeRecordRadiance RandomNode(std::mt19937& rng) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  NodeRecordRadiance r{};
  NodeRecordCommon& c = r.common;
  for (int k = 0; k < 3; ++k) {
    const float a = u(rng) * 2.0f, b = u(rng) * 2.0f;
    c.lo[k] = std::min(a, b);
    c.hi[k] = std::max(a, b);
  }
  const bool leaf = u(rng) < 0;
  c.flags = leaf ? kNodeFlagLeaf : 0;
  c.child_count = leaf ? 0 : 1 + static_cast<uint32_t>(rng() % 8);
  c.children = leaf ? kNoNodeRef : MakeNodeRef(rng() % 100000, rng() % 600);
  c.first_point = (uint64_t{rng()} << 8) % kMaxStoredPointIndex;
  c.point_count = rng() % 1000000;
  c.depth = rng() % 32;
  c.area = LogUniform(rng, -20, 20);
  const float scale = LogUniform(rng, -20, 20);
  for (int k = 0; k < 9; ++k) c.sh_area[k] = u(rng) * scale;
  for (int ch = 0; ch < 3; ++ch) {
    const float ps = LogUniform(rng, -20, 20);
    for (int k = 0; k < 9; ++k) r.sh_power[ch][k] = u(rng) * ps;
  }
  return r;
}

float MaxAbs9(const float* c) {
  float m = 0;
  for (int k = 0; k < 9; ++k) m = std::max(m, std::fabs(c[k]));
  return m;
}

// Links, counts, depth, flags and area exact; area SH within half a step of 1/32767 of the
// node's largest coefficient, power SH within half a step of 1/127 of the colour's largest.
TEST(CompactFormatTest, NodeFieldsRoundTripWithinTheirBounds) {
  const PositionGrid g = TestGrid();
  std::mt19937 rng(11);
  for (int i = 0; i < 5000; ++i) {
    const NodeRecordRadiance r = RandomNode(rng);
    for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
      uint8_t bytes[kNodeRecordRadianceBytes];
      EncodeNodeRecord(r, ch, g, bytes);
      const NodeRecordRadiance d = DecodeNodeRecord(bytes, ch, g);
      const NodeRecordCommon &a = r.common, &b = d.common;
      ASSERT_EQ(b.flags, a.flags);
      ASSERT_EQ(b.child_count, a.child_count);
      ASSERT_EQ(b.children, a.children);
      ASSERT_EQ(b.first_point, a.first_point);
      ASSERT_EQ(b.point_count, a.point_count);
      ASSERT_EQ(b.depth, a.depth);
      ASSERT_EQ(b.area, a.area);
      for (int k = 0; k < 3; ++k) {
        ASSERT_LE(b.lo[k], a.lo[k]);
        ASSERT_GE(b.hi[k], a.hi[k]);
        ASSERT_LE(a.lo[k] - b.lo[k], g.step * 1.001f);
        ASSERT_LE(b.hi[k] - a.hi[k], g.step * 1.001f);
      }
      const float sa = MaxAbs9(a.sh_area);
      for (int k = 0; k < 9; ++k) {
        ASSERT_LE(std::fabs(b.sh_area[k] - a.sh_area[k]), sa / (2 * 32767.0f) * 1.01f) << k;
      }
      for (int c = 0; c < 3; ++c) {
        const float sp = MaxAbs9(r.sh_power[c]);
        for (int k = 0; k < 9; ++k) {
          if (ch == Channels::kOcclusion) {
            ASSERT_EQ(d.sh_power[c][k], 0.0f);
          } else {
            ASSERT_LE(std::fabs(d.sh_power[c][k] - r.sh_power[c][k]), sp / (2 * 127.0f) * 1.01f);
          }
        }
      }
    }
  }
}

// The builder's case: bounds of decoded positions are stored exactly; and bounds of any points
// (a hand-made record) are rounded outward, so the decoded box still holds every point.
TEST(CompactFormatTest, NodeBoundsContainTheirPointsAfterQuantization) {
  const PositionGrid g = TestGrid();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int n = 0; n < 2000; ++n) {
    // A small cluster somewhere in the box, down to a few cells wide.
    // (The grid's cube is -3 .. 7 on x; a cluster stays inside it, as the builder's do.)
    const glm::vec3 centre(-3.0f + 9 * u(rng), -2.0f + 6 * u(rng), -1.0f + 2 * u(rng));
    const float spread = LogUniform(rng, -22, 0);
    std::vector<Surfel> raw, decoded;
    for (int i = 0; i < 16; ++i) {
      Surfel s;
      s.position = centre + spread * glm::vec3(u(rng), u(rng), u(rng));
      s.radius = 0.01f;
      raw.push_back(s);
      decoded.push_back(DecodePointRecord(EncodeSurfel(s, Channels::kOcclusion, g).bytes,
                                          Channels::kOcclusion, g));
    }
    for (const std::vector<Surfel>* pts : {&decoded, &raw}) {
      Bounds b;
      for (const Surfel& s : *pts) b.Extend(s.position);
      NodeRecordRadiance r{};
      for (int k = 0; k < 3; ++k) r.common.lo[k] = b.lo[k], r.common.hi[k] = b.hi[k];
      r.common.flags = kNodeFlagLeaf;
      r.common.children = kNoNodeRef;
      uint8_t bytes[kNodeRecordOcclusionBytes];
      EncodeNodeRecord(r, Channels::kOcclusion, g, bytes);
      const NodeRecordRadiance d = DecodeNodeRecord(bytes, Channels::kOcclusion, g);
      for (int k = 0; k < 3; ++k) {
        if (pts == &decoded) {
          ASSERT_EQ(d.common.lo[k], b.lo[k]);
          ASSERT_EQ(d.common.hi[k], b.hi[k]);
        }
        for (const std::vector<Surfel>* all : {&decoded, &raw}) {
          if (pts == &decoded && all == &raw) continue;  // raw points may lie half a cell out
          for (const Surfel& s : *all) {
            ASSERT_LE(d.common.lo[k], s.position[k]);
            ASSERT_GE(d.common.hi[k], s.position[k]);
          }
        }
      }
    }
  }
}

StoreMeta PageMeta(Channels c) {
  StoreMeta m;
  m.channels = c;
  m.page_size = 4096 - 16;
  m.point_count = 1000000;
  const PositionGrid g = TestGrid();
  for (int a = 0; a < 3; ++a) m.grid_origin[a] = g.origin[a];
  m.grid_step = g.step;
  return m;
}

std::vector<uint8_t> NodePayload(const StoreMeta& m, int records) {
  std::mt19937 rng(5);
  std::vector<uint8_t> payload(size_t(records) * NodeRecordSize(m.channels));
  for (int i = 0; i < records; ++i) {
    NodeRecordRadiance r{};
    NodeRecordCommon& c = r.common;
    for (int k = 0; k < 3; ++k) c.lo[k] = -1.0f, c.hi[k] = 1.0f;
    c.flags = kNodeFlagLeaf;
    c.children = kNoNodeRef;
    c.first_point = rng() % 1000;
    c.point_count = 16;
    c.area = 1.0f;
    c.depth = 3;
    c.sh_area[0] = 0.886f;
    EncodeNodeRecord(r, m.channels, PositionGrid::Of(m),
                     payload.data() + i * NodeRecordSize(m.channels));
  }
  return payload;
}

absl::Status Decode(const StoreMeta& m, Section s, uint64_t page_no, uint32_t records,
                    const std::vector<uint8_t>& payload, DecodedPage* out) {
  PageHeader h{};
  h.kind = static_cast<uint16_t>(s == Section::kNodes ? PageKind::kNode : PageKind::kPoint);
  h.format = kStoreFormatVersion;
  h.record_count = records;
  h.payload_bytes = static_cast<uint32_t>(payload.size());
  h.page_no = page_no;
  PageView v;
  v.header = &h;
  v.payload = absl::MakeConstSpan(payload);
  return DecodePage(v, s, page_no, m, "store Z", out);
}

TEST(CompactFormatTest, DamagedOrTruncatedPagesAreDataLossNamingThePage) {
  for (Channels c : {Channels::kOcclusion, Channels::kRadiance}) {
    const StoreMeta m = PageMeta(c);
    std::vector<uint8_t> good = NodePayload(m, 10);
    DecodedPage page;
    ASSERT_TRUE(Decode(m, Section::kNodes, 7, 10, good, &page).ok());
    EXPECT_EQ(page.count, 10u);

    // Truncated: the records do not fit the payload.
    std::vector<uint8_t> cut(good.begin(), good.end() - 1);
    absl::Status s = Decode(m, Section::kNodes, 7, 10, cut, &page);
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(std::string(s.message()), HasSubstr("nodes page 7"));
    EXPECT_THAT(std::string(s.message()), HasSubstr("store Z"));

    // A leaf with children, and an interior node with 15 (the field holds up to 15).
    std::vector<uint8_t> bad = good;
    bad[NodeRecordSize(c) * 4 + 33] = 0x31;
    s = Decode(m, Section::kNodes, 7, 10, bad, &page);
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(std::string(s.message()), HasSubstr("nodes page 7 is corrupt: node 4"));
    bad[NodeRecordSize(c) * 4 + 33] = 0xf0;
    s = Decode(m, Section::kNodes, 7, 10, bad, &page);
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);

    // Inverted bounds: lo's x cell above hi's.
    bad = good;
    const uint64_t cell = kGridMax;
    std::memcpy(bad.data() + NodeRecordSize(c) * 2, &cell, 3);
    s = Decode(m, Section::kNodes, 7, 10, bad, &page);
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(std::string(s.message()), HasSubstr("node 2 has bad bounds"));

    // A point page one record short.
    const uint32_t per = PointsPerPage(m.page_size, c);
    std::vector<uint8_t> points(size_t(per) * PointRecordSize(c));
    ASSERT_TRUE(Decode(m, Section::kPoints, 3, per, points, &page).ok());
    points.resize(points.size() - 1);
    s = Decode(m, Section::kPoints, 3, per, points, &page);
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(std::string(s.message()), HasSubstr("points page 3"));
  }
}

// Any bytes decode to an error or to records the traversal may trust, never a crash.
TEST(CompactFormatTest, RandomNodeBytesNeverCrash) {
  const StoreMeta m = PageMeta(Channels::kRadiance);
  std::mt19937 rng(9);
  for (int t = 0; t < 2000; ++t) {
    std::vector<uint8_t> payload(size_t(NodeRecordSize(m.channels)) * 4);
    for (uint8_t& b : payload) b = static_cast<uint8_t>(rng());
    DecodedPage page;
    const absl::Status s = Decode(m, Section::kNodes, 1, 4, payload, &page);
    if (s.ok()) {
      for (uint32_t i = 0; i < page.count; ++i) {
        ASSERT_LE(page.nodes[i].child_count, 8);
        ASSERT_LE(page.nodes[i].first_point + page.nodes[i].point_count, m.point_count);
      }
    } else {
      ASSERT_EQ(s.code(), absl::StatusCode::kDataLoss);
      ASSERT_THAT(std::string(s.message()), HasSubstr("nodes page 1"));
    }
  }
}

}  // namespace
}  // namespace pbgi::internal
