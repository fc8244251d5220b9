// The flags that choose how `pbgi shade`, `demo` and `eval` draw the gathered elements
// (RasterOptions::footprint) and how finely the cut takes curved nodes (Cut::curved_scale,
// Cut::curved_box_scale). The commands default to footprints that tile with curved_scale 0.3
// (docs/eval.md, "Session 4") and curved_box_scale 1 ("Session 13"), and to the cut that sees
// radiance (ShadeOptions::radiance_contrast, docs/design.md "A cut that sees radiance").
#ifndef PBGI_TOOLS_FOOTPRINT_FLAGS_H_
#define PBGI_TOOLS_FOOTPRINT_FLAGS_H_

#include <string>

#include "CLI/CLI.hpp"
#include "pbgi/raster.h"
#include "pbgi/shade.h"

namespace pbgi::tools {

// "polygons" or "splats", as the flags spell them (CLI checks the spelling).
inline Footprint ParseFootprint(const std::string& name) {
  return name == "polygons" ? Footprint::kPolygons : Footprint::kSplats;
}

struct FootprintFlags {
  std::string footprint = "polygons";  // or "splats"
  float curved_scale = 0.3f;
  float curved_box_scale = 1.0f;
  float radiance_contrast = kRecommendedRadianceContrast;  // ShadeOptions::radiance_contrast
};

inline void AddRadianceContrastFlag(CLI::App* app, float* k) {
  app->add_option("--radiance-contrast", *k,
                  "Where radiance is shaded: nodes whose parts' radiance strays from their mean "
                  "are taken whole only below the max solid angle over this times their "
                  "contrast (Cut::radiance_contrast; 0: off)")
      ->check(CLI::Range(0.0f, 1e6f))
      ->capture_default_str();
}

inline void AddFootprintFlags(CLI::App* app, FootprintFlags* f) {
  app->add_option("--footprint", f->footprint,
                  "splats (round splats, first layer summed freely) or polygons (footprints "
                  "that tile, exact area coverage; see pbgi/raster.h)")
      ->check(CLI::IsMember({"splats", "polygons"}))
      ->capture_default_str();
  app->add_option("--curved-scale", f->curved_scale,
                  "Curved nodes are taken whole only below this times the max solid angle")
      ->check(CLI::Range(1e-3f, 1.0f))
      ->capture_default_str();
  app->add_option("--curved-box-scale", f->curved_box_scale,
                  "Curved nodes are taken whole only when their box, too, subtends below this "
                  "times the max solid angle (0: off)")
      ->check(CLI::Range(0.0f, 1e3f))
      ->capture_default_str();
  AddRadianceContrastFlag(app, &f->radiance_contrast);
}

inline void ApplyFootprintFlags(const FootprintFlags& f, ShadeOptions* options) {
  options->raster.footprint = ParseFootprint(f.footprint);
  options->cut.curved_scale = f.curved_scale;
  options->cut.curved_box_scale = f.curved_box_scale;
  options->radiance_contrast = f.radiance_contrast;
}

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_FOOTPRINT_FLAGS_H_
