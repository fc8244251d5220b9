// Scenes: the inputs of Coherent PBGI (docs/design.md, "Scenes").
//
// A Scene is triangles (meshes placed by instances), materials (albedo, emission) and lights (a
// sun, a uniform sky, and area lights, which are simply the emissive triangles). The same scene
// feeds Embree through a Tracer (camera rays, shadow rays, the reference integrator) and the
// surfel sampler that streams points to the builder, so both sides see one geometry and one
// lighting function.
//
// Radiance convention (used everywhere in this header): a diffuse surface of albedo `a` lit by
// irradiance E reflects radiance a * E / pi. The lighting function DirectLight() returns E / pi,
// so a surfel's radiance is albedo * DirectLight + emission. In these units:
// - a sun of `radiance` S gives a surface facing it at angle theta: albedo * S * cos(theta);
// - a uniform sky of radiance K gives: albedo * K * (cosine-weighted visible fraction);
// - an emissive triangle of emission Le is a one-sided Lambertian emitter of radiance Le.
//
// Thread safety: Scene is plain data. A Tracer is immutable after Create() and all its const
// methods may be called from many threads at once. A SurfelSource belongs to one thread (it uses
// TBB internally).
#ifndef PBGI_SCENE_H_
#define PBGI_SCENE_H_

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/types/span.h"
#include "glm/mat4x4.hpp"
#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"

namespace pbgi {

struct Material {
  glm::vec3 albedo{0.8f};
  glm::vec3 emission{0.0f};  // one-sided: emitted on the side the triangle's normal points to
  // A thin sheet (a leaf, a card): its back side is just the other side of the sheet, not the
  // inside of a solid. The sampler's hidden-sample test (SamplerOptions::drop_hidden) ignores
  // such triangles; every other triangle is taken to face out of solid matter.
  bool thin = false;
};

struct Sun {
  glm::vec3 direction{0.0f, 0.0f, 1.0f};  // unit vector from the scene towards the sun
  glm::vec3 radiance{0.0f};               // see the radiance convention above
};

struct Lights {
  bool has_sun = false;
  Sun sun;
  glm::vec3 sky{0.0f};         // uniform sky radiance (rays that leave the scene see it)
  int sky_rays = 4;            // stratified cosine-weighted shadow rays per point for the sky
  int area_light_samples = 8;  // stratified shadow rays per point over all emissive triangles
};

// An indexed triangle mesh in its own object space. The normal of triangle (a, b, c) is
// normalize(cross(b - a, c - a)): winding decides the front side.
struct Mesh {
  std::vector<glm::vec3> positions;
  std::vector<glm::uvec3> triangles;
  std::vector<uint32_t> materials;  // one material index per triangle
};

// A placement of a mesh. Instancing keeps scenes compact: a forest of a thousand trees holds
// a few tree meshes.
struct Instance {
  uint32_t mesh = 0;
  glm::mat4 transform{1.0f};  // affine, object to world
  int32_t material = -1;      // >= 0: overrides the mesh's per-triangle materials
};

struct Scene {
  std::string name;
  std::vector<Mesh> meshes;
  std::vector<Instance> instances;
  std::vector<Material> materials;
  Lights lights;
  // False for occlusion-only scenes (the forest): samplers then bake no radiance.
  bool has_radiance = true;

  // Checks indices, material references and finite transforms; names what is wrong.
  absl::Status Validate() const;
  // Bounds of all instanced triangles in world space.
  Bounds ComputeBounds() const;
  // Total world-space area of all instanced triangles (double precision).
  double SurfaceArea() const;
  // Number of instanced triangles (what the sampler and Embree see).
  int64_t TriangleCount() const;
};

// ---- Procedural scenes ------------------------------------------------------------------------

struct SceneOptions {
  uint64_t seed = 1;
  // Scale of the scene's content: city blocks per side, trees per side of the forest. 0 picks
  // the scene's default. Point counts do not depend on it: the sampler sets the density.
  int size = 0;
};

// The names MakeScene() knows: cornell, city, forest, disk, sphere-in-box.
std::vector<std::string> ProceduralSceneNames();
absl::StatusOr<Scene> MakeScene(absl::string_view name, const SceneOptions& options = {});

// Cornell box in [0,1]^3 (z up, open towards -y), two white blocks, a red wall at x=0, a green
// wall at x=1, and an emissive quad under the ceiling (the only light).
Scene MakeCornellScene(const SceneOptions& options);
// A grid of city blocks with buildings of many sizes on a ground plane, lit by a sun and a sky.
Scene MakeCityScene(const SceneOptions& options);
// Many instanced trees (trunks and leaf quads) on a ground plane; occlusion only.
Scene MakeForestScene(const SceneOptions& options);
// A disk of `radius` (a `segments`-gon) in the plane z = 0 whose front faces -z, emission
// `emission`, albedo 0, no other light. From a point at (0, 0, -h) facing +z the disk subtends
// the form factor r^2 / (h^2 + r^2) (occlusion), and irradiance pi * emission * r^2/(h^2 + r^2).
Scene MakeDiskScene(float radius = 1.0f, int segments = 256, glm::vec3 emission = glm::vec3(1.0f));
// A closed box [-2,2]^3 with inward faces (albedo 0.5) around an emissive sphere (radius 0.5,
// emission 1, albedo 0) at the origin, and a sun and a sky outside that must not leak in. A wall
// point at distance d from the center facing it sees the sphere with form factor (R/d)^2.
Scene MakeSphereInBoxScene(const SceneOptions& options);

// The glossy lobe of ReferenceGlossy(): the same D as RasterOptions' (pbgi/raster.h).
struct GlossyParams {
  GlossyLobe lobe = GlossyLobe::kPhong;  // kPhong or kGgx
  float phong_exponent = 32.0f;          // >= 0
  float ggx_roughness = 0.2f;            // (0, 1]
};

// ---- Embree -----------------------------------------------------------------------------------

// A pinhole camera. Pixel (x, y) has y = 0 at the top row.
struct Camera {
  glm::vec3 eye{0.0f, -1.0f, 0.5f};
  glm::vec3 look_at{0.0f, 0.0f, 0.5f};
  glm::vec3 up{0.0f, 0.0f, 1.0f};
  float fov_y_degrees = 45.0f;
  int width = 640;
  int height = 480;

  // The unit direction of the ray through the point (px, py) in pixel coordinates (pixel
  // centers are at x + 0.5).
  glm::vec3 Direction(float px, float py) const;
};

struct Hit {
  bool hit = false;
  float distance = 0.0f;
  glm::vec3 position{0.0f};
  glm::vec3 normal{0.0f};  // unit geometric normal of the triangle's front side (by winding)
  bool front = false;      // the ray arrived at the front side
  uint32_t material = 0;
  uint32_t instance = 0;
  uint32_t triangle = 0;  // index in the instance's mesh
};

// What a camera pixel sees: a receiver for shading, with the normal turned to face the camera.
// The position is the hit pulled back towards the eye by Tracer::epsilon().
struct CameraHit {
  bool hit = false;
  glm::vec3 position{0.0f};
  glm::vec3 normal{0.0f};
  uint32_t material = 0;
  uint8_t sheet = 0;  // the sheet tag of a thin surface hit (Surfel::sheet), else 0
};

// A point that receives light: a shading point and its unit normal.
// Receiver (a shading point: position and normal) is defined in pbgi/surfel.h.

// Embree over a Scene: one RTCScene per mesh, instanced into a top-level RTCScene.
// Thread safety: immutable after Create(); every method is const and safe to call from many
// threads. REQUIRES: the Scene outlives the Tracer and is not modified while it lives.
class Tracer {
 public:
  static absl::StatusOr<std::unique_ptr<Tracer>> Create(const Scene& scene);
  ~Tracer();
  Tracer(const Tracer&) = delete;
  Tracer& operator=(const Tracer&) = delete;

  const Scene& scene() const;
  // Offset along the normal for rays leaving a surface (relative to the scene's size).
  float epsilon() const;

  // Closest hit along origin + t * dir, t in (0, tmax). REQUIRES: dir is unit length.
  Hit Intersect(const glm::vec3& origin, const glm::vec3& dir, float tmax) const;
  // Whether anything lies along origin + t * dir, t in (0, tmax).
  bool Occluded(const glm::vec3& origin, const glm::vec3& dir, float tmax) const;

  // One ray per pixel center, TBB-parallel; row-major, width * height entries.
  std::vector<CameraHit> TraceCamera(const Camera& camera) const;

  // The lighting function: irradiance / pi at point p with unit normal n from the scene's sun,
  // sky and emissive triangles, with shadow rays. `key` seeds the stratified samples (same key,
  // same answer). The surfel baker and the reference integrator both use it.
  glm::vec3 DirectLight(const glm::vec3& p, const glm::vec3& n, uint64_t key) const;
  // Outgoing radiance of a surface point on the front side of `material`:
  // albedo * DirectLight + emission.
  glm::vec3 SurfaceRadiance(const glm::vec3& p, const glm::vec3& n, uint32_t material,
                            uint64_t key) const;
  // The same for many points, in groups of kGroup consecutive points that share one random
  // shift of their light samples (drawn from `key` and the group's index); the point in slot i
  // of its group draws a stratified set of its own, shifted by i's share of the strata, so the
  // group's sets are stratified together: every estimate is unbiased, and neighbours that
  // share a place average their errors (docs/design.md, "Baking"). `slots`: each point's slot,
  // when the span holds a group's points with some left out (a dropped sample); empty: its
  // index in its group. REQUIRES: all spans have the same size; slots < kGroup.
  static constexpr int kGroup = 16;
  void SurfaceRadiance(absl::Span<const glm::vec3> p, absl::Span<const glm::vec3> n,
                       absl::Span<const uint32_t> materials, uint64_t key,
                       absl::Span<glm::vec3> out, absl::Span<const uint8_t> slots = {}) const;

  // Reference integrator (Embree against the scene geometry): `rays` stratified
  // cosine-weighted rays from p around n. Occlusion: the fraction that hit something within
  // max_distance (any side). Irradiance: the integral of incident radiance times cos over the
  // hemisphere (one diffuse bounce: the radiance of each hit point is SurfaceRadiance(); the
  // back of a thin sheet (Material::thin) is lit from its own side, albedo * DirectLight(p, -n);
  // other back sides are 0, the inside of a solid; rays that miss contribute nothing, the sky
  // being direct light). Divide by pi for RenderMan's "average radiance" convention.
  float ReferenceOcclusion(const glm::vec3& p, const glm::vec3& n, int rays, float max_distance,
                           uint64_t seed = 1) const;
  // `max_distance`: hits farther than this count as misses (what lies within a distance band;
  // pixel_error --bands).
  glm::vec3 ReferenceIrradiance(const glm::vec3& p, const glm::vec3& n, int rays, uint64_t seed = 1,
                                float max_distance = std::numeric_limits<float>::infinity()) const;
  // Glossy radiance as pbgi/raster.h defines it for ShadeResult::glossy: the lobe-weighted
  // mean radiance over the directions w above both the receiver's tangent plane (n.w > 0) and
  // the lobe's (r.w > 0), r = normalize(reflection),
  //   integral L(w) D(angle(w, r)) dw / integral D(angle(w, r)) dw,
  // with L the same one-bounce radiance as ReferenceIrradiance (SurfaceRadiance() on front
  // sides, a thin sheet's back lit from its side, 0 on other back sides and misses). `rays`
  // stratified directions are drawn from D itself over r's hemisphere (each lobe's own inverse CDF
  // in cos(angle to r), see scene/sample_math.h); those below n's horizon are dropped, so the
  // estimate is the mean L of the rest: both integrals of the ratio estimated with the same samples
  // (consistent; its bias is O(1/rays)). 0 when no direction is left or the reflection is zero.
  // REQUIRES: a valid lobe (GlossyLobe kPhong or kGgx, the ranges of GlossyParams).
  glm::vec3 ReferenceGlossy(const glm::vec3& p, const glm::vec3& n, const glm::vec3& reflection,
                            const GlossyParams& lobe, int rays, uint64_t seed = 1) const;
  // ReferenceOcclusion with the same rays traced as Embree 16-wide packets (rtcOccluded16) instead
  // of one rtcOccluded1 per ray: the same answer; bench/scene compares their speed.
  float ReferenceOcclusionPackets(const glm::vec3& p, const glm::vec3& n, int rays,
                                  float max_distance, uint64_t seed = 1) const;
  // TBB-parallel batch forms; results in receiver order, deterministic for a seed.
  std::vector<float> ReferenceOcclusion(absl::Span<const Receiver> receivers, int rays,
                                        float max_distance, uint64_t seed = 1) const;
  std::vector<glm::vec3> ReferenceIrradiance(absl::Span<const Receiver> receivers, int rays,
                                             uint64_t seed = 1) const;
  std::vector<glm::vec3> ReferenceGlossy(absl::Span<const ShadeReceiver> receivers,
                                         const GlossyParams& lobe, int rays,
                                         uint64_t seed = 1) const;

 private:
  struct Impl;
  explicit Tracer(std::unique_ptr<Impl> impl);
  // Direct light (irradiance / pi) at up to kGroup points; `active` false skips a point;
  // slot[i] (nullptr: i) is point i's slot in its group (SurfaceRadiance()).
  void DirectLightGroup(int count, const glm::vec3* p, const glm::vec3* n, const bool* active,
                        const uint8_t* slot, uint64_t key, glm::vec3* out) const;
  // Shadow rays for up to kGroup points: blocked[i] for the active ones.
  void OccludedGroup(int count, const glm::vec3* origin, const glm::vec3* dir, const float* tfar,
                     const bool* active, bool* blocked) const;
  class HitRadiance;  // the reference's hits and their radiance (tracer.cc)
  std::unique_ptr<Impl> impl_;
};

// ---- Surfel sampling --------------------------------------------------------------------------

struct SamplerOptions {
  int64_t count = 0;     // number of surfels (exact), or
  double density = 0.0;  // surfels per unit area, used when count == 0
  uint64_t seed = 1;
  bool bake = true;  // bake direct light into radiance (never for occlusion-only scenes)
  int64_t chunk_size = 1 << 17;  // candidates generated per parallel batch (bounds the memory)
  // Drop samples that lie inside solid geometry: the Cornell floor under a block, the city's
  // ground under a building, a roof under a tower. No camera sees them, and PBGI would see them
  // through the solid's back faces. A sample is hidden when the ray along its own normal first
  // meets the back face of a non-thin triangle (see Material::thin).
  bool drop_hidden = true;
  // Where a triangle's k surfels go. kPieces (a cloud to shade with): a triangle of at most 32
  // surfels is cut into k pieces of equal area, as compact as it allows, each surfel at its
  // piece's centre, so that its disk covers its piece as well as a disk can (no two disks of a
  // small triangle in one corner, no disk hanging far over its edge); a triangle narrower than
  // 0.7 spacings gets its surfels evenly along its length, in the middle of its width; a larger
  // triangle gets a rotated Hammersley set. kUniform (points to test with, such as receivers):
  // the rotated Hammersley set everywhere, every point of a triangle equally likely, its edges
  // and corners too.
  enum class Placement { kPieces, kUniform };
  Placement placement = Placement::kPieces;
};

// A streaming SurfelSource over a scene's triangles. Surfels are stratified over the area
// (systematic sampling along the cumulative area of the triangles, then `placement` inside each
// triangle), each representing area/count: pi r^2 = area per surfel, so the total surfel area
// equals the mesh area. Normals are the triangles' geometric normals. Radiance is
// SurfaceRadiance() at the surfel. Memory is constant in the count (one chunk in flight);
// surfel i depends only on (scene, options, i), so the stream is identical for any number of
// threads. Not thread-safe (uses TBB internally).
//
// With drop_hidden (the default), a deterministic pilot pass (up to 2^17 stratified samples)
// estimates the visible fraction v of the area; the stream then draws count / v candidates as
// above and drops the hidden ones, so the count is within about 1% of the request (not exact:
// KnownCount() is -1), each surfel stands for the area / candidates, and the total surfel area
// is the visible area. When the pilot finds nothing hidden, nothing is tested or dropped and the
// count is exact, as without drop_hidden. Density mode asks for density * visible area.
absl::StatusOr<std::unique_ptr<SurfelSource>> MakeSceneSurfelSource(
    std::shared_ptr<const Scene> scene, const SamplerOptions& options);

// ---- Mesh import ------------------------------------------------------------------------------

// What OrientScene() did to a scene's meshes. A component is a set of triangles connected
// across manifold edges (edges that exactly two triangles share) once vertices are welded by
// position; it is closed when each of its edges is used by exactly two of its triangles in
// opposite directions.
struct OrientReport {
  int64_t components = 0;
  int64_t closed_components = 0;          // oriented outward (positive signed volume)
  int64_t cavities = 0;                   // closed shells inside an odd number of others: inward
  int64_t open_components = 0;            // with a boundary edge: thin
  int64_t non_manifold_components = 0;    // an edge used by three or more of its triangles: thin
  int64_t non_orientable_components = 0;  // no consistent winding exists: thin
  int64_t flipped_triangles = 0;          // triangles whose winding was reversed
  int64_t thin_triangles = 0;             // triangles given a thin material
  int64_t thin_materials = 0;             // thin copies of materials made for them
  int64_t welded_vertices = 0;            // vertices merged into another at the same position
  int64_t collapsed_triangles = 0;        // triangles that welding made degenerate: untouched
  int64_t mixed_mirror_meshes = 0;        // placed both mirrored and not: outward for the latter
  int64_t nesting_unchecked = 0;          // closed shells past the nesting test's work budget
                                          // (left facing out)
};

// Orients each mesh consistently, in its own object space (a mesh that all its instances mirror
// is oriented so that it faces out in world space). Vertices are welded by position (within a
// millionth of the mesh's diagonal); a winding is propagated across manifold edges; a closed
// component faces outward, or inward when it is nested in an odd number of closed components of
// the same mesh (the inner wall of a hollow solid). Components that are open, non-manifold or
// non-orientable keep their majority winding made consistent and get a copy of their material
// with Material::thin set (closed parts sharing that material keep the original). Nesting is not
// looked for across meshes; a closed box meant to be seen from inside (a room) is turned to face
// out like any solid.
OrientReport OrientScene(Scene* scene);

// What ImportMesh() found and dropped. Each dropped item is counted, and `warnings` has one
// line per kind of problem, with its count.
struct ImportReport {
  int64_t meshes = 0;     // meshes kept
  int64_t instances = 0;  // placements of kept meshes in the node hierarchy
  int64_t triangles = 0;  // triangles kept (per mesh, before instancing)
  int64_t materials = 0;
  int64_t meshes_without_normals = 0;  // normals are taken from the geometry anyway
  int64_t empty_meshes = 0;            // meshes with no usable triangles
  int64_t degenerate_triangles = 0;    // zero-area triangles, dropped
  int64_t nan_triangles = 0;           // triangles with a NaN or infinite vertex, dropped
  int64_t non_triangle_faces = 0;      // points and lines, dropped
  bool oriented = false;               // OrientScene() ran (ImportOptions::orient)
  OrientReport orientation;
  std::vector<std::string> warnings;
};

struct ImportOptions {
  // Run OrientScene() on the imported meshes; off keeps every triangle as the file winds it.
  bool orient = true;
};

// Reads a mesh file through Assimp (OBJ, PLY, glTF/GLB, FBX, DAE, STL, 3MF, ...), keeping its
// node hierarchy as instances and its materials' base (or diffuse) and emissive colours. A file
// that Assimp cannot read is an error naming the file and Assimp's reason; a file with nothing
// usable left is an error. The scene has no lights: the caller adds them.
absl::StatusOr<Scene> ImportMesh(const std::string& path, const ImportOptions& options,
                                 ImportReport* report);
// The same with the default options (oriented).
absl::StatusOr<Scene> ImportMesh(const std::string& path, ImportReport* report);

}  // namespace pbgi

#endif  // PBGI_SCENE_H_
