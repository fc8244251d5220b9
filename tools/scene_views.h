// Scenes by name or path for the commands, their default cameras, and camera views shaded
// from a database (the `shade --scene`, `eval` and `demo` commands share these).
#ifndef PBGI_TOOLS_SCENE_VIEWS_H_
#define PBGI_TOOLS_SCENE_VIEWS_H_

#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "tools/image_io.h"

namespace pbgi::tools {

// A procedural scene's name (see ProceduralSceneNames()) or a mesh file that Assimp reads.
absl::StatusOr<std::shared_ptr<const Scene>> LoadScene(const std::string& spec, uint64_t seed,
                                                       int size);

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
  Image direct;     // direct light * albedo + emission, from the tracer
  Image composite;  // direct + indirect, sky where nothing was hit
  uint64_t receivers = 0;
  double trace_seconds = 0;
  ShadeStats shade;
};

// Traces the camera's primary rays with Embree, shades the hit points from `db` (in
// options.mode; kShared gets the view's image layout) and composes the images. With an
// occlusion-only database, `indirect` is black and `composite` is direct * (1 - occlusion) plus the
// sky's ambient term.
absl::StatusOr<ViewImages> RenderView(const Tracer& tracer, Database& db, const Camera& camera,
                                      const ShadeOptions& options);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_SCENE_VIEWS_H_
