// Mesh import through Assimp: known areas round-trip, quirks are counted, bad files refused.
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"
#include "pbgi/scene.h"
#include "tests/common/scratch_dir.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

class ImportTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = scratch_.path(); }
  std::string Write(const std::string& name, const std::string& text) {
    std::string path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary) << text;
    return path;
  }
  testing_common::ScratchDir scratch_;
  fs::path dir_;
};

// A unit cube (area 6) as 6 quads, with a material and one degenerate face.
constexpr char kCubeObj[] = R"(mtllib cube.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
usemtl orange
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
f 1 2 1
)";
constexpr char kCubeMtl[] = R"(newmtl orange
Kd 0.9 0.5 0.1
Ke 0 0 0
)";

TEST_F(ImportTest, ObjCubeRoundTripsThroughTheSampler) {
  Write("cube.mtl", kCubeMtl);
  ImportReport report;
  auto scene = ImportMesh(Write("cube.obj", kCubeObj), &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->TriangleCount(), 12);
  EXPECT_NEAR(scene->SurfaceArea(), 6.0, 1e-6);
  EXPECT_EQ(report.triangles, 12);
  EXPECT_EQ(report.degenerate_triangles, 1);
  EXPECT_EQ(report.meshes_without_normals, 1);
  ASSERT_FALSE(report.warnings.empty());
  bool orange = false;
  for (const Material& m : scene->materials) {
    orange = orange || (std::abs(m.albedo.x - 0.9f) < 1e-6f && std::abs(m.albedo.y - 0.5f) < 1e-6f);
  }
  EXPECT_TRUE(orange);

  // Sample it: count, area and every surfel on the cube's surface with an axis normal.
  scene->lights.sky = glm::vec3(1.0f);
  SamplerOptions o;
  o.count = 6000;
  auto source = MakeSceneSurfelSource(std::make_shared<Scene>(*scene), o);
  ASSERT_TRUE(source.ok()) << source.status();
  std::vector<Surfel> s(7000);
  auto n = (*source)->Next(absl::MakeSpan(s));
  ASSERT_TRUE(n.ok());
  ASSERT_EQ(*n, 6000u);
  double area = 0.0;
  int faces[6] = {0, 0, 0, 0, 0, 0};
  for (size_t i = 0; i < *n; ++i) {
    area += s[i].Area();
    const glm::vec3& p = s[i].position;
    const glm::vec3& nn = s[i].normal;
    int axis = std::abs(nn.x) > 0.5f ? 0 : (std::abs(nn.y) > 0.5f ? 1 : 2);
    ASSERT_NEAR(std::abs(nn[axis]), 1.0f, 1e-6f);
    // On the face its normal names: outward normal + at coordinate 1, - at 0.
    EXPECT_NEAR(p[axis], nn[axis] > 0 ? 1.0f : 0.0f, 1e-6f);
    ++faces[axis * 2 + (nn[axis] > 0 ? 1 : 0)];
    // The outside of a convex cube sees the whole sky: albedo * sky.
    EXPECT_NEAR(s[i].radiance.x, 0.9f, 1e-5f);
  }
  EXPECT_NEAR(area, 6.0, 0.12);
  for (int f : faces) EXPECT_NEAR(f, 1000, 1);
}

TEST_F(ImportTest, AsciiStlTetrahedron) {
  // Right-angle tetrahedron with unit legs: area 3 * 0.5 + sqrt(3)/2.
  std::string stl = "solid t\n";
  auto facet = [&](const char* a, const char* b, const char* c) {
    absl::StrAppend(&stl, "facet normal 0 0 0\nouter loop\nvertex ", a, "\nvertex ", b, "\nvertex ",
                    c, "\nendloop\nendfacet\n");
  };
  facet("0 0 0", "0 1 0", "1 0 0");
  facet("0 0 0", "1 0 0", "0 0 1");
  facet("0 0 0", "0 0 1", "0 1 0");
  facet("1 0 0", "0 1 0", "0 0 1");
  stl += "endsolid t\n";
  ImportReport report;
  auto scene = ImportMesh(Write("tet.stl", stl), &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->TriangleCount(), 4);
  EXPECT_NEAR(scene->SurfaceArea(), 1.5 + std::sqrt(3.0) / 2.0, 1e-6);
}

TEST_F(ImportTest, NodeTransformsBecomeInstances) {
  // A glTF-free check of the hierarchy: Collada places one triangle mesh twice, scaled by 2.
  const char* dae = R"(<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="meter" meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries>
    <geometry id="tri" name="tri"><mesh>
      <source id="pos"><float_array id="pos-array" count="9">0 0 0 1 0 0 0 1 0</float_array>
        <technique_common><accessor source="#pos-array" count="3" stride="3">
          <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
        </accessor></technique_common></source>
      <vertices id="verts"><input semantic="POSITION" source="#pos"/></vertices>
      <triangles count="1"><input semantic="VERTEX" source="#verts" offset="0"/><p>0 1 2</p></triangles>
    </mesh></geometry>
  </library_geometries>
  <library_visual_scenes><visual_scene id="s">
    <node id="a"><matrix>2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1</matrix><instance_geometry url="#tri"/></node>
    <node id="b"><matrix>2 0 0 5 0 2 0 0 0 0 2 0 0 0 0 1</matrix><instance_geometry url="#tri"/></node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>
)";
  ImportReport report;
  auto scene = ImportMesh(Write("two.dae", dae), &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->instances.size(), 2u);
  EXPECT_NEAR(scene->SurfaceArea(), 2 * 0.5 * 4.0, 1e-5);
  Bounds b = scene->ComputeBounds();
  EXPECT_NEAR(b.hi.x, 7.0f, 1e-5f);
}

TEST_F(ImportTest, GltfBaseColorEmissionAndNodeTranslation) {
  // One triangle of area 2, lifted to z = 3 by its node, base colour and emission set.
  const char* gltf =
      R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],)"
      R"( "nodes": [{"mesh": 0, "translation": [0, 0, 3]}],)"
      R"( "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "material": 0}]}],)"
      R"( "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.4, 0.6, 1.0]},)"
      R"( "emissiveFactor": [0.5, 0.25, 0.0]}],)"
      R"( "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,)"
      R"(AAAAAAAAAAAAAAAAAAAAQAAAAAAAAAAAAAAAAAAAAEAAAAAA"}],)"
      R"( "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],)"
      R"( "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",)"
      R"( "min": [0, 0, 0], "max": [2, 2, 0]}]})";
  ImportReport report;
  auto scene = ImportMesh(Write("tri.gltf", gltf), &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_NEAR(scene->SurfaceArea(), 2.0, 1e-6);
  Bounds b = scene->ComputeBounds();
  EXPECT_NEAR(b.lo.z, 3.0f, 1e-6f);
  EXPECT_NEAR(b.hi.z, 3.0f, 1e-6f);
  const Material& m = scene->materials[scene->meshes[0].materials[0]];
  EXPECT_NEAR(m.albedo.x, 0.2f, 1e-6f);
  EXPECT_NEAR(m.albedo.y, 0.4f, 1e-6f);
  EXPECT_NEAR(m.albedo.z, 0.6f, 1e-6f);
  EXPECT_NEAR(m.emission.x, 0.5f, 1e-6f);
  EXPECT_NEAR(m.emission.y, 0.25f, 1e-6f);
}

TEST_F(ImportTest, GarbageIsRefusedNamingTheFile) {
  std::string junk;
  for (int i = 0; i < 4096; ++i) junk.push_back(static_cast<char>((i * 7919) % 251));
  for (const char* name : {"junk.ply", "junk.glb", "junk.fbx", "junk.xyzzy"}) {
    std::string path = Write(name, junk);
    ImportReport report;
    auto scene = ImportMesh(path, &report);
    ASSERT_FALSE(scene.ok()) << name;
    EXPECT_NE(scene.status().message().find(path), absl::string_view::npos) << scene.status();
  }
  auto missing = ImportMesh((dir_ / "missing.obj").string(), nullptr);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
}

TEST_F(ImportTest, NothingUsableLeftIsAnError) {
  // Only degenerate faces.
  ImportReport report;
  auto scene = ImportMesh(Write("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"), &report);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("nothing usable"), absl::string_view::npos)
      << scene.status();
}

TEST_F(ImportTest, NanVerticesAreDroppedAndCounted) {
  ImportReport report;
  auto scene = ImportMesh(Write("nan.obj",
                                "v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 0 0 1\n"
                                "f 1 2 3\nf 1 4 5\nf 2 4 5\n"),
                          &report);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->TriangleCount(), 1);
  EXPECT_EQ(report.nan_triangles, 2);
  bool named = false;
  for (const std::string& w : report.warnings) named = named || w.find("NaN") != std::string::npos;
  EXPECT_TRUE(named);
}

}  // namespace
}  // namespace pbgi
