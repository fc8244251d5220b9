// The scene sampler: exact counts, area, normals, stratification and determinism (per seed,
// per chunk size, per thread count).
#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/scene.h"
#include "scene/sample_math.h"
#include "tbb/task_arena.h"

namespace pbgi {
namespace {

std::vector<Surfel> Drain(SurfelSource& source, size_t batch = 10007) {
  std::vector<Surfel> all, buf(batch);
  for (;;) {
    auto n = source.Next(absl::MakeSpan(buf));
    EXPECT_TRUE(n.ok()) << n.status();
    if (!n.ok() || *n == 0) break;
    all.insert(all.end(), buf.begin(), buf.begin() + static_cast<long>(*n));
  }
  return all;
}

std::vector<Surfel> Sample(const Scene& scene, SamplerOptions options) {
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(scene), options);
  EXPECT_TRUE(source.ok()) << source.status();
  if (!source.ok()) return {};
  return Drain(**source);
}

bool SameSurfels(const std::vector<Surfel>& a, const std::vector<Surfel>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (a[i].position != b[i].position || a[i].normal != b[i].normal ||
        a[i].radius != b[i].radius || a[i].radiance != b[i].radiance) {
      return false;
    }
  }
  return true;
}

Scene Small(const std::string& name) {
  SceneOptions o;
  o.seed = 7;
  o.size = 3;  // small city and forest keep the test fast
  auto s = MakeScene(name, o);
  EXPECT_TRUE(s.ok()) << s.status();
  return *s;
}

class SamplerSceneTest : public ::testing::TestWithParam<std::string> {};

TEST_P(SamplerSceneTest, CountAreaNormalsAndBounds) {
  Scene scene = Small(GetParam());
  SamplerOptions o;
  o.count = 50021;
  o.bake = false;
  o.chunk_size = 4099;    // many chunks, odd boundaries
  o.drop_hidden = false;  // all the area (hidden_test.cc checks the visible-area contract)
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(scene), o);
  ASSERT_TRUE(source.ok()) << source.status();
  EXPECT_EQ((*source)->KnownCount(), o.count);
  std::vector<Surfel> s = Drain(**source);
  // The count is exact (the issue asks for 1%).
  EXPECT_EQ(static_cast<int64_t>(s.size()), o.count);
  double area = 0.0;
  Bounds b = (*source)->KnownBounds();
  glm::vec3 pad = 1e-4f * (b.Extent() + glm::vec3(1.0f));
  b.lo -= pad;
  b.hi += pad;
  int off_bounds = 0, bad_normals = 0;
  for (const Surfel& sf : s) {
    area += sf.Area();
    if (!b.Contains(sf.position)) ++off_bounds;
    if (std::abs(glm::length(sf.normal) - 1.0f) > 1e-5f) ++bad_normals;
  }
  EXPECT_NEAR(area / scene.SurfaceArea(), 1.0, 0.02);
  EXPECT_EQ(off_bounds, 0);
  EXPECT_EQ(bad_normals, 0);
}

INSTANTIATE_TEST_SUITE_P(AllScenes, SamplerSceneTest,
                         ::testing::Values("cornell", "city", "forest", "disk", "sphere-in-box"),
                         [](const auto& info) {
                           std::string n = info.param;
                           for (char& c : n) {
                             if (c == '-') c = '_';
                           }
                           return n;
                         });

TEST(SamplerTest, DensityGivesAreaTimesDensity) {
  Scene scene = Small("cornell");
  SamplerOptions o;
  o.density = 20000.0;
  o.bake = false;
  o.drop_hidden = false;
  std::vector<Surfel> s = Sample(scene, o);
  EXPECT_EQ(static_cast<int64_t>(s.size()), std::llround(scene.SurfaceArea() * o.density));
}

// Two quads of areas 1 and 3: systematic sampling gives each its share to within one surfel.
TEST(SamplerTest, StratifiedAcrossTriangles) {
  Scene scene;
  scene.materials.push_back({});
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                 {2, 0, 0}, {5, 0, 0}, {5, 1, 0}, {2, 1, 0}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {4, 6, 7}};
  m.materials = {0, 0, 0, 0};
  scene.meshes.push_back(m);
  scene.instances.push_back({0, glm::mat4(1.0f), -1});
  SamplerOptions o;
  o.count = 10000;
  o.bake = false;
  std::vector<Surfel> s = Sample(scene, o);
  ASSERT_EQ(s.size(), 10000u);
  int left = 0;
  // And stratified inside each quad: every 0.1 x 0.1 cell of the unit quad gets 25 +- 5 (for
  // independent uniform points, 5 is one standard deviation: a third of the cells would fail).
  std::vector<int> cells(100, 0);
  for (const Surfel& sf : s) {
    if (sf.position.x < 1.5f) {
      ++left;
      int cx = std::min(9, static_cast<int>(sf.position.x * 10));
      int cy = std::min(9, static_cast<int>(sf.position.y * 10));
      ++cells[cy * 10 + cx];
    }
  }
  EXPECT_NEAR(left, 2500, 2);
  for (int c = 0; c < 100; ++c) EXPECT_NEAR(cells[c], 25, 5) << "cell " << c;
}

// Pieces of equal area: their centres average to the triangle's centroid (as unequal pieces'
// would not), each lies inside the triangle, and no two coincide.
TEST(SamplerTest, EqualAreaPiecesAverageToTheCentroid) {
  const glm::vec3 tris[][3] = {{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}},
                               {{0, 0, 0}, {0.12f, 0, 0}, {0, 4, 0}},    // a trunk face's half
                               {{0, 0, 0}, {5, 0, 0}, {2.5f, 0.3f, 0}},  // obtuse, flat
                               {{1, 2, 3}, {2, 2.5f, 3.5f}, {1.2f, 3, 2}}};
  for (const auto& t : tris) {
    const glm::vec3 centroid = (t[0] + t[1] + t[2]) / 3.0f;
    const glm::vec3 n = glm::cross(t[1] - t[0], t[2] - t[0]);
    for (uint64_t k : {1, 2, 3, 5, 7, 16, 31}) {
      glm::dvec3 sum(0.0);
      std::vector<glm::vec3> pts;
      for (uint64_t j = 0; j < k; ++j) {
        const glm::vec3 p = internal::EqualAreaPiecePoint(t[0], t[1], t[2], j, k);
        sum += glm::dvec3(p);
        for (int e = 0; e < 3; ++e) {  // inside: on the inner side of each edge
          const float side = glm::dot(glm::cross(t[(e + 1) % 3] - t[e], p - t[e]), n);
          EXPECT_GT(side, 0.0f) << "k " << k << " j " << j;
        }
        for (const glm::vec3& q : pts) EXPECT_GT(glm::length(p - q), 1e-4f);
        pts.push_back(p);
      }
      const glm::vec3 mean(sum / static_cast<double>(k));
      EXPECT_LT(glm::length(mean - centroid), 1e-5f * glm::length(t[1] - t[0])) << "k " << k;
    }
  }
}

// Along a narrow triangle, sample j of k sits (j + 1/4) / k of the longest edge from the end
// where the triangle is wider, in the middle of its width there; a narrow quad's two triangles
// then interleave their samples evenly along it.
TEST(SamplerTest, StripPointsInterleaveAlongANarrowQuad) {
  const glm::vec3 q0(0, 0, 0), q1(0.12f, 0, 0), q2(0.12f, 4, 0), q3(0, 4, 0);
  for (uint64_t k : {2, 3, 6, 12}) {
    std::vector<float> ys;
    for (const auto& tri : {std::array<glm::vec3, 3>{q0, q1, q2}, {q0, q2, q3}}) {
      for (uint64_t j = 0; j < k; ++j) {
        const glm::vec3 p = internal::StripPoint(tri[0], tri[1], tri[2], j, k);
        ys.push_back(p.y);
        // In the middle of the triangle's width at that height (its sides are x = 0.12 or 0
        // and the diagonal x = 0.03 y).
        const float diag = 0.03f * p.y;
        const float mid = tri[2] == q2 ? 0.5f * (diag + 0.12f) : 0.5f * diag;
        EXPECT_NEAR(p.x, mid, 2e-3f) << "k " << k << " j " << j;
      }
    }
    std::sort(ys.begin(), ys.end());
    for (size_t i = 0; i < ys.size(); ++i) {
      // 2k points evenly along the quad, (i + 1/2) of a 4 / (2k) spacing.
      EXPECT_NEAR(ys[i], (i + 0.5f) * 4.0f / (2 * k), 0.03f * 4.0f / k) << "k " << k;
    }
  }
}

// What the pieces are for: a cloud of disks that covers small and narrow triangles where they
// are. A scene of 200 leaves (0.36 x 0.24, two or three surfels each, as the forest's at 2 M) and
// a trunk's face (0.12 x 4, narrower than the 0.2 spacing), with a floor that sets the density.
// Counted on a fine grid of each surface: how much of it the disks of its own surfels cover, and
// how much of their area hangs over its edges; and along the face, the longest stretch no disk
// reaches. Placement::kUniform (the rotated Hammersley set) is the comparison.
TEST(SamplerTest, PiecesCoverSmallAndNarrowTriangles) {
  Scene scene;
  scene.materials.push_back({});
  Mesh m;
  auto quad = [&m](glm::vec3 p, float w, float h) {
    const uint32_t i = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(),
                       {p, p + glm::vec3(w, 0, 0), p + glm::vec3(w, h, 0), p + glm::vec3(0, h, 0)});
    m.triangles.push_back({i, i + 1, i + 2});
    m.triangles.push_back({i, i + 2, i + 3});
    m.materials.insert(m.materials.end(), {0, 0});
  };
  for (int i = 0; i < 200; ++i) quad(glm::vec3(i % 20, i / 20, 0), 0.36f, 0.24f);
  quad(glm::vec3(30, 0, 0), 0.12f, 4.0f);
  quad(glm::vec3(40, 0, 0), 10.0f, 10.0f);  // the floor
  scene.meshes.push_back(m);
  scene.instances.push_back({0, glm::mat4(1.0f), -1});
  const double area = 200 * 0.36 * 0.24 + 0.48 + 100.0;
  struct Cover {
    double leaf_covered = 0, leaf_overhang = 0, strip_gap = 0;
  };
  auto measure = [&](SamplerOptions::Placement placement) {
    SamplerOptions o;
    o.count = std::llround(area / 0.04);  // 0.2 spacing
    o.bake = false;
    o.drop_hidden = false;
    o.placement = placement;
    const std::vector<Surfel> s = Sample(scene, o);
    Cover c;
    if (s.empty()) return c;
    const float r = s[0].radius;
    auto covered = [&](glm::vec3 q, glm::vec3 lo, glm::vec3 hi) {
      for (const Surfel& sf : s) {
        const glm::vec3 p = sf.position;
        if (p.x < lo.x || p.y < lo.y || p.x > hi.x || p.y > hi.y) continue;
        if (glm::length(q - p) <= r) return true;
      }
      return false;
    };
    // Leaves: the share of each leaf's grid its own disks cover; the share of the disks' area
    // outside their leaf (a grid over the disk).
    const int g = 24;
    int64_t in = 0, all = 0, out = 0, disk = 0;
    for (int i = 0; i < 200; ++i) {
      const glm::vec3 lo(i % 20, i / 20, 0), hi = lo + glm::vec3(0.36f, 0.24f, 0);
      for (int x = 0; x < g; ++x) {
        for (int y = 0; y < g; ++y) {
          const glm::vec3 q = lo + glm::vec3((x + 0.5f) * 0.36f / g, (y + 0.5f) * 0.24f / g, 0);
          in += covered(q, lo, hi) ? 1 : 0;
          ++all;
        }
      }
    }
    for (const Surfel& sf : s) {
      if (sf.position.x >= 20.5f) continue;  // leaves only
      const glm::vec3 lo(std::floor(sf.position.x), std::floor(sf.position.y), 0);
      for (int x = 0; x < g; ++x) {
        for (int y = 0; y < g; ++y) {
          const glm::vec3 q = sf.position + glm::vec3((2 * (x + 0.5f) / g - 1) * r,
                                                      (2 * (y + 0.5f) / g - 1) * r, 0);
          if (glm::length(q - sf.position) > r) continue;
          ++disk;
          const glm::vec3 f = q - lo;
          out += (f.x < 0 || f.y < 0 || f.x > 0.36f || f.y > 0.24f) ? 1 : 0;
        }
      }
    }
    c.leaf_covered = static_cast<double>(in) / static_cast<double>(all);
    c.leaf_overhang = static_cast<double>(out) / static_cast<double>(disk);
    // The face: the longest run of its centre line that no disk reaches.
    double run = 0, longest = 0;
    for (int y = 0; y < 4000; ++y) {
      const glm::vec3 q(30.06f, (y + 0.5f) * 0.001f, 0);
      run = covered(q, glm::vec3(29.9f, -1, 0), glm::vec3(30.2f, 5, 0)) ? 0 : run + 0.001;
      longest = std::max(longest, run);
    }
    c.strip_gap = longest / (2 * r);
    std::printf(
        "placement %d: leaves covered %.3f, overhang %.3f; face's longest gap %.2f "
        "diameters\n",
        static_cast<int>(placement), c.leaf_covered, c.leaf_overhang, c.strip_gap);
    return c;
  };
  const Cover pieces = measure(SamplerOptions::Placement::kPieces);
  const Cover uniform = measure(SamplerOptions::Placement::kUniform);
  // Pieces: 0.755 of the leaves covered, 0.097 of the disks' area over their edges, the face's
  // longest gap 0.54 diameters; uniform: 0.583, 0.324, 2.14.
  EXPECT_GT(pieces.leaf_covered, 0.72);
  EXPECT_GT(pieces.leaf_covered, uniform.leaf_covered + 0.1);
  EXPECT_LT(pieces.leaf_overhang, 0.15);
  EXPECT_LT(pieces.leaf_overhang, uniform.leaf_overhang - 0.1);
  EXPECT_LT(pieces.strip_gap, 0.6);
  EXPECT_GT(uniform.strip_gap, 2 * pieces.strip_gap);
}

TEST(SamplerTest, DeterministicPerSeedChunkAndThreads) {
  Scene scene = Small("cornell");
  SamplerOptions o;
  o.count = 20000;
  o.seed = 42;
  o.chunk_size = 3001;
  o.drop_hidden = false;  // exact count; hidden_test.cc repeats this with hidden samples dropped
  std::vector<Surfel> one, two, again, other_chunk, other_seed;
  tbb::task_arena(1).execute([&] { one = Sample(scene, o); });
  tbb::task_arena(2).execute([&] { two = Sample(scene, o); });
  again = Sample(scene, o);
  SamplerOptions big = o;
  big.chunk_size = 1 << 16;
  other_chunk = Sample(scene, big);
  SamplerOptions seed = o;
  seed.seed = 43;
  other_seed = Sample(scene, seed);
  ASSERT_EQ(one.size(), 20000u);
  EXPECT_TRUE(SameSurfels(one, two));
  EXPECT_TRUE(SameSurfels(one, again));
  EXPECT_TRUE(SameSurfels(one, other_chunk));
  EXPECT_FALSE(SameSurfels(one, other_seed));
}

TEST(SamplerTest, RewindRestartsTheSameStream) {
  Scene scene = Small("city");
  SamplerOptions o;
  o.count = 5000;
  o.chunk_size = 1024;
  o.drop_hidden = false;
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(scene), o);
  ASSERT_TRUE(source.ok()) << source.status();
  std::vector<Surfel> first = Drain(**source, 333);
  ASSERT_TRUE((*source)->Rewind().ok());
  std::vector<Surfel> second = Drain(**source, 4096);
  EXPECT_EQ(first.size(), 5000u);
  EXPECT_TRUE(SameSurfels(first, second));
  EXPECT_TRUE((*source)->HasRadiance());
}

TEST(SamplerTest, ForestIsOcclusionOnly) {
  Scene scene = Small("forest");
  SamplerOptions o;
  o.count = 1000;
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(scene), o);
  ASSERT_TRUE(source.ok()) << source.status();
  EXPECT_FALSE((*source)->HasRadiance());
  for (const Surfel& s : Drain(**source)) EXPECT_EQ(s.radiance, glm::vec3(0.0f));
}

// Sheet tags (Surfel::sheet): the surfels of one piece of a thin mesh (triangles joined by
// edges, vertices welded) share a tag; two leaves that cross each other, the same leaf in two
// instances, differ; a sheet folded over an edge is one piece; one-sided surfaces carry 0.
TEST(SamplerTest, SheetTagsFollowTheMeshesPieces) {
  Scene scene;
  scene.name = "sheets";
  scene.materials.push_back(Material{});  // 0: solid
  Material leaf;
  leaf.thin = true;
  scene.materials.push_back(leaf);  // 1: thin
  Mesh m;
  auto quad = [&m](glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d, uint32_t mat, bool shared) {
    const uint32_t k = static_cast<uint32_t>(m.positions.size());
    if (shared) {
      m.positions.insert(m.positions.end(), {a, b, c, d});
      m.triangles.push_back({k, k + 1, k + 2});
      m.triangles.push_back({k, k + 2, k + 3});
    } else {  // each triangle its own vertices: joined only once welded
      m.positions.insert(m.positions.end(), {a, b, c, a, c, d});
      m.triangles.push_back({k, k + 1, k + 2});
      m.triangles.push_back({k + 3, k + 4, k + 5});
    }
    m.materials.insert(m.materials.end(), {mat, mat});
  };
  quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, 1, false);                           // A: z = 0
  quad({0.5f, 0, -0.5f}, {0.5f, 1, -0.5f}, {0.5f, 1, 0.5f}, {0.5f, 0, 0.5f}, 1, true);  // B
  quad({0, 0, 2}, {1, 0, 2}, {1, 1, 2}, {0, 1, 2}, 1, true);   // C: z = 2, folded down into D
  quad({1, 0, 2}, {1, 0, 1}, {1, 1, 1}, {1, 1, 2}, 1, false);  // D: x = 1, z in [1, 2]
  quad({3, 0, 5}, {4, 0, 5}, {4, 1, 5}, {3, 1, 5}, 0, true);   // E: solid, above nothing
  scene.meshes.push_back(m);
  for (float x : {0.0f, 10.0f}) {
    Instance in;
    in.mesh = 0;
    in.transform = glm::mat4(1.0f);
    in.transform[3] = glm::vec4(x, 0.0f, 0.0f, 1.0f);
    scene.instances.push_back(in);
  }
  SamplerOptions o;
  o.count = 20000;
  o.bake = false;
  // tag[instance][piece]: A, B, C, D, E; -1 until seen.
  int tag[2][5];
  for (auto& t : tag) std::fill(std::begin(t), std::end(t), -1);
  int seen = 0;
  for (const Surfel& sf : Sample(scene, o)) {
    const int inst = sf.position.x >= 5.0f ? 1 : 0;
    const glm::vec3 p = sf.position - glm::vec3(10.0f * static_cast<float>(inst), 0.0f, 0.0f);
    auto on = [](float v, float at) { return std::fabs(v - at) < 1e-5f; };
    int piece = -1;
    if (on(p.z, 5.0f)) {
      piece = 4;
    } else if (on(p.z, 2.0f)) {
      piece = 2;
    } else if (on(p.x, 1.0f) && p.z > 1.0f) {
      piece = 3;
    } else if (on(p.z, 0.0f)) {
      piece = 0;
    } else if (on(p.x, 0.5f)) {
      piece = 1;
    }
    ASSERT_GE(piece, 0) << p.x << " " << p.y << " " << p.z;
    ASSERT_EQ(sf.two_sided, piece != 4);
    if (tag[inst][piece] < 0) tag[inst][piece] = sf.sheet;
    ASSERT_EQ(sf.sheet, tag[inst][piece]) << "instance " << inst << " piece " << piece;
    ++seen;
  }
  ASSERT_GT(seen, 19000);
  for (int inst = 0; inst < 2; ++inst) {
    EXPECT_EQ(tag[inst][4], 0);
    for (int piece = 0; piece < 4; ++piece) EXPECT_GT(tag[inst][piece], 0) << piece;
    EXPECT_NE(tag[inst][0], tag[inst][1]);  // crossing leaves
    EXPECT_EQ(tag[inst][2], tag[inst][3]);  // one sheet, folded
    EXPECT_NE(tag[inst][0], tag[inst][2]);
  }
  EXPECT_NE(tag[0][0], tag[1][0]);  // the same leaf, instanced twice
}

TEST(SamplerTest, RefusesBadRequests) {
  Scene scene = Small("cornell");
  SamplerOptions none;
  EXPECT_FALSE(MakeSceneSurfelSource(std::make_shared<Scene>(scene), none).ok());
  Scene empty;
  empty.name = "empty";
  SamplerOptions o;
  o.count = 10;
  auto r = MakeSceneSurfelSource(std::make_shared<Scene>(empty), o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("empty"), absl::string_view::npos) << r.status();
  EXPECT_FALSE(MakeScene("no-such-scene").ok());
}

}  // namespace
}  // namespace pbgi
