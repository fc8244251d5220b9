// `pbgi eval --view`: the error of a camera view, pixel by pixel. Shades the primary hits of a
// view with PBGI and with the Embree reference (the same receivers), and writes both images and
// a signed error heat map with the figures that a person sees as defects: the mean and the tail
// of |error|, and the worst 8x8 tile (a block or a streak shows there even when the mean is
// small). The image metrics are a plain function so that tests can check them.
#ifndef PBGI_TOOLS_VIEW_EVAL_H_
#define PBGI_TOOLS_VIEW_EVAL_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "glm/vec3.hpp"
#include "pbgi/scene.h"
#include "tools/image_io.h"
#include "tools/mesh_flags.h"
#include "tools/sharing_flags.h"

namespace pbgi::tools {

// Errors of an image against a reference over its covered pixels.
struct ImageErrors {
  uint64_t pixels = 0;                 // covered pixels compared
  double mae = 0, rmse = 0, bias = 0;  // bias: mean signed error (got - reference)
  double p99 = 0;                      // 99th percentile of |error|
  double max = 0;
  // The largest mean |error| over the tiles x tiles blocks of the image (tiles with at least a
  // quarter of their pixels covered), and where it lies (pixel of its top-left corner).
  double worst_tile = 0;
  int worst_tile_x = -1, worst_tile_y = -1;
  // The mean of the reference over the covered pixels (to state errors relative to it).
  double reference_mean = 0;
};

// `got` and `reference` are width * height scalars, row-major; `covered[p]` marks the pixels
// to compare.
ImageErrors CompareImages(int width, int height, const std::vector<double>& got,
                          const std::vector<double>& reference, const std::vector<uint8_t>& covered,
                          int tile = 8);

// A signed error map: white at 0, red where got > reference, blue where below, saturated at
// |error| = scale; uncovered pixels grey.
Image ErrorHeatMap(int width, int height, const std::vector<double>& got,
                   const std::vector<double>& reference, const std::vector<uint8_t>& covered,
                   double scale);

struct ViewEvalArgs {
  std::string scene = "city";
  LightFlags lights;  // a mesh file's lights, or a procedural scene's replaced (LoadLitScene)
  std::string out_dir = "out/eval-view";
  std::string mode = "occlusion";  // occlusion | irradiance | glossy
  // glossy: the lobe around each pixel's mirrored view direction (CameraReceivers::shade),
  // against Tracer::ReferenceGlossy of the same lobe.
  GlossyParams lobe;
  int64_t points = 4'000'000;
  int width = 960, height = 540;
  int rays = 4096;  // reference rays per pixel (two independent halves estimate its own error)
  std::vector<float> solid_angles = {0.03f};
  std::vector<int> resolutions = {12};
  std::vector<std::string> cuts = {"cosine"};
  std::vector<std::string> footprints = {"polygons"};      // swept: polygons | splats
  float curved_scale = 0.3f;                               // Cut::curved_scale
  float curved_box_scale = 1.0f;                           // Cut::curved_box_scale
  float radiance_contrast = kRecommendedRadianceContrast;  // ShadeOptions::radiance_contrast
  std::string hitsides = "front";
  uint64_t memory_bytes = uint64_t{512} << 20;  // the build's cap
  uint64_t cache_bytes = uint64_t{256} << 20;   // the shading cache
  int threads = 0;
  uint64_t seed = 1;
  int size = 0;
  std::string up = "z";         // a mesh file's up axis
  std::string orient = "auto";  // a mesh file: auto | none
  double error_scale = 0.1;     // the heat map saturates at this |error| (occlusion units)
  // Modes: every setting per receiver (ShadeMode::kExact) and, unless exact_only, shared
  // (kShared) at every spacing x tolerance, seeing the receivers as an image ("image") or as a
  // point set ("points").
  bool exact_only = false;
  bool shared_only = false;
  std::vector<int> spacings = {8};
  std::vector<float> tolerances = {0.05f};
  float radius_factor = 0.5f;
  std::string layout = "image";
  // Far-field sharing rows: every mode row again with ShadeOptions::far_sharing at each of
  // these distance factors (none: no such rows); far_only drops the rows without it.
  FarSharingFlags far;
  std::vector<float> far_factors;
  bool far_only = false;
  // The reference at these rays per pixel, timed and compared like PBGI, for the speed ratio at
  // equal image MAE (none: no ratio).
  std::vector<int> ray_sweep;
  int repeat = 1;  // time every row this many times, keep the median (the results repeat)
  // Only the pixels of this window (x, y, width, height; empty: the whole image) are shaded and
  // compared, to look at one artifact closely; the images keep the view's size.
  std::string window;
  // A CSV of the first PBGI row's receivers (pixel, position, normal, reference, PBGI, error).
  std::string dump_receivers;
  // A database already built from this scene (same fingerprint) instead of building one from
  // `points` surfels; empty: build.
  std::string db;
};

absl::Status RunViewEval(const ViewEvalArgs& args);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_VIEW_EVAL_H_
