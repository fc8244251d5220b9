// Mesh import through Assimp: every format it reads, the node hierarchy kept as instances, the
// materials' base (or diffuse) and emissive colours, and the formats' quirks counted.
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <assimp/Importer.hpp>
#include <cmath>
#include <filesystem>
#include <system_error>

#include "absl/strings/str_format.h"
#include "pbgi/scene.h"

namespace pbgi {
namespace {

glm::mat4 ToGlm(const aiMatrix4x4& m) {
  // aiMatrix4x4 is row-major (a1..a4 is the first row); glm is column-major.
  glm::mat4 g;
  g[0] = glm::vec4(m.a1, m.b1, m.c1, m.d1);
  g[1] = glm::vec4(m.a2, m.b2, m.c2, m.d2);
  g[2] = glm::vec4(m.a3, m.b3, m.c3, m.d3);
  g[3] = glm::vec4(m.a4, m.b4, m.c4, m.d4);
  return g;
}

bool Finite(const aiVector3D& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

Material ReadMaterial(const aiMaterial* m) {
  Material out;
  aiColor4D c;
  if (m->Get(AI_MATKEY_BASE_COLOR, c) == AI_SUCCESS ||
      m->Get(AI_MATKEY_COLOR_DIFFUSE, c) == AI_SUCCESS) {
    out.albedo = glm::clamp(glm::vec3(c.r, c.g, c.b), 0.0f, 1.0f);
  }
  aiColor3D e;
  if (m->Get(AI_MATKEY_COLOR_EMISSIVE, e) == AI_SUCCESS) {
    float strength = 1.0f;
    m->Get(AI_MATKEY_EMISSIVE_INTENSITY, strength);
    glm::vec3 em = glm::vec3(e.r, e.g, e.b) * strength;
    if (std::isfinite(em.x) && std::isfinite(em.y) && std::isfinite(em.z)) {
      out.emission = glm::max(em, glm::vec3(0.0f));
    }
  }
  return out;
}

// One aiMesh as a pbgi mesh: its valid triangles (counting what is dropped in `r`), or false
// when none is left.
bool ConvertMesh(const aiMesh* am, uint32_t material, ImportReport& r, Mesh* out) {
  if (!am->HasNormals()) ++r.meshes_without_normals;
  Mesh mesh;
  mesh.positions.reserve(am->mNumVertices);
  for (unsigned v = 0; v < am->mNumVertices; ++v) {
    const aiVector3D& p = am->mVertices[v];
    mesh.positions.emplace_back(p.x, p.y, p.z);
  }
  for (unsigned f = 0; f < am->mNumFaces; ++f) {
    const aiFace& face = am->mFaces[f];
    if (face.mNumIndices != 3) {
      ++r.non_triangle_faces;
      continue;
    }
    const unsigned a = face.mIndices[0], b = face.mIndices[1], c = face.mIndices[2];
    if (a >= am->mNumVertices || b >= am->mNumVertices || c >= am->mNumVertices) {
      ++r.degenerate_triangles;
      continue;
    }
    if (!Finite(am->mVertices[a]) || !Finite(am->mVertices[b]) || !Finite(am->mVertices[c])) {
      ++r.nan_triangles;
      continue;
    }
    glm::dvec3 pa(mesh.positions[a]), pb(mesh.positions[b]), pc(mesh.positions[c]);
    double area2 = glm::length(glm::cross(pb - pa, pc - pa));
    if (!(area2 > 0.0) || !std::isfinite(area2)) {
      ++r.degenerate_triangles;
      continue;
    }
    mesh.triangles.emplace_back(a, b, c);
    mesh.materials.push_back(material);
  }
  if (mesh.triangles.empty()) {
    ++r.empty_meshes;
    return false;
  }
  // Non-finite vertices that no kept triangle uses would still fail Validate(): zero them.
  for (glm::vec3& p : mesh.positions) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) p = glm::vec3(0.0f);
  }
  r.triangles += static_cast<int64_t>(mesh.triangles.size());
  *out = std::move(mesh);
  return true;
}

// Walks the node hierarchy: each (node, mesh) pair is an instance with the node's world
// transform, so a mesh placed many times is stored once. Returns the placements dropped for a
// non-finite transform.
int64_t PlaceInstances(const aiNode* root, const std::vector<int>& mesh_of, Scene* scene) {
  struct Item {
    const aiNode* node;
    glm::mat4 parent;
  };
  std::vector<Item> stack;
  if (root) stack.push_back({root, glm::mat4(1.0f)});
  int64_t bad_transforms = 0;
  while (!stack.empty()) {
    Item it = stack.back();
    stack.pop_back();
    glm::mat4 world = it.parent * ToGlm(it.node->mTransformation);
    bool finite = true;
    for (int c = 0; c < 4; ++c) {
      for (int k = 0; k < 4; ++k) finite = finite && std::isfinite(world[c][k]);
    }
    for (unsigned k = 0; k < it.node->mNumMeshes; ++k) {
      unsigned mi = it.node->mMeshes[k];
      if (mi >= mesh_of.size() || mesh_of[mi] < 0) continue;
      if (!finite) {
        ++bad_transforms;
        continue;
      }
      scene->instances.push_back({static_cast<uint32_t>(mesh_of[mi]), world, -1});
    }
    for (unsigned c = 0; c < it.node->mNumChildren; ++c) {
      stack.push_back({it.node->mChildren[c], world});
    }
  }
  return bad_transforms;
}

// One warning per kind of thing dropped.
void AddWarnings(const std::string& path, int64_t bad_transforms, ImportReport& r) {
  auto warn = [&](int64_t n, const char* what) {
    if (n > 0) r.warnings.push_back(absl::StrFormat("mesh '%s': %d %s", path, n, what));
  };
  warn(r.meshes_without_normals, "mesh(es) without normals (normals taken from the geometry)");
  warn(r.empty_meshes, "empty mesh(es) without usable triangles, skipped");
  warn(r.degenerate_triangles, "degenerate (zero-area) triangle(s) dropped");
  warn(r.nan_triangles, "triangle(s) with NaN or infinite vertices dropped");
  warn(r.non_triangle_faces, "point or line primitive(s) dropped");
  warn(bad_transforms, "placement(s) with a non-finite node transform dropped");
}

}  // namespace

absl::StatusOr<Scene> ImportMesh(const std::string& path, ImportReport* report) {
  return ImportMesh(path, ImportOptions{}, report);
}

absl::StatusOr<Scene> ImportMesh(const std::string& path, const ImportOptions& options,
                                 ImportReport* report) {
  ImportReport local;
  ImportReport& r = report ? *report : local;
  r = ImportReport{};
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    return absl::NotFoundError(absl::StrFormat("mesh '%s': no such file", path));
  }
  Assimp::Importer importer;
  // Points and lines are dropped (and counted) by us; triangulate polygons; no smoothing or
  // normal generation (normals come from the geometry); keep degenerate faces to count them.
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE, 0);
  const aiScene* ai =
      importer.ReadFile(path, aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                  aiProcess_ValidateDataStructure);
  if (ai == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrFormat("mesh '%s': Assimp cannot read it: %s", path, importer.GetErrorString()));
  }
  if (ai->mFlags & AI_SCENE_FLAGS_INCOMPLETE) {
    return absl::InvalidArgumentError(
        absl::StrFormat("mesh '%s': Assimp read an incomplete scene (no meshes)", path));
  }
  Scene scene;
  scene.name = std::filesystem::path(path).filename().string();
  for (unsigned i = 0; i < ai->mNumMaterials; ++i) {
    scene.materials.push_back(ReadMaterial(ai->mMaterials[i]));
  }
  const uint32_t default_material = static_cast<uint32_t>(scene.materials.size());
  scene.materials.push_back(Material{});
  // One pbgi mesh per usable aiMesh; -1 for the dropped ones.
  std::vector<int> mesh_of(ai->mNumMeshes, -1);
  for (unsigned mi = 0; mi < ai->mNumMeshes; ++mi) {
    const aiMesh* am = ai->mMeshes[mi];
    const uint32_t material =
        am->mMaterialIndex < ai->mNumMaterials ? am->mMaterialIndex : default_material;
    Mesh mesh;
    if (!ConvertMesh(am, material, r, &mesh)) continue;
    mesh_of[mi] = static_cast<int>(scene.meshes.size());
    scene.meshes.push_back(std::move(mesh));
  }
  const int64_t bad_transforms = PlaceInstances(ai->mRootNode, mesh_of, &scene);
  r.meshes = static_cast<int64_t>(scene.meshes.size());
  r.instances = static_cast<int64_t>(scene.instances.size());
  r.materials = static_cast<int64_t>(ai->mNumMaterials);
  AddWarnings(path, bad_transforms, r);
  if (scene.instances.empty()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "mesh '%s': nothing usable left (%d meshes, %d empty, %d degenerate and %d NaN triangles "
        "dropped)",
        path, ai->mNumMeshes, r.empty_meshes, r.degenerate_triangles, r.nan_triangles));
  }
  absl::Status valid = scene.Validate();
  if (!valid.ok()) return valid;
  if (options.orient) {
    r.orientation = OrientScene(&scene);
    r.oriented = true;
  }
  return scene;
}

}  // namespace pbgi
