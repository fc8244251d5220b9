// A flat view of a Scene's instanced triangles, shared by the Tracer and the sampler: global
// triangle numbers (instance by instance), world-space vertices, materials, and the emissive
// triangles (the area lights) with a power CDF for light sampling.
#ifndef PBGI_SCENE_SCENE_INDEX_H_
#define PBGI_SCENE_SCENE_INDEX_H_

#include <cstdint>
#include <vector>

#include "pbgi/scene.h"
#include "scene/sample_math.h"

namespace pbgi::internal {

// The connected pieces of a mesh: triangles that share an edge (vertices welded within a
// millionth of the mesh's diagonal, as OrientMesh welds them) get the same number, the least
// triangle index of the piece (scene/orient.cc).
std::vector<uint32_t> MeshPieces(const Mesh& mesh);

class SceneIndex {
 public:
  // REQUIRES: scene.Validate() is OK; `scene` outlives the index.
  explicit SceneIndex(const Scene& scene);

  const Scene& scene() const { return *scene_; }
  int64_t triangle_count() const { return instance_first_.back(); }
  // First global triangle number of each instance; instance_count() + 1 entries.
  const std::vector<int64_t>& instance_first() const { return instance_first_; }

  // The instance that holds global triangle g. REQUIRES: 0 <= g < triangle_count().
  uint32_t InstanceOf(int64_t g) const;

  WorldTriangle Triangle(uint32_t instance, uint32_t tri) const {
    const Instance& in = scene_->instances[instance];
    const Mesh& m = scene_->meshes[in.mesh];
    const glm::uvec3& t = m.triangles[tri];
    return {TransformPoint(in.transform, m.positions[t.x]),
            TransformPoint(in.transform, m.positions[t.y]),
            TransformPoint(in.transform, m.positions[t.z])};
  }
  uint32_t MaterialOf(uint32_t instance, uint32_t tri) const {
    const Instance& in = scene_->instances[instance];
    if (in.material >= 0) return static_cast<uint32_t>(in.material);
    return scene_->meshes[in.mesh].materials[tri];
  }

  // The sheet tag (Surfel::sheet) of a triangle of a thin material: 1-255, a hash of the instance
  // and the triangle's piece of its mesh (MeshPieces), so that separate sheets (two crossing
  // leaves) differ and the triangles of one sheet agree; 0 for other materials.
  uint8_t SheetOf(uint32_t instance, uint32_t tri) const {
    const std::vector<uint32_t>& pieces = mesh_pieces_[scene_->instances[instance].mesh];
    if (pieces.empty() || !scene_->materials[MaterialOf(instance, tri)].thin) return 0;
    return static_cast<uint8_t>(1 + HashCombine(instance, pieces[tri]) % 255);
  }

  // Area lights: every front-emitting triangle with non-zero emission and area.
  struct Emitter {
    WorldTriangle tri;
    glm::vec3 normal;
    glm::vec3 emission;
    float area;
  };
  const std::vector<Emitter>& emitters() const { return emitters_; }
  // Cumulative power weights (emission luminance * area), emitters().size() + 1 entries.
  const std::vector<double>& emitter_cdf() const { return emitter_cdf_; }
  // The emitter whose CDF interval holds u in [0, 1).
  size_t PickEmitter(double u) const;

  // Size of the scene (the longest extent of its bounds) and its bounds.
  float extent() const { return extent_; }
  const Bounds& bounds() const { return bounds_; }

 private:
  const Scene* scene_;
  std::vector<int64_t> instance_first_;
  std::vector<std::vector<uint32_t>> mesh_pieces_;  // per mesh; empty where nothing is thin
  std::vector<Emitter> emitters_;
  std::vector<double> emitter_cdf_;
  Bounds bounds_;
  float extent_ = 0.0f;
};

}  // namespace pbgi::internal

#endif  // PBGI_SCENE_SCENE_INDEX_H_
