// The flags that say how a mesh file is read, the same in `pbgi import`, `shade --scene` and
// `eval`: its up axis and whether it is oriented (scene/orient.cc); parsed by ParseUpAxis and
// ParseOrient (tools/scene_views.h). And the lights of a mesh file, which brings none, the same
// in `pbgi import` and `eval` (ApplyLightFlags, tools/scene_views.h).
#ifndef PBGI_TOOLS_MESH_FLAGS_H_
#define PBGI_TOOLS_MESH_FLAGS_H_

#include <string>

#include "CLI/CLI.hpp"

namespace pbgi::tools {

inline void AddMeshFlags(CLI::App* app, std::string* up, std::string* orient) {
  app->add_option("--up", *up, "Up axis of a mesh file: z, or y (glTF, many OBJ files)")
      ->check(CLI::IsMember({"y", "z", "Y", "Z"}))
      ->capture_default_str();
  app->add_option("--orient", *orient,
                  "Mesh files: auto winds closed shells outward and marks open or non-manifold "
                  "parts thin (two-sided); none keeps the file's winding")
      ->check(CLI::IsMember({"auto", "none"}))
      ->capture_default_str();
}

// --sun DX,DY,DZ[,R,G,B] (towards the sun), --sky R,G,B, --sky-rays N.
struct LightFlags {
  std::string sun;
  std::string sky;
  int sky_rays = 8;
};

inline void AddLightFlags(CLI::App* app, LightFlags* f, const char* whose) {
  app->add_option(
      "--sun", f->sun,
      std::string("Sun direction (towards the sun) and radiance: DX,DY,DZ[,R,G,B]") + whose);
  app->add_option("--sky", f->sky, std::string("Uniform sky radiance: R,G,B") + whose);
  app->add_option("--sky-rays", f->sky_rays, "Shadow rays per surfel for the sky")
      ->check(CLI::Range(1, 1024))
      ->capture_default_str();
}

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_MESH_FLAGS_H_
