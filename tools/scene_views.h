// Scenes by name or path for the commands, their default cameras, and camera views shaded
// from a database (the `shade --scene`, `eval` and `demo` commands share these).
#ifndef PBGI_TOOLS_SCENE_VIEWS_H_
#define PBGI_TOOLS_SCENE_VIEWS_H_

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "tools/image_io.h"
#include "tools/mesh_flags.h"

namespace pbgi::tools {

// Which world axis points up in a mesh file. pbgi's frame is Z-up (the sun, the sky, the
// cameras); glTF, and many OBJ and FBX files, are Y-up.
enum class UpAxis { kZ, kY };
absl::StatusOr<UpAxis> ParseUpAxis(const std::string& text);
const char* UpAxisName(UpAxis up);

// A procedural scene's name (see ProceduralSceneNames()) or a mesh file that Assimp reads; a
// Y-up mesh is turned to Z-up (+90 degrees about x: y becomes z).
// Mesh files are oriented (OrientScene()) unless `orient` is false, as `pbgi import --orient`;
// `report`, when given, receives what the import did (untouched for a procedural scene).
absl::StatusOr<std::shared_ptr<const Scene>> LoadScene(const std::string& spec, uint64_t seed,
                                                       int size, UpAxis up = UpAxis::kZ,
                                                       bool orient = true,
                                                       ImportReport* report = nullptr);
// LoadScene() with ApplyLightFlags(): a mesh file without --sun or --sky is lit by a white sky,
// and `tool` says so on stderr (irradiance and glossy light would otherwise be zero
// everywhere, and compare as exact).
// `recorded`, when given: a database's stats; a mesh file without --sun or --sky then takes the
// lights recorded there (LightsProvenance(), as `pbgi import` or `eval --view` baked it), not a
// white sky, as `pbgi shade` does (WithRecordedLights()).
absl::StatusOr<std::shared_ptr<const Scene>> LoadLitScene(
    const std::string& spec, uint64_t seed, int size, UpAxis up, bool orient,
    const LightFlags& lights, const char* tool, ImportReport* report = nullptr,
    const std::map<std::string, std::string>* recorded = nullptr);
// "--orient auto|none" -> whether to orient.
absl::StatusOr<bool> ParseOrient(const std::string& text);
// One line for a summary: what OrientScene() did.
std::string DescribeOrientation(const OrientReport& r);
// Turns every instance of a Y-up scene to Z-up.
void RotateYUpToZUp(Scene* scene);

// What identifies a scene's geometry: "scene.name", "scene.seed" and "scene.size" (procedural),
// "scene.up" and "scene.orient" (mesh files), "scene.triangles", "scene.bounds" and
// "scene.geometry" (a hash of every instanced triangle's vertices, in winding order). `pbgi
// generate` and `pbgi import` write it into their PLY's comments, and the builds store it in the
// meta record's stats, so that a view can be checked against the database it is shaded from.
std::map<std::string, std::string> SceneFingerprint(const Scene& scene, uint64_t seed, int size,
                                                    UpAxis up, bool oriented = true);
// SceneFingerprint() of the scene that `spec` names (LoadScene()'s), as a view checks it against
// a database: a mesh file's also records the file as "scene.file", as `pbgi import` does.
std::map<std::string, std::string> SpecFingerprint(const Scene& scene, const std::string& spec,
                                                   uint64_t seed, int size, UpAxis up,
                                                   bool oriented);
// Lights from --sun, --sky and --sky-rays (tools/mesh_flags.h) for `scene`: those given replace
// the scene's. A mesh file (`mesh`) brings no lights: without --sun or --sky it is lit by a white
// sky, and `*defaulted` (when given) says so; a procedural scene without either keeps its own
// lights and sky rays. InvalidArgument names a malformed option.
absl::Status ApplyLightFlags(const LightFlags& flags, bool mesh, Scene* scene,
                             bool* defaulted = nullptr);

// The lights that baked an imported mesh's surfels ("light.sun": DX,DY,DZ,R,G,B; "light.sky":
// R,G,B), kept with its fingerprint so that a view of the mesh is lit the same way; and back.
std::map<std::string, std::string> LightsProvenance(const Lights& lights);
// The scene with the lights recorded in `stats`, when it has none of its own (a mesh file).
std::shared_ptr<const Scene> WithRecordedLights(std::shared_ptr<const Scene> scene,
                                                const std::map<std::string, std::string>& stats);

// OK when the database was built from this scene (same name, triangle count and geometry hash),
// or has no fingerprint. FailedPrecondition naming both scenes, each recorded field that differs
// (database against view) and the fix when they differ.
// Without a fingerprint, *warning is set when the database's bounds do not fit the scene's.
absl::Status CheckSceneMatchesDatabase(const Scene& scene,
                                       const std::map<std::string, std::string>& fingerprint,
                                       const StoreMeta& meta, const std::string& db_path,
                                       std::string* warning);

// A camera that frames the scene: hand-placed for the procedural scenes, from the bounds
// for anything else.
Camera DefaultCamera(const Scene& scene, int width, int height);

// Receivers to shade: each one's glossy lobe centred on its normal.
std::vector<ShadeReceiver> ShadeReceiversOf(absl::Span<const Receiver> receivers);

// "X,Y,Z" -> vector.
absl::StatusOr<glm::vec3> ParseVec3(const std::string& text);

// The receivers of a camera view: one per pixel whose primary ray hits, lifted off the surface
// by the tracer's epsilon, its normal turned to the side the camera sees; the glossy lobe's
// centre is the mirrored view direction. pixel_of[i] is receiver i's pixel (row-major);
// surface[i] its hit's material (an object edge for ShadeMode::kShared).
struct CameraReceivers {
  int width = 0, height = 0;
  std::vector<CameraHit> hits;  // every pixel's primary hit
  std::vector<Receiver> receivers;
  std::vector<ShadeReceiver> shade;  // the same, with the glossy lobe's centre
  std::vector<uint32_t> pixel_of;
  std::vector<uint32_t> surface;
  // `options` with these receivers' image layout (for kShared; the spans point into this).
  ShadeOptions WithLayout(const ShadeOptions& options) const;
};
CameraReceivers MakeCameraReceivers(const Tracer& tracer, const Camera& camera);

struct ViewImages {
  Image occlusion;  // 1 - occlusion (white = open), grey
  Image indirect;   // diffuse indirect light: albedo / pi * irradiance
  // Glossy indirect light: the lobe-weighted mean radiance around each pixel's reflection
  // direction (ShadeResult::glossy); empty (0x0) unless the options ask for a glossy lobe.
  Image glossy;
  Image direct;     // direct light * albedo + emission, from the tracer
  Image composite;  // direct + indirect, sky where nothing was hit
  uint64_t receivers = 0;
  double trace_seconds = 0;
  ShadeStats shade;
  double compose_seconds = 0;  // the direct light (shadow rays) and the images, after shading
};

// Traces the camera's primary rays with Embree, shades the hit points from `db` (in
// options.mode; kShared gets the view's image layout) and composes the images. With an
// occlusion-only database, `indirect` is black and `composite` is direct * (1 - occlusion) plus the
// sky's ambient term.
// `after_shading`, when set, is called once the view is shaded, before it is composed; `db` is
// not used after it, so it may close the database (its page cache is then not held beside the
// images: the peak memory of a large view).
absl::StatusOr<ViewImages> RenderView(const Tracer& tracer, Database& db, const Camera& camera,
                                      const ShadeOptions& options,
                                      const std::function<void()>& after_shading = {});

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_SCENE_VIEWS_H_
