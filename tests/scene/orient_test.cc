// OrientScene(): closed shells face out (cavities in), open and non-manifold parts are wound
// consistently and marked thin, duplicated vertices are welded.
#include <cmath>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "glm/geometric.hpp"
#include "gtest/gtest.h"
#include "pbgi/scene.h"
#include "tests/common/scratch_dir.h"

namespace pbgi {
namespace {

// The 12 triangles of the box [lo, hi], wound outward, as corner positions (three per
// triangle, no sharing: a "triangle soup" as STL writes it).
std::vector<glm::vec3> BoxSoup(glm::vec3 lo, glm::vec3 hi) {
  auto c = [&](int i) {
    return glm::vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
  };
  // Quads as corner indices, counter-clockwise seen from outside.
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  std::vector<glm::vec3> out;
  for (const auto& q : quads) {
    for (int t : {0, 1, 2, 0, 2, 3}) out.push_back(c(q[t]));
  }
  return out;
}

// A mesh from a soup; `share` welds nothing itself but indexes equal positions once (as an
// indexed file would), so both forms are tested.
Mesh MeshOf(const std::vector<glm::vec3>& soup, bool share, uint32_t material = 0) {
  Mesh m;
  std::map<std::tuple<float, float, float>, uint32_t> index;
  for (size_t i = 0; i < soup.size(); i += 3) {
    glm::uvec3 t;
    for (int k = 0; k < 3; ++k) {
      const glm::vec3& p = soup[i + k];
      auto key = std::make_tuple(p.x, p.y, p.z);
      auto it = index.find(key);
      if (share && it != index.end()) {
        t[k] = it->second;
      } else {
        t[k] = static_cast<uint32_t>(m.positions.size());
        m.positions.push_back(p);
        if (share) index[key] = t[k];
      }
    }
    m.triangles.push_back(t);
    m.materials.push_back(material);
  }
  return m;
}

Scene SceneOf(std::vector<Mesh> meshes) {
  Scene s;
  s.name = "test";
  s.materials.push_back(Material{});
  for (uint32_t i = 0; i < meshes.size(); ++i) s.instances.push_back({i, glm::mat4(1.0f), -1});
  s.meshes = std::move(meshes);
  return s;
}

glm::vec3 Normal(const Mesh& m, size_t t) {
  const glm::vec3 a = m.positions[m.triangles[t][0]], b = m.positions[m.triangles[t][1]],
                  c = m.positions[m.triangles[t][2]];
  return glm::normalize(glm::cross(b - a, c - a));
}

glm::vec3 Centroid(const Mesh& m, size_t t) {
  return (m.positions[m.triangles[t][0]] + m.positions[m.triangles[t][1]] +
          m.positions[m.triangles[t][2]]) /
         3.0f;
}

// Every triangle of the axis box [lo, hi] in `m` (from `first`, `count` of them) faces away
// from the box's center (sign +1) or towards it (-1).
void ExpectFacing(const Mesh& m, size_t first, size_t count, glm::vec3 lo, glm::vec3 hi,
                  float sign) {
  const glm::vec3 center = 0.5f * (lo + hi);
  for (size_t t = first; t < first + count; ++t) {
    const glm::vec3 d = Centroid(m, t) - center;
    EXPECT_GT(sign * glm::dot(Normal(m, t), d), 0.0f) << "triangle " << t;
  }
}

// Reverses the winding of triangle t.
void Flip(Mesh& m, size_t t) { std::swap(m.triangles[t][1], m.triangles[t][2]); }

bool Thin(const Scene& s, const Mesh& m, size_t t) { return s.materials[m.materials[t]].thin; }

TEST(OrientTest, CubeWithSomeFacesFlippedComesOutOutward) {
  for (bool share : {true, false}) {
    Mesh m = MeshOf(BoxSoup(glm::vec3(0), glm::vec3(1)), share);
    for (size_t t : {0, 3, 4, 7, 11}) Flip(m, t);
    Scene s = SceneOf({m});
    const OrientReport r = OrientScene(&s);
    EXPECT_EQ(r.components, 1);
    EXPECT_EQ(r.closed_components, 1);
    EXPECT_EQ(r.flipped_triangles, 5);
    EXPECT_EQ(r.thin_triangles, 0);
    EXPECT_EQ(r.welded_vertices, share ? 0 : 36 - 8);
    ExpectFacing(s.meshes[0], 0, 12, glm::vec3(0), glm::vec3(1), 1.0f);
    for (size_t t = 0; t < 12; ++t) EXPECT_FALSE(Thin(s, s.meshes[0], t));
    EXPECT_EQ(s.materials.size(), 1u);
  }
}

TEST(OrientTest, InsideOutCubeComesOutOutward) {
  Mesh m = MeshOf(BoxSoup(glm::vec3(-3), glm::vec3(2)), true);
  for (size_t t = 0; t < 12; ++t) Flip(m, t);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.closed_components, 1);
  EXPECT_EQ(r.flipped_triangles, 12);
  ExpectFacing(s.meshes[0], 0, 12, glm::vec3(-3), glm::vec3(2), 1.0f);
}

TEST(OrientTest, OpenBoxIsThinAndConsistentlyWound) {
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(1));
  soup.resize(soup.size() - 6);  // drop the +x face: 5 faces, 10 triangles
  Mesh m = MeshOf(soup, true);
  Flip(m, 2);  // one wrong, the majority outward
  Scene s = SceneOf({m});
  s.materials.push_back(Material{});  // an unused material stays as it is
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.components, 1);
  EXPECT_EQ(r.open_components, 1);
  EXPECT_EQ(r.closed_components, 0);
  EXPECT_EQ(r.thin_triangles, 10);
  EXPECT_EQ(r.thin_materials, 1);
  EXPECT_EQ(r.flipped_triangles, 1);
  ExpectFacing(s.meshes[0], 0, 10, glm::vec3(0), glm::vec3(1), 1.0f);
  for (size_t t = 0; t < 10; ++t) EXPECT_TRUE(Thin(s, s.meshes[0], t));
  ASSERT_EQ(s.materials.size(), 3u);
  EXPECT_FALSE(s.materials[0].thin);
  EXPECT_TRUE(s.materials[2].thin);
  EXPECT_TRUE(s.Validate().ok());
}

TEST(OrientTest, OpenSheetKeepsTheMajorityWinding) {
  // An open box wound inward as a whole (as a room without a wall): nothing to flip.
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(1));
  soup.resize(soup.size() - 6);
  Mesh m = MeshOf(soup, true);
  for (size_t t = 0; t < 10; ++t) Flip(m, t);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.flipped_triangles, 0);
  ExpectFacing(s.meshes[0], 0, 10, glm::vec3(0), glm::vec3(1), -1.0f);
}

TEST(OrientTest, TouchingCubesAreTwoClosedShells) {
  // Two cubes in contact over a face region (one's face lies in the other's), one of them
  // inside-out, in one mesh.
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(1));
  const std::vector<glm::vec3> b = BoxSoup(glm::vec3(1, 0.25f, 0.25f), glm::vec3(2, 0.75f, 0.75f));
  soup.insert(soup.end(), b.begin(), b.end());
  Mesh m = MeshOf(soup, true);
  for (size_t t = 12; t < 24; ++t) Flip(m, t);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.components, 2);
  EXPECT_EQ(r.closed_components, 2);
  EXPECT_EQ(r.cavities, 0);
  EXPECT_EQ(r.flipped_triangles, 12);
  ExpectFacing(s.meshes[0], 0, 12, glm::vec3(0), glm::vec3(1), 1.0f);
  ExpectFacing(s.meshes[0], 12, 12, glm::vec3(1, 0.25f, 0.25f), glm::vec3(2, 0.75f, 0.75f), 1.0f);
}

TEST(OrientTest, CubesSharingAnEdgeAreEachClosed) {
  // The welded edge from (1,1,0) to (1,1,1) is used by four triangles: non-manifold for the
  // mesh, but each cube uses it twice and is closed on its own.
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(1));
  const std::vector<glm::vec3> b = BoxSoup(glm::vec3(1, 1, 0), glm::vec3(2, 2, 1));
  soup.insert(soup.end(), b.begin(), b.end());
  Mesh m = MeshOf(soup, false);
  Flip(m, 5);
  Flip(m, 17);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.components, 2);
  EXPECT_EQ(r.closed_components, 2);
  EXPECT_EQ(r.flipped_triangles, 2);
  ExpectFacing(s.meshes[0], 0, 12, glm::vec3(0), glm::vec3(1), 1.0f);
  ExpectFacing(s.meshes[0], 12, 12, glm::vec3(1, 1, 0), glm::vec3(2, 2, 1), 1.0f);
}

TEST(OrientTest, NonManifoldFinDoesNotCrashAndIsThin) {
  // A closed cube plus a fin: one extra triangle on a cube edge, so that edge has three uses
  // (two from the cube's faces, one from the fin).
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(1));
  soup.push_back(glm::vec3(1, 1, 0));
  soup.push_back(glm::vec3(1, 1, 1));
  soup.push_back(glm::vec3(2, 2, 0.5f));
  // And three triangles on one edge, none of which forms a shell.
  soup.push_back(glm::vec3(5, 0, 0));
  soup.push_back(glm::vec3(5, 0, 1));
  soup.push_back(glm::vec3(6, 0, 0));
  soup.push_back(glm::vec3(5, 0, 0));
  soup.push_back(glm::vec3(5, 0, 1));
  soup.push_back(glm::vec3(4, 0, 0));
  soup.push_back(glm::vec3(5, 0, 1));
  soup.push_back(glm::vec3(5, 0, 0));
  soup.push_back(glm::vec3(5, 1, 0));
  Mesh m = MeshOf(soup, true);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  // The cube stays one closed shell (its edge with the fin is used twice by it); the fin and
  // the three blades are open pieces on their own.
  EXPECT_EQ(r.closed_components, 1);
  EXPECT_EQ(r.thin_triangles, 4);
  for (size_t t = 0; t < 12; ++t) EXPECT_FALSE(Thin(s, s.meshes[0], t));
  for (size_t t = 12; t < 16; ++t) EXPECT_TRUE(Thin(s, s.meshes[0], t));
  EXPECT_TRUE(s.Validate().ok());
}

TEST(OrientTest, NestedShellBoundsACavity) {
  // A hollow block: an outer shell and an inner one, both given outward. The inner shell is the
  // wall of the hollow and must face into it.
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(4));
  const std::vector<glm::vec3> inner = BoxSoup(glm::vec3(1), glm::vec3(3));
  soup.insert(soup.end(), inner.begin(), inner.end());
  // And a solid in the hollow, given inside-out: it faces out again.
  const std::vector<glm::vec3> core = BoxSoup(glm::vec3(1.5f), glm::vec3(2.5f));
  soup.insert(soup.end(), core.begin(), core.end());
  Mesh m = MeshOf(soup, true);
  for (size_t t = 24; t < 36; ++t) Flip(m, t);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.closed_components, 3);
  EXPECT_EQ(r.cavities, 1);
  EXPECT_EQ(r.flipped_triangles, 24);
  ExpectFacing(s.meshes[0], 0, 12, glm::vec3(0), glm::vec3(4), 1.0f);
  ExpectFacing(s.meshes[0], 12, 12, glm::vec3(1), glm::vec3(3), -1.0f);
  ExpectFacing(s.meshes[0], 24, 12, glm::vec3(1.5f), glm::vec3(2.5f), 1.0f);
}

TEST(OrientTest, ManyShellsInsideOneHollowAreEachCavities) {
  // 16^3 cubes (a grid of pebbles) inside one big box: the nesting test finds each cube's one
  // holder through the grid, without comparing every pair.
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(-1), glm::vec3(33));
  for (int x = 0; x < 16; ++x) {
    for (int y = 0; y < 16; ++y) {
      for (int z = 0; z < 16; ++z) {
        const glm::vec3 lo(2.0f * x, 2.0f * y, 2.0f * z);
        const std::vector<glm::vec3> b = BoxSoup(lo, lo + glm::vec3(1.0f));
        soup.insert(soup.end(), b.begin(), b.end());
      }
    }
  }
  Scene s = SceneOf({MeshOf(soup, true)});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.closed_components, 1 + 4096);
  EXPECT_EQ(r.cavities, 4096);
  EXPECT_EQ(r.nesting_unchecked, 0);
  EXPECT_EQ(r.flipped_triangles, 4096 * 12);
  ExpectFacing(s.meshes[0], 12, 12, glm::vec3(0), glm::vec3(1), -1.0f);
}

TEST(OrientTest, MirroredPlacementFacesOutInWorldSpace) {
  Mesh m = MeshOf(BoxSoup(glm::vec3(0), glm::vec3(1)), true);
  Scene s = SceneOf({m});
  s.instances[0].transform = glm::mat4(glm::vec4(-1, 0, 0, 0), glm::vec4(0, 1, 0, 0),
                                       glm::vec4(0, 0, 1, 0), glm::vec4(0, 0, 0, 1));
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.flipped_triangles, 12);  // inward in object space: outward once mirrored
  ExpectFacing(s.meshes[0], 0, 12, glm::vec3(0), glm::vec3(1), -1.0f);
}

TEST(OrientTest, DuplicatedVerticesAreWeldedWithinTolerance) {
  // A soup whose copies of a corner differ by float noise far below the mesh's scale.
  std::vector<glm::vec3> soup = BoxSoup(glm::vec3(0), glm::vec3(1000));
  for (size_t i = 0; i < soup.size(); ++i) soup[i] += glm::vec3(1e-5f * static_cast<float>(i % 3));
  Mesh m = MeshOf(soup, false);
  Flip(m, 6);
  Scene s = SceneOf({m});
  const OrientReport r = OrientScene(&s);
  EXPECT_EQ(r.welded_vertices, 36 - 8);
  EXPECT_EQ(r.closed_components, 1);
  EXPECT_EQ(r.flipped_triangles, 1);
}

TEST(OrientTest, ImportOrientsAnInsideOutObjUnlessTurnedOff) {
  testing_common::ScratchDir scratch;
  const std::string path = (scratch.path() / "cube.obj").string();
  // The cube of import_test.cc with every face wound inward.
  std::ofstream(path) << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
                         "f 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 2 6 7 3\nf 3 7 8 4\nf 4 8 5 1\n";
  ImportReport report;
  auto scene = ImportMesh(path, &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_TRUE(report.oriented);
  EXPECT_EQ(report.orientation.closed_components, 1);
  EXPECT_EQ(report.orientation.flipped_triangles, 12);
  ExpectFacing(scene->meshes[0], 0, 12, glm::vec3(0), glm::vec3(1), 1.0f);
  ImportOptions off;
  off.orient = false;
  auto raw = ImportMesh(path, off, &report);
  ASSERT_TRUE(raw.ok()) << raw.status();
  EXPECT_FALSE(report.oriented);
  ExpectFacing(raw->meshes[0], 0, 12, glm::vec3(0), glm::vec3(1), -1.0f);
}

}  // namespace
}  // namespace pbgi
