// Polygon footprints (raster/polygon.h): exact area coverage, tiling, and the cube's faces.
#include "raster/polygon.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <type_traits>
#include <vector>

#include "glm/geometric.hpp"
#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "pbgi/sh.h"
#include "raster/polygon_coverage.h"

namespace pbgi::internal {
namespace {

using polygon_coverage::PixelSamples;

// Face-plane pixel area of face +z at resolution res: (2 / res)^2.
Polygon Quad(glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d) {
  Polygon p;
  p.n = 4;
  p.v[0] = a, p.v[1] = b, p.v[2] = c, p.v[3] = d;
  return p;
}

std::map<uint32_t, float> Coverage(const Polygon& p, int res) {
  std::vector<float> acc;
  std::vector<PixelCoverage> out;
  RasterizePolygon(p, res, &acc, &out);
  std::map<uint32_t, float> m;
  for (const PixelCoverage& c : out) m[c.pixel] += c.coverage;
  return m;
}

TEST(PolygonTest, PixelAlignedSquareCoversItsPixelsExactly) {
  // On the plane z = 1 (face +z, res 8: pixel edges at x = -1 + k / 4), the square
  // [-0.5, 0.25] x [0, 0.5] covers columns 2..4 and rows 4..5 exactly.
  const int res = 8;
  const Polygon p =
      Quad({-0.5f, 0.0f, 1.0f}, {0.25f, 0.0f, 1.0f}, {0.25f, 0.5f, 1.0f}, {-0.5f, 0.5f, 1.0f});
  const auto m = Coverage(p, res);
  const uint32_t base = 4 * res * res;
  EXPECT_EQ(m.size(), 6u);
  for (int row = 4; row <= 5; ++row) {
    for (int col = 2; col <= 4; ++col) {
      auto it = m.find(base + uint32_t(row * res + col));
      ASSERT_NE(it, m.end()) << row << " " << col;
      EXPECT_NEAR(it->second, 1.0f, 1e-5f);
    }
  }
}

TEST(PolygonTest, CoverageSumsToTheAreaOfAnyConvexPolygon) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-0.95f, 0.95f);
  const int res = 12;
  for (int trial = 0; trial < 200; ++trial) {
    // A random triangle and a random quad (convex hull of 4 points on a circle) on z = 1.
    Polygon p;
    const float cx = u(rng) * 0.5f, cy = u(rng) * 0.5f, r = 0.02f + 0.4f * std::fabs(u(rng));
    const int n = 3 + trial % 4;
    float angle = 0.0f;
    for (int i = 0; i < n; ++i) {
      angle += 0.2f + 1.2f * std::fabs(u(rng)) / n * 4.0f;
      if (angle > 6.2f) break;
      p.v[p.n++] = glm::vec3(cx + r * std::cos(angle), cy + r * std::sin(angle), 1.0f);
    }
    if (p.n < 3) continue;
    const auto m = Coverage(p, res);
    const double pixel_area = (2.0 / res) * (2.0 / res);
    double sum = 0;
    for (const auto& [pixel, c] : m) {
      EXPECT_LE(c, 1.0f + 1e-6f);
      sum += c * pixel_area;
    }
    EXPECT_NEAR(sum, PolygonArea(p), 2e-5 + 1e-4 * PolygonArea(p)) << trial;
  }
}

TEST(PolygonTest, SkipIsAskedAboutARectangleHoldingEveryCoveredPixel) {
  // The rasterizer skips a face's coverage when every pixel of the rectangle that skip() is
  // given is closed: that rectangle must hold every pixel the polygon covers there, on one face
  // and across several, and a face skipped must emit nothing.
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const int res = 12;
  int checked = 0, multi_face = 0;
  for (int trial = 0; trial < 300; ++trial) {
    // A random quad: a square of random size and tilt around a random point above the horizon.
    const glm::vec3 c(u(rng), u(rng), 0.2f + std::fabs(u(rng)));
    const glm::vec3 n = glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + 1e-3f);
    const glm::vec3 e1 = glm::normalize(glm::cross(
        n, std::fabs(n.x) < 0.9f ? glm::vec3(1.0f, 0.0f, 0.0f) : glm::vec3(0.0f, 1.0f, 0.0f)));
    const glm::vec3 e2 = glm::cross(n, e1);
    const float r = trial % 3 == 0 ? 0.8f * std::fabs(u(rng)) : 0.05f * std::fabs(u(rng));
    Polygon p =
        Quad(c - r * e1 - r * e2, c + r * e1 - r * e2, c + r * e1 + r * e2, c - r * e1 + r * e2);
    ClipHalfSpace(glm::vec3(0.0f, 0.0f, 1.0f), &p);
    if (p.n < 3) continue;
    struct Rect {
      int col0, col1, row0, row1;
    };
    std::map<uint32_t, Rect> rects;  // by the face's first pixel
    std::vector<float> acc;
    std::vector<PixelCoverage> covered;
    RasterizePolygonTo(
        p, res, &acc,
        [&](uint32_t pixel, float cov) {
          covered.push_back({pixel, cov});
        },
        [&](uint32_t first, int col0, int col1, int row0, int row1) {
          rects[first] = Rect{col0, col1, row0, row1};
          return false;
        });
    multi_face += rects.size() > 1;
    for (const PixelCoverage& pc : covered) {
      const uint32_t first = pc.pixel / (res * res) * (res * res);
      ASSERT_TRUE(rects.count(first)) << trial;
      const Rect& rc = rects[first];
      const int row = int(pc.pixel - first) / res, col = int(pc.pixel - first) % res;
      EXPECT_TRUE(col >= rc.col0 && col <= rc.col1 && row >= rc.row0 && row <= rc.row1)
          << trial << " pixel " << pc.pixel;
      ++checked;
    }
    // The same pixels as RasterizePolygon's, and none where every face is skipped.
    EXPECT_EQ(covered.size(), Coverage(p, res).size()) << trial;
    int skipped_emits = 0;
    RasterizePolygonTo(
        p, res, &acc, [&](uint32_t, float) { ++skipped_emits; },
        [](uint32_t, int, int, int, int) { return true; });
    EXPECT_EQ(skipped_emits, 0) << trial;
  }
  EXPECT_GT(checked, 1000);
  EXPECT_GT(multi_face, 10);
}

TEST(PolygonTest, PolygonsSharingAnEdgeTileTheirUnion) {
  // A quad cut by a line into two polygons: per pixel, the two coverages add up to the quad's.
  const int res = 12;
  const Polygon whole =
      Quad({-0.7f, -0.6f, 1.0f}, {0.5f, -0.4f, 1.0f}, {0.6f, 0.55f, 1.0f}, {-0.5f, 0.7f, 1.0f});
  Polygon left = whole, right = whole;
  const glm::vec3 m(1.0f, 0.3f, 0.05f);  // the cutting plane through the origin
  ClipHalfSpace(m, &left);
  ClipHalfSpace(-m, &right);
  ASSERT_GE(left.n, 3);
  ASSERT_GE(right.n, 3);
  auto a = Coverage(whole, res), l = Coverage(left, res), r = Coverage(right, res);
  for (const auto& [pixel, c] : a) {
    EXPECT_NEAR(l[pixel] + r[pixel], c, 2e-5f) << pixel;
  }
  for (const auto& [pixel, c] : l) EXPECT_TRUE(a.count(pixel)) << pixel;
}

std::map<uint32_t, uint64_t> Masks(const Polygon& p, int res) {
  std::vector<float> acc;
  std::map<uint32_t, uint64_t> m;
  RasterizePolygonTo(p, res, &acc,
                     [&](uint32_t pixel, float, const PixelSamples& s) { m[pixel] |= s.mask(); });
  return m;
}

// Coverage masks (Rasterizer::Layer()): a pixel-aligned half pixel holds exactly its half of the
// samples; the two parts of a quad cut by a line have disjoint masks whose union is the quad's
// (so the pieces of one solid that tile a pixel add up to it, and never count a sample twice);
// and over random polygons a mask's share of samples follows the exact coverage.
TEST(PolygonTest, CoverageMasksSampleThePolygon) {
  const int res = 8;  // face +z, pixel edges at x = -1 + k / 4
  const Polygon half = Quad({-0.5f, 0.0f, 1.0f}, {-0.375f, 0.0f, 1.0f}, {-0.375f, 0.25f, 1.0f},
                            {-0.5f, 0.25f, 1.0f});  // the left half of column 2, row 4
  const auto hm = Masks(half, res);
  ASSERT_EQ(hm.size(), 1u);
  EXPECT_EQ(hm.begin()->first, 4u * res * res + 4u * res + 2u);
  EXPECT_EQ(hm.begin()->second, 0x0f0f0f0f0f0f0f0full);  // sample columns 0..3 of every row

  const Polygon whole =
      Quad({-0.7f, -0.6f, 1.0f}, {0.5f, -0.4f, 1.0f}, {0.6f, 0.55f, 1.0f}, {-0.5f, 0.7f, 1.0f});
  Polygon left = whole, right = whole;
  const glm::vec3 m(1.0f, 0.3f, 0.05f);
  ClipHalfSpace(m, &left);
  ClipHalfSpace(-m, &right);
  auto a = Masks(whole, 12), l = Masks(left, 12), r = Masks(right, 12);
  for (const auto& [pixel, mask] : a) {
    EXPECT_EQ(l[pixel] & r[pixel], 0u) << pixel;
    EXPECT_EQ(l[pixel] | r[pixel], mask) << pixel;
  }

  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-0.9f, 0.9f);
  double err = 0.0;
  int pixels = 0;
  for (int trial = 0; trial < 100; ++trial) {
    Polygon p;
    p.n = 3;
    for (int i = 0; i < 3; ++i) p.v[i] = glm::vec3(u(rng), u(rng), 1.0f);
    std::vector<float> acc;
    RasterizePolygonTo(p, 12, &acc, [&](uint32_t, float cov, const PixelSamples& s) {
      const double share = std::popcount(s.mask()) / 64.0;
      EXPECT_NEAR(share, cov, 0.2);
      err += std::fabs(share - cov);
      ++pixels;
    });
  }
  EXPECT_LT(err / pixels, 0.03);
}

// The samples a polygon touches (RasterOptions::bound_by_footprints): against brute force, every
// point of random triangles lies in a sample cell marked touched in its pixel (the set is
// conservative, so the bound never cuts coverage), and the set is not much more than the
// coverage (the bound is tight: the cells along the edges).
TEST(PolygonTest, TouchedSamplesHoldEveryPointOfThePolygon) {
  using polygon_coverage::kMaskSide;
  const int res = 12;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-0.95f, 0.95f), w(0.0f, 1.0f);
  double excess = 0.0;
  int pixels = 0;
  for (int trial = 0; trial < 200; ++trial) {
    Polygon p;
    p.n = 3;
    // Small and slim triangles too: within a few pixels, some thinner than a sample.
    const glm::vec3 c(u(rng), u(rng), 1.0f);
    const float size = (trial / 2) % 2 ? 0.05f : 0.4f;
    for (int i = 0; i < 3; ++i) {
      p.v[i] =
          c + glm::vec3(size * (w(rng) - 0.5f), (trial % 3 ? size : 0.01f) * (w(rng) - 0.5f), 0.0f);
    }
    std::map<uint32_t, uint64_t> touched;
    std::map<uint32_t, float> cover;
    std::vector<float> acc;
    RasterizePolygonTo(p, res, &acc, [&](uint32_t pixel, float cov, const PixelSamples& s) {
      touched[pixel] |= s.touched();
      cover[pixel] += cov;
    });
    for (int k = 0; k < 4000; ++k) {
      float a = w(rng), b = w(rng);
      if (a + b > 1.0f) a = 1.0f - a, b = 1.0f - b;
      const glm::vec3 q = p.v[0] + a * (p.v[1] - p.v[0]) + b * (p.v[2] - p.v[0]);
      if (!(std::fabs(q.x) < 1.0f && std::fabs(q.y) < 1.0f)) continue;  // off the face
      const float fx = (q.x + 1.0f) * 0.5f * res, fy = (q.y + 1.0f) * 0.5f * res;
      const int col = std::min(res - 1, static_cast<int>(fx)),
                row = std::min(res - 1, static_cast<int>(fy));
      const int i = std::min(kMaskSide - 1, static_cast<int>((fx - col) * kMaskSide)),
                j = std::min(kMaskSide - 1, static_cast<int>((fy - row) * kMaskSide));
      const uint32_t pixel = 4u * res * res + static_cast<uint32_t>(row * res + col);
      if (!cover.count(pixel)) continue;  // coverage below the sink's 1e-6 floor
      ASSERT_TRUE(touched.count(pixel)) << trial << " " << pixel;
      EXPECT_TRUE((touched[pixel] >> (j * kMaskSide + i)) & 1u)
          << "trial " << trial << " pixel " << pixel << " sample " << i << "," << j;
    }
    for (const auto& [pixel, bits] : touched) {
      excess += std::popcount(bits) / 64.0 - std::min(1.0f, cover[pixel]);
      ++pixels;
    }
  }
  EXPECT_GT(pixels, 200);
  EXPECT_LT(excess / pixels, 0.2);
}

// The spans of Spans() and BandSpans(), found eight sample rows at a time, against the same
// expressions one row at a time (the code before they took lanes): the same bits in every row,
// over random convex polygons with vertices on sample rows, band edges and each other's rows
// (horizontal edges), small and large, so the masks and touched samples cannot move.
void SpansOneRowAtATime(const polygon_coverage::Poly2& p, int y0, int y1, bool bands,
                        polygon_coverage::MaskSpans* s) {
  using polygon_coverage::CeilPos;
  using polygon_coverage::kMaskSide;
  s->row0 = y0 * kMaskSide;
  s->rows = std::min((y1 - y0 + 1) * kMaskSide, polygon_coverage::kMaxMaskRows);
  for (int j = 0; j < s->rows; ++j) s->xl[j] = 1e30f, s->xr[j] = -1e30f;
  constexpr float kSide = kMaskSide;
  for (int i = 0; i < p.n; ++i) {
    const int k = i + 1 == p.n ? 0 : i + 1;
    float ax = p.x[i], ay = p.y[i], bx = p.x[k], by = p.y[k];
    if (!bands && ay == by) continue;
    if (ay > by) std::swap(ax, bx), std::swap(ay, by);
    if (!bands) {
      const int j0 = std::max(s->row0, CeilPos(std::max(0.0f, ay * kSide - 0.5f)));
      const int j1 = std::min(s->row0 + s->rows, CeilPos(std::max(0.0f, by * kSide - 0.5f)));
      const float slope = (bx - ax) / (by - ay);
      for (int j = j0; j < j1; ++j) {
        const float y = (static_cast<float>(j) + 0.5f) / kSide;
        const float x = ax + (y - ay) * slope;
        s->xl[j - s->row0] = std::min(s->xl[j - s->row0], x);
        s->xr[j - s->row0] = std::max(s->xr[j - s->row0], x);
      }
      continue;
    }
    const int j0 = std::max(s->row0, static_cast<int>(std::floor(ay * kSide)));
    const int j1 = std::min(s->row0 + s->rows - 1, static_cast<int>(std::floor(by * kSide)));
    const float slope = by > ay ? (bx - ax) / (by - ay) : 0.0f;
    for (int j = j0; j <= j1; ++j) {
      const float lo = std::max(ay, static_cast<float>(j) / kSide);
      const float hi = std::min(by, static_cast<float>(j + 1) / kSide);
      const float xa = by > ay ? ax + (lo - ay) * slope : std::min(ax, bx);
      const float xb = by > ay ? ax + (hi - ay) * slope : std::max(ax, bx);
      s->xl[j - s->row0] = std::min({s->xl[j - s->row0], xa, xb});
      s->xr[j - s->row0] = std::max({s->xr[j - s->row0], xa, xb});
    }
  }
}

TEST(PolygonTest, SpansInLanesMatchOneRowAtATime) {
  using polygon_coverage::MaskSpans;
  using polygon_coverage::Poly2;
  std::mt19937 rng(16);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  auto spans = std::make_unique<MaskSpans[]>(4);  // 16 KB: off the stack
  int rows = 0, differ = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    const int res = trial % 3 == 0 ? 12 : trial % 3 == 1 ? 8 : 64;
    const float size = trial % 4 == 0   ? 0.2f
                       : trial % 4 == 1 ? 1.0f
                       : trial % 4 == 2 ? 4.0f
                                        : 30.0f;
    const float cx = u(rng) * res, cy = u(rng) * res, r = size * u(rng),
                start = 6.2831853f * u(rng);
    Poly2 p;
    p.n = 3 + static_cast<int>(rng() % 6);
    for (int i = 0; i < p.n; ++i) {
      const float angle = start + 6.2831853f * static_cast<float>(i) / static_cast<float>(p.n);
      float x = cx + r * std::cos(angle), y = cy + r * std::sin(angle);
      if (rng() % 5 == 0) y = std::round(y * 8.0f) / 8.0f + (rng() % 2 ? 0.0625f : 0.0f);
      if (i > 0 && rng() % 7 == 0) y = p.y[i - 1];
      p.x[i] = std::min(static_cast<float>(res), std::max(0.0f, x));
      p.y[i] = std::min(static_cast<float>(res), std::max(0.0f, y));
    }
    float miny = 1e30f, maxy = -1e30f;
    for (int i = 0; i < p.n; ++i) miny = std::min(miny, p.y[i]), maxy = std::max(maxy, p.y[i]);
    const int y0 = std::min(res - 1, static_cast<int>(miny));
    const int y1 = std::min(res - 1, std::max(y0, polygon_coverage::CeilPos(maxy) - 1));
    polygon_coverage::Spans(p, y0, y1, &spans[0]);
    SpansOneRowAtATime(p, y0, y1, /*bands=*/false, &spans[1]);
    polygon_coverage::BandSpans(p, y0, y1, &spans[2]);
    SpansOneRowAtATime(p, y0, y1, /*bands=*/true, &spans[3]);
    for (int pair = 0; pair < 4; pair += 2) {
      const MaskSpans &lanes = spans[pair], &one = spans[pair + 1];
      ASSERT_EQ(lanes.row0, one.row0);
      ASSERT_EQ(lanes.rows, one.rows);
      for (int j = 0; j < one.rows; ++j) {
        ++rows;
        differ += std::memcmp(&lanes.xl[j], &one.xl[j], sizeof(float)) != 0 ||
                  std::memcmp(&lanes.xr[j], &one.xr[j], sizeof(float)) != 0;
      }
    }
  }
  EXPECT_EQ(differ, 0) << "of " << rows << " rows";
  EXPECT_GT(rows, 100000);
}

// SplitLanes() and AbsArea2Lanes() (the 2 x 2-block path with lanes) against Split() and Area2():
// the same parts vertex for vertex and the same |area| bit for bit, over polygons of one to eight
// vertices within two pixels of the split line, with vertices on the line (of either zero sign
// relative to it), runs of vertices along it, repeated vertices, not quite convex polygons (as
// Project()'s clamping leaves them), and stale lanes past n.
TEST(PolygonTest, SplitAndAreaInLanesMatchOneVertexAtATime) {
  using polygon_coverage::Poly2;
  std::mt19937 rng(28);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  int parts = 0, differ = 0, crossings = 0;
  auto same_part = [](const Poly2& a, const Poly2& b) {
    return a.n == b.n && std::memcmp(a.x, b.x, a.n * sizeof(float)) == 0 &&
           std::memcmp(a.y, b.y, a.n * sizeof(float)) == 0;
  };
  for (int trial = 0; trial < 100000; ++trial) {
    const float line = static_cast<float>(1 + rng() % 10);
    Poly2 p;
    // Stale lanes: NaN, huge, or a previous polygon's.
    for (int i = 0; i < 8; ++i) {
      p.x[i] = trial % 3 == 0 ? std::numeric_limits<float>::quiet_NaN() : 1e6f * u(rng);
      p.y[i] = trial % 5 == 0 ? -std::numeric_limits<float>::infinity() : 1e6f * u(rng);
    }
    p.n = 1 + static_cast<int>(rng() % 8);
    const float cx = line - 1.0f + 2.0f * u(rng), cy = line - 1.0f + 2.0f * u(rng);
    const float r = trial % 4 == 0 ? 0.05f * u(rng) : 1.2f * u(rng), start = 6.2831853f * u(rng);
    for (int i = 0; i < p.n; ++i) {
      const float angle = start + 6.2831853f * static_cast<float>(i) / static_cast<float>(p.n);
      float x = cx + r * std::cos(angle), y = cy + r * std::sin(angle);
      if (rng() % 4 == 0) x = line;
      if (rng() % 6 == 0) y = line;
      if (i > 0 && rng() % 8 == 0) x = p.x[i - 1], y = p.y[i - 1];
      if (rng() % 10 == 0) x = std::clamp(x, line - 0.5f, line + 0.25f);  // clamped: not convex
      p.x[i] = x, p.y[i] = y;
    }
    for (int coord = 0; coord < 2; ++coord) {
      Poly2 lanes[2], one[2];
      polygon_coverage::SplitLanes(p, coord, line, &lanes[0], &lanes[1]);
      polygon_coverage::Split(p, coord, line, &one[0], &one[1]);
      crossings += one[0].n + one[1].n > p.n;
      for (int k = 0; k < 2; ++k) {
        ++parts;
        const bool same = same_part(lanes[k], one[k]);
        differ += !same;
        if (!same || one[k].n > 8) continue;
        const float a = polygon_coverage::AbsArea2Lanes(one[k]);
        const float b = std::fabs(polygon_coverage::Area2(one[k]));
        differ += std::memcmp(&a, &b, sizeof a) != 0;
      }
    }
  }
  EXPECT_EQ(differ, 0) << "of " << parts << " parts";
  EXPECT_GT(crossings, 50000);
}

// RasterizePolygonTo() finds a polygon's faces and projects it in lanes (up to eight vertices):
// against the one-vertex-at-a-time form, the same pixels, coverages, coverage masks, touched
// samples and skip() rectangles, bit for bit, over polygons on one face and across several,
// with vertices on the faces' edges and corners, at the apex, and with stale vertices past n.
TEST(PolygonTest, RasterizePolygonInLanesMatchesOneVertexAtATime) {
  std::mt19937 rng(19);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  struct Out {
    std::vector<uint32_t> pixels, rects;
    std::vector<float> covs;
    std::vector<uint64_t> masks, touched;
  };
  auto run = [](auto lanes, const Polygon& p, int res, Out* o) {
    std::vector<float> acc;
    RasterizePolygonIn<decltype(lanes)::value>(
        p, res, &acc,
        [&](uint32_t pixel, float cov, const PixelSamples& t) {
          o->pixels.push_back(pixel);
          o->covs.push_back(cov);
          o->masks.push_back(t.mask());
          o->touched.push_back(t.touched());
        },
        [&](uint32_t first, int col0, int col1, int row0, int row1) {
          o->rects.insert(o->rects.end(),
                          {first, uint32_t(col0), uint32_t(col1), uint32_t(row0), uint32_t(row1)});
          return false;
        });
  };
  int polygons = 0, multi_face = 0, differ = 0;
  for (int trial = 0; trial < 40000; ++trial) {
    const int res = trial % 3 == 0 ? 12 : trial % 3 == 1 ? 8 : 5;
    Polygon p;
    // Stale vertices past n, as a reused polygon has them.
    for (glm::vec3& v : p.v) v = glm::vec3(1e3f * u(rng), 1e3f * u(rng), -1e3f);
    if (trial % 7 == 3) p.v[11] = glm::vec3(std::numeric_limits<float>::quiet_NaN());
    const glm::vec3 d = glm::normalize(glm::vec3(u(rng), u(rng), std::fabs(u(rng))) + 1e-3f);
    const glm::vec3 e1 = glm::normalize(
        glm::cross(d, std::fabs(d.x) < 0.9f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0)));
    const glm::vec3 e2 = glm::cross(d, e1);
    const float r = trial % 4 == 0 ? 1.5f * std::fabs(u(rng)) : 0.3f * std::fabs(u(rng));
    p.n = 3 + static_cast<int>(rng() % (trial % 5 == 0 ? kMaxPolygonVertices - 2 : 6));
    const float start = 3.14159f * u(rng);
    for (int i = 0; i < p.n; ++i) {
      const float angle = start + 6.2831853f * static_cast<float>(i) / p.n;
      glm::vec3 x = d + r * (std::cos(angle) * e1 + std::sin(angle) * e2);
      // Vertices on a face's edge (|x| = |y|), on a corner, at zero of either sign.
      if (rng() % 9 == 0) x.y = (rng() % 2 ? 1.0f : -1.0f) * std::fabs(x.x);
      if (rng() % 13 == 0) x.z = std::fabs(x.x), x.y = std::fabs(x.x);
      if (rng() % 11 == 0) x[rng() % 3] = rng() % 2 ? 0.0f : -0.0f;
      p.v[i] = x;
    }
    if (trial % 50 == 7) p.v[0] = glm::vec3(0.0f);  // at the apex
    ClipHalfSpace(glm::vec3(0.0f, 0.0f, 1.0f), &p);
    if (p.n < 3) continue;
    ++polygons;
    Out lanes, one;
    run(std::true_type{}, p, res, &lanes);
    run(std::false_type{}, p, res, &one);
    multi_face += one.rects.size() > 5;
    const bool same =
        lanes.pixels == one.pixels && lanes.rects == one.rects && lanes.masks == one.masks &&
        lanes.touched == one.touched && lanes.covs.size() == one.covs.size() &&
        // (memcmp of empty vectors' data(), which may be null, is undefined: UBSan)
        (one.covs.empty() ||
         std::memcmp(lanes.covs.data(), one.covs.data(), one.covs.size() * sizeof(float)) == 0);
    differ += !same;
  }
  EXPECT_EQ(differ, 0) << "of " << polygons;
  EXPECT_GT(polygons, 30000);
  EXPECT_GT(multi_face, 3000);
}

// BoxDotRange() against the eight corners' dot products (the code before it): the same values
// over random boxes, flat ones and normals with zero components included.
TEST(PolygonTest, BoxDotRangeIsTheCornersOwnExtremes) {
  std::mt19937 rng(16);
  std::uniform_real_distribution<float> u(-10.0f, 10.0f);
  int differ = 0, trials = 0;
  for (int trial = 0; trial < 200000; ++trial) {
    Bounds b;
    glm::vec3 n, o;
    for (int k = 0; k < 3; ++k) {
      const float x = u(rng), e = rng() % 5 == 0 ? 0.0f : std::fabs(u(rng)) * 0.1f;
      b.lo[k] = x, b.hi[k] = x + e;
      n[k] = rng() % 6 == 0 ? 0.0f : u(rng) * 0.1f;
      o[k] = rng() % 4 == 0 ? b.lo[k] : u(rng);
    }
    float lo = 0.0f, hi = 0.0f;
    BoxDotRange(b, n, o, &lo, &hi);
    float want_lo = std::numeric_limits<float>::infinity(), want_hi = -want_lo;
    for (int i = 0; i < 8; ++i) {
      const glm::vec3 corner((i & 1) ? b.hi.x : b.lo.x, (i & 2) ? b.hi.y : b.lo.y,
                             (i & 4) ? b.hi.z : b.lo.z);
      const float t = glm::dot(n, corner - o);
      want_lo = std::min(want_lo, t);
      want_hi = std::max(want_hi, t);
    }
    ++trials;
    differ += !(lo == want_lo) || !(hi == want_hi);
  }
  EXPECT_EQ(differ, 0) << "of " << trials;
}

// ConeSolidAngle() finds four triangles' N and D at a time: against the code it replaced, one
// triangle at a time, the same float to the bit, over box silhouettes (its caller's polygons),
// near and far, and random convex polygons of 3 to 12 vertices, large and tiny.
float ConeSolidAngleOneTriangleAtATime(const Polygon& p) {
  if (p.n < 3) return 0.0f;
  float len[kMaxPolygonVertices];
  for (int i = 0; i < p.n; ++i) len[i] = glm::length(p.v[i]);
  const glm::vec3& a = p.v[0];
  float re = 1.0f, im = 0.0f, orient = 0.0f;
  for (int i = 1; i + 1 < p.n; ++i) {
    const glm::vec3& b = p.v[i];
    const glm::vec3& c = p.v[i + 1];
    const float num = glm::dot(a, glm::cross(b - a, c - a));
    const float den = len[0] * len[i] * len[i + 1] + glm::dot(a, b) * len[i + 1] +
                      glm::dot(a, c) * len[i] + glm::dot(b, c) * len[0];
    const float big = std::max(std::fabs(num), std::fabs(den));
    if (!(big > 0.0f)) continue;
    const float zr = den / big, zi = num / big;
    const float r = re * zr - im * zi;
    im = re * zi + im * zr;
    re = r;
    orient += num;
  }
  if (orient < 0.0f) im = -im;  // the vertices turn clockwise seen from the origin
  float half = std::atan2(im, re);
  if (half < 0.0f) half = re < 0.0f ? half + 2.0f * static_cast<float>(sh::kPi) : 0.0f;
  return 2.0f * half;
}

TEST(PolygonTest, ConeSolidAngleInLanesMatchesOneTriangleAtATime) {
  std::mt19937 rng(16);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  int differ = 0, polygons = 0;
  for (int trial = 0; trial < 100000; ++trial) {
    Polygon q;
    if (trial % 2 == 0) {
      const float scale = trial % 6 == 0 ? 200.0f : trial % 6 == 2 ? 20.0f : 2.0f;
      const glm::vec3 lo(scale * u(rng), scale * u(rng), scale * u(rng));
      const glm::vec3 ext(0.01f + std::fabs(u(rng)), 0.01f + std::fabs(u(rng)),
                          0.01f + std::fabs(u(rng)));
      const glm::vec3 hi = lo + ext;
      bool inside = true;
      int mask = 0;
      for (int k = 0; k < 3; ++k) {
        inside &= lo[k] <= 0.0f && hi[k] >= 0.0f;
        mask |= (lo[k] > 0.0f || hi[k] < 0.0f) ? 1 << k : 0;
      }
      if (inside) continue;
      BoxSilhouette(lo, hi, mask, &q);
    } else {
      // A regular-ish polygon around a random direction at a random distance.
      const glm::vec3 d = glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + 1e-3f);
      const glm::vec3 e1 = glm::normalize(
          glm::cross(d, std::fabs(d.x) < 0.9f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0)));
      const glm::vec3 e2 = glm::cross(d, e1);
      const float dist = std::exp(4.0f * u(rng)), r = dist * std::exp(3.0f * u(rng) - 2.0f);
      q.n = 3 + static_cast<int>(rng() % (kMaxPolygonVertices - 2));
      const float start = 3.14159f * u(rng), turn = trial % 4 == 1 ? -1.0f : 1.0f;
      for (int i = 0; i < q.n; ++i) {
        const float angle = start + turn * 6.2831853f * static_cast<float>(i) / q.n;
        q.v[i] = dist * d + r * (std::cos(angle) * e1 + std::sin(angle) * e2);
      }
    }
    if (q.n < 3) continue;
    ++polygons;
    const float got = ConeSolidAngle(q), want = ConeSolidAngleOneTriangleAtATime(q);
    differ += std::memcmp(&got, &want, sizeof got) != 0;
  }
  EXPECT_EQ(differ, 0) << "of " << polygons;
  EXPECT_GT(polygons, 80000);
}

TEST(PolygonTest, APolygonAcrossFacesKeepsItsSolidAngle) {
  // A large square at distance 1 below the receiver's zenith, tilted, spanning five faces:
  // sum over pixels of coverage * pixel solid angle approaches the polygon's solid angle (the
  // face-plane area fraction is not exactly the solid-angle fraction inside a pixel).
  MicroBuffer mb;
  ASSERT_TRUE(mb.Prepare(32).ok());
  const int res = 32;
  const Polygon p =
      Quad({-3.0f, -3.0f, 0.4f}, {3.0f, -3.0f, 0.4f}, {3.0f, 3.0f, 0.4f}, {-3.0f, 3.0f, 0.4f});
  const auto m = Coverage(p, res);
  double omega = 0;
  for (const auto& [pixel, c] : m) omega += c * mb.PixelSolidAngle(int(pixel));
  // Solid angle of the square [-3, 3]^2 at height 0.4: 4 atan(a b / (h sqrt(h^2 + a^2 + b^2))).
  const double a = 3, h = 0.4;
  const double exact = 4.0 * std::atan(a * a / (h * std::sqrt(h * h + 2 * a * a)));
  EXPECT_NEAR(omega, exact, 0.01 * exact);
}

TEST(PolygonTest, PlaneBoxPolygonIsTheCrossSection) {
  Polygon p;
  // The plane z = 0.25 through the unit box: the square [0,1]^2 at z = 0.25.
  PlaneBoxPolygon({0, 0, 1}, 0.25f, {0, 0, 0}, {1, 1, 1}, &p);
  EXPECT_EQ(p.n, 4);
  EXPECT_NEAR(PolygonArea(p), 1.0, 1e-5);
  // The diagonal plane x + y + z = 1.5 cuts the unit cube in a regular hexagon of side
  // sqrt(2) / 2: area 3 sqrt(3) / 2 * s^2 = 3 sqrt(3) / 4.
  PlaneBoxPolygon(glm::normalize(glm::vec3(1, 1, 1)), 1.5f / std::sqrt(3.0f), {0, 0, 0}, {1, 1, 1},
                  &p);
  EXPECT_EQ(p.n, 6);
  EXPECT_NEAR(PolygonArea(p), 3.0 * std::sqrt(3.0) / 4.0, 1e-4);
  // A flat box (a wall's cluster) and its own plane.
  PlaneBoxPolygon({1, 0, 0}, 2.0f, {2, -1, -1}, {2, 1, 1}, &p);
  EXPECT_NEAR(PolygonArea(p), 4.0, 1e-3);
  // A plane that misses the box.
  PlaneBoxPolygon({0, 0, 1}, 3.0f, {0, 0, 0}, {1, 1, 1}, &p);
  EXPECT_EQ(p.n, 0);
}

// The solid angle of an axis-aligned rectangle {z = h, [x0, x1] x [y0, y1]} seen from the
// origin: the signed sum of the four rectangles from the foot point (double precision).
double RectangleSolidAngle(double x0, double x1, double y0, double y1, double h) {
  auto corner = [h](double a, double b) {
    return std::atan(a * b / (h * std::sqrt(h * h + a * a + b * b)));
  };
  return corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0);
}

// The faces of the box [lo, hi] that the origin sees, each with its solid angle (double).
std::vector<std::pair<Polygon, double>> SeenFaces(const glm::vec3& lo, const glm::vec3& hi) {
  std::vector<std::pair<Polygon, double>> faces;
  for (int k = 0; k < 3; ++k) {
    const float at = lo[k] > 0.0f ? lo[k] : hi[k] < 0.0f ? hi[k] : 0.0f;
    if (at == 0.0f) continue;
    const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
    Polygon q;
    q.n = 4;
    for (int j = 0; j < 4; ++j) {
      q.v[j][k] = at;
      q.v[j][k1] = (j == 1 || j == 2) ? hi[k1] : lo[k1];
      q.v[j][k2] = (j >= 2) ? hi[k2] : lo[k2];
    }
    faces.push_back({q, RectangleSolidAngle(lo[k1], hi[k1], lo[k2], hi[k2], std::fabs(at))});
  }
  return faces;
}

TEST(PolygonTest, BoxSilhouetteCoversWhatItsSeenFacesCover) {
  // Boxes seen across one, two and three faces, near and far, with the origin above the
  // horizon (z > 0 half-space: the boxes' lowest corner may lie below it).
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const int res = 12;
  int by_count[4] = {0, 0, 0, 0};
  for (int trial = 0; trial < 300; ++trial) {
    const float scale = trial % 3 == 0 ? 20.0f : 2.0f;
    glm::vec3 lo(scale * u(rng), scale * u(rng), scale * std::fabs(u(rng)));
    const glm::vec3 ext(0.05f + std::fabs(u(rng)), 0.05f + std::fabs(u(rng)),
                        0.05f + std::fabs(u(rng)));
    if (trial % 5 == 1) lo.x = -0.5f * ext.x, lo.y = -0.5f * ext.y;  // one face, overhead
    glm::vec3 hi = lo + ext;
    bool inside = true;
    for (int k = 0; k < 3; ++k) inside &= lo[k] <= 0.0f && hi[k] >= 0.0f;
    if (inside) continue;
    const auto faces = SeenFaces(lo, hi);
    int mask = 0;
    for (int k = 0; k < 3; ++k) mask |= (lo[k] > 0.0f || hi[k] < 0.0f) ? 1 << k : 0;
    ++by_count[faces.size()];
    Polygon sil;
    BoxSilhouette(lo, hi, mask, &sil);
    ASSERT_GE(sil.n, 4);
    // Its solid angle is the faces' sum.
    double omega = 0;
    for (const auto& f : faces) omega += f.second;
    EXPECT_NEAR(ConeSolidAngle(sil), omega, 2e-4 * omega + 1e-7) << trial;
    // Its coverage, pixel by pixel, is the faces' sum (above the horizon).
    ClipHalfSpace({0, 0, 1}, &sil);
    std::map<uint32_t, float> want;
    for (auto f : faces) {
      ClipHalfSpace({0, 0, 1}, &f.first);
      for (const auto& [pixel, c] : Coverage(f.first, res)) want[pixel] += c;
    }
    const auto got = Coverage(sil, res);
    for (const auto& [pixel, c] : want) {
      const auto it = got.find(pixel);
      EXPECT_NEAR(it == got.end() ? 0.0f : it->second, std::min(1.0f, c), 2e-4f)
          << trial << " pixel " << pixel;
    }
    for (const auto& [pixel, c] : got) EXPECT_TRUE(want.count(pixel) || c < 2e-4f) << pixel;
  }
  EXPECT_GT(by_count[1], 10);
  EXPECT_GT(by_count[2], 10);
  EXPECT_GT(by_count[3], 10);
}

TEST(PolygonTest, ConeSolidAngleOfNearAndFarSquares) {
  // The square [-a, a]^2 at height h, from nearly a hemisphere to a speck: 4 atan(a^2 / (h
  // sqrt(h^2 + 2 a^2))).
  for (const double h : {1e-3, 0.1, 1.0, 10.0, 1e3}) {
    const double a = 1.0;
    const Polygon p =
        Quad({-1, -1, float(h)}, {1, -1, float(h)}, {1, 1, float(h)}, {-1, 1, float(h)});
    const double exact = 4.0 * std::atan(a * a / (h * std::sqrt(h * h + 2 * a * a)));
    EXPECT_NEAR(ConeSolidAngle(p), exact, 1e-5 * exact) << h;
  }
}

}  // namespace
}  // namespace pbgi::internal
