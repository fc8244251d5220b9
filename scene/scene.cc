// Scene's own checks and measures, and the flat triangle index over its instances.
#include "pbgi/scene.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "scene/scene_index.h"

namespace pbgi {
namespace {

bool Finite(const glm::vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

}  // namespace

absl::Status Scene::Validate() const {
  for (size_t m = 0; m < meshes.size(); ++m) {
    const Mesh& mesh = meshes[m];
    if (mesh.materials.size() != mesh.triangles.size()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("scene '%s': mesh %d has %d triangles but %d material indices", name, m,
                          mesh.triangles.size(), mesh.materials.size()));
    }
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      const glm::uvec3& tri = mesh.triangles[t];
      if (tri.x >= mesh.positions.size() || tri.y >= mesh.positions.size() ||
          tri.z >= mesh.positions.size()) {
        return absl::InvalidArgumentError(
            absl::StrFormat("scene '%s': mesh %d triangle %d indexes a vertex past the %d vertices",
                            name, m, t, mesh.positions.size()));
      }
      if (mesh.materials[t] >= materials.size()) {
        return absl::InvalidArgumentError(
            absl::StrFormat("scene '%s': mesh %d triangle %d uses material %d of %d", name, m, t,
                            mesh.materials[t], materials.size()));
      }
    }
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      if (!Finite(mesh.positions[v])) {
        return absl::InvalidArgumentError(
            absl::StrFormat("scene '%s': mesh %d vertex %d is not finite", name, m, v));
      }
    }
  }
  for (size_t i = 0; i < instances.size(); ++i) {
    const Instance& in = instances[i];
    if (in.mesh >= meshes.size()) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "scene '%s': instance %d places mesh %d of %d", name, i, in.mesh, meshes.size()));
    }
    if (in.material >= 0 && static_cast<size_t>(in.material) >= materials.size()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("scene '%s': instance %d uses material %d of %d", name, i, in.material,
                          materials.size()));
    }
    for (int c = 0; c < 4; ++c) {
      if (!Finite(glm::vec3(in.transform[c])) || !std::isfinite(in.transform[c][3])) {
        return absl::InvalidArgumentError(
            absl::StrFormat("scene '%s': instance %d has a non-finite transform", name, i));
      }
    }
  }
  if (lights.sky_rays < 0 || lights.area_light_samples < 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("scene '%s': negative light sample counts", name));
  }
  if (lights.has_sun && !(std::abs(glm::length(lights.sun.direction) - 1.0f) < 1e-3f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("scene '%s': the sun direction is not a unit vector", name));
  }
  return absl::OkStatus();
}

Bounds Scene::ComputeBounds() const {
  Bounds b;
  for (const Instance& in : instances) {
    const Mesh& m = meshes[in.mesh];
    Bounds local;
    for (const glm::uvec3& t : m.triangles) {
      local.Extend(m.positions[t.x]);
      local.Extend(m.positions[t.y]);
      local.Extend(m.positions[t.z]);
    }
    if (local.Empty()) continue;
    // The corners of the object-space box bound the transformed triangles (affine map).
    for (int c = 0; c < 8; ++c) {
      glm::vec3 p((c & 1) ? local.hi.x : local.lo.x, (c & 2) ? local.hi.y : local.lo.y,
                  (c & 4) ? local.hi.z : local.lo.z);
      b.Extend(internal::TransformPoint(in.transform, p));
    }
  }
  return b;
}

double Scene::SurfaceArea() const {
  double area = 0.0;
  for (const Instance& in : instances) {
    const Mesh& m = meshes[in.mesh];
    for (const glm::uvec3& t : m.triangles) {
      internal::WorldTriangle w{internal::TransformPoint(in.transform, m.positions[t.x]),
                                internal::TransformPoint(in.transform, m.positions[t.y]),
                                internal::TransformPoint(in.transform, m.positions[t.z])};
      area += w.Area();
    }
  }
  return area;
}

int64_t Scene::TriangleCount() const {
  int64_t n = 0;
  for (const Instance& in : instances) n += static_cast<int64_t>(meshes[in.mesh].triangles.size());
  return n;
}

namespace internal {

SceneIndex::SceneIndex(const Scene& scene) : scene_(&scene) {
  instance_first_.reserve(scene.instances.size() + 1);
  instance_first_.push_back(0);
  for (const Instance& in : scene.instances) {
    instance_first_.push_back(instance_first_.back() +
                              static_cast<int64_t>(scene.meshes[in.mesh].triangles.size()));
  }
  // Sheet tags: pieces only of the meshes that some instance draws with a thin material.
  std::vector<bool> thin(scene.meshes.size(), false);
  for (const Instance& in : scene.instances) {
    if (in.material >= 0) {
      thin[in.mesh] = thin[in.mesh] || scene.materials[static_cast<size_t>(in.material)].thin;
      continue;
    }
    for (uint32_t m : scene.meshes[in.mesh].materials) {
      if (scene.materials[m].thin) {
        thin[in.mesh] = true;
        break;
      }
    }
  }
  mesh_pieces_.resize(scene.meshes.size());
  for (size_t m = 0; m < scene.meshes.size(); ++m) {
    if (thin[m]) mesh_pieces_[m] = MeshPieces(scene.meshes[m]);
  }
  emitter_cdf_.push_back(0.0);
  for (uint32_t i = 0; i < scene.instances.size(); ++i) {
    const Instance& in = scene.instances[i];
    const Mesh& m = scene.meshes[in.mesh];
    bool any = false;
    for (uint32_t t = 0; t < m.triangles.size() && !any; ++t) {
      const Material& mat = scene.materials[MaterialOf(i, t)];
      any = mat.emission.x > 0 || mat.emission.y > 0 || mat.emission.z > 0;
    }
    if (!any) continue;
    for (uint32_t t = 0; t < m.triangles.size(); ++t) {
      const Material& mat = scene.materials[MaterialOf(i, t)];
      float lum = 0.2126f * mat.emission.x + 0.7152f * mat.emission.y + 0.0722f * mat.emission.z;
      if (!(lum > 0.0f)) continue;
      WorldTriangle w = Triangle(i, t);
      glm::vec3 c = w.Cross();
      float len = glm::length(c);
      if (!(len > 0.0f)) continue;
      emitters_.push_back({w, c / len, mat.emission, 0.5f * len});
      emitter_cdf_.push_back(emitter_cdf_.back() + static_cast<double>(lum) * 0.5 * len);
    }
  }
  bounds_ = scene.ComputeBounds();
  if (!bounds_.Empty()) {
    glm::vec3 e = bounds_.Extent();
    extent_ = std::max(e.x, std::max(e.y, e.z));
  }
}

uint32_t SceneIndex::InstanceOf(int64_t g) const {
  auto it = std::upper_bound(instance_first_.begin(), instance_first_.end(), g);
  return static_cast<uint32_t>((it - instance_first_.begin()) - 1);
}

size_t SceneIndex::PickEmitter(double u) const {
  double target = u * emitter_cdf_.back();
  auto it = std::upper_bound(emitter_cdf_.begin(), emitter_cdf_.end(), target);
  size_t i = static_cast<size_t>(it - emitter_cdf_.begin());
  i = i == 0 ? 0 : i - 1;
  return std::min(i, emitters_.size() - 1);
}

}  // namespace internal
}  // namespace pbgi
