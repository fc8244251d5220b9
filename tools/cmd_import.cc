// `pbgi import MESH -o OUT.ply [-n N | --density D] [--sun DX,DY,DZ[,R,G,B]] [--sky R,G,B]`:
// a mesh file through Assimp, sampled into surfels with direct light baked, streamed to PLY.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "base/proc.h"
#include "pbgi/ply.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/command.h"

namespace pbgi::tools {
namespace {

// "a,b,c" or "a,b,c,d,e,f" -> numbers; `what` names the option in errors.
absl::StatusOr<std::vector<float>> ParseFloats(const std::string& text, const char* what, size_t n1,
                                               size_t n2) {
  std::vector<float> v;
  for (absl::string_view part : absl::StrSplit(text, ',')) {
    float f = 0.0f;
    if (!absl::SimpleAtof(part, &f) || !std::isfinite(f)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: '%s' is not a number in '%s'", what, part, text));
    }
    v.push_back(f);
  }
  if (v.size() != n1 && v.size() != n2) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s wants %d or %d comma-separated numbers, got '%s'", what, n1, n2, text));
  }
  return v;
}

// "1000", "2.5M", "1e8", "100k" -> a count (decimal suffixes k, M, G).
absl::StatusOr<int64_t> ParseCount(const std::string& text) {
  std::string s = text;
  double mult = 1.0;
  if (!s.empty()) {
    const char c = s.back();
    mult = (c == 'k' || c == 'K')   ? 1e3
           : (c == 'm' || c == 'M') ? 1e6
           : (c == 'g' || c == 'G') ? 1e9
                                    : 1.0;
    if (mult != 1.0) s.pop_back();
  }
  double v = 0.0;
  if (s.empty() || !absl::SimpleAtod(s, &v) || !(v >= 0.0) || !std::isfinite(v * mult) ||
      v * mult > 9e18) {
    return absl::InvalidArgumentError(
        absl::StrFormat("'%s' is not a point count (examples: 1000000, 10M, 1e8)", text));
  }
  return static_cast<int64_t>(std::llround(v * mult));
}

struct Options {
  std::string mesh;
  std::string out;
  std::string points;
  double density = 0.0;
  std::string sun;
  std::string sky;
  uint64_t seed = 1;
  int sky_rays = 8;
  bool ascii = false;
};

absl::Status Run(const Options& o) {
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(o.out));
  int64_t points = 0;
  if (!o.points.empty()) {
    PBGI_ASSIGN_OR_RETURN(points, ParseCount(o.points));
  }
  if ((points > 0) == (o.density > 0)) {
    return absl::InvalidArgumentError("give exactly one of -n POINTS and --density D");
  }
  ImportReport report;
  PBGI_ASSIGN_OR_RETURN(Scene scene, ImportMesh(o.mesh, &report));
  for (const std::string& w : report.warnings) {
    absl::FPrintF(stderr, "pbgi import: warning: %s\n", w.c_str());
  }
  if (!o.sun.empty()) {
    PBGI_ASSIGN_OR_RETURN(std::vector<float> v, ParseFloats(o.sun, "--sun", 3, 6));
    glm::vec3 d(v[0], v[1], v[2]);
    if (!(glm::length(d) > 0.0f)) return absl::InvalidArgumentError("--sun: zero direction");
    scene.lights.has_sun = true;
    scene.lights.sun.direction = glm::normalize(d);
    scene.lights.sun.radiance = v.size() == 6 ? glm::vec3(v[3], v[4], v[5]) : glm::vec3(1.0f);
  }
  if (!o.sky.empty()) {
    PBGI_ASSIGN_OR_RETURN(std::vector<float> v, ParseFloats(o.sky, "--sky", 3, 3));
    scene.lights.sky = glm::vec3(v[0], v[1], v[2]);
  }
  if (o.sun.empty() && o.sky.empty()) {
    scene.lights.sky = glm::vec3(1.0f);
    absl::FPrintF(stderr, "pbgi import: no --sun or --sky given: lighting with a white sky\n");
  }
  scene.lights.sky_rays = o.sky_rays;
  absl::FPrintF(stderr,
                "pbgi import: %s: %d meshes, %d placements, %d triangles placed, %d materials, "
                "area %.6g\n",
                o.mesh.c_str(), report.meshes, report.instances, scene.TriangleCount(),
                report.materials, scene.SurfaceArea());
  auto shared = std::make_shared<const Scene>(std::move(scene));
  SamplerOptions sampler;
  sampler.count = points;
  sampler.density = o.density;
  sampler.seed = o.seed;
  const auto start = std::chrono::steady_clock::now();
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<SurfelSource> source,
                        MakeSceneSurfelSource(shared, sampler));
  PlyWriterOptions wo;
  wo.ascii = o.ascii;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyWriter> writer, PlyWriter::Create(o.out, wo));
  const int64_t count = source->KnownCount();
  const bool tty = StderrIsTerminal();
  std::vector<Surfel> buf(1 << 16);
  int64_t done = 0;
  auto last = start;
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(size_t n, source->Next(absl::MakeSpan(buf)));
    if (n == 0) break;
    PBGI_RETURN_IF_ERROR(writer->Write(absl::MakeConstSpan(buf.data(), n)));
    done += static_cast<int64_t>(n);
    const auto now = std::chrono::steady_clock::now();
    if (now - last > std::chrono::milliseconds(tty ? 200 : 1000)) {
      last = now;
      const double secs = std::chrono::duration<double>(now - start).count();
      absl::FPrintF(stderr, "%s%d / %d points (%.1f%%), %.2f M points/s%s", tty ? "\r" : "", done,
                    count, 100.0 * static_cast<double>(done) / static_cast<double>(count),
                    static_cast<double>(done) / secs * 1e-6, tty ? "" : "\n");
    }
  }
  PBGI_RETURN_IF_ERROR(writer->Close());
  if (tty) absl::FPrintF(stderr, "\n");
  const double secs =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  absl::PrintF("%s: %d points, %.2f s, %.0f points/s, peak memory %s\n", o.out.c_str(), done, secs,
               static_cast<double>(done) / secs, FormatBytes(internal::PeakRssBytes()).c_str());
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto o = std::make_shared<Options>();
    app->add_option("mesh", o->mesh, "Mesh file (OBJ, PLY, glTF/GLB, FBX, DAE, STL, 3MF, ...)")
        ->required();
    app->add_option("-o,--output", o->out, "Output PLY file")->required();
    app->add_option("-n,--points", o->points, "Number of surfels (10M, 1e8, ...)");
    app->add_option("--density", o->density, "Surfels per unit area");
    app->add_option("--sun", o->sun,
                    "Sun direction (towards the sun) and radiance: DX,DY,DZ[,R,G,B]");
    app->add_option("--sky", o->sky, "Uniform sky radiance: R,G,B");
    app->add_option("--sky-rays", o->sky_rays, "Shadow rays per surfel for the sky")
        ->capture_default_str();
    app->add_option("--seed", o->seed, "Sampling seed")->capture_default_str();
    app->add_flag("--ascii", o->ascii, "Write ASCII PLY instead of binary");
    return [o]() { return Run(*o); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(import, "import",
                      "Sample a mesh file (through Assimp) into surfels with direct light, to PLY",
                      Setup());
}  // namespace pbgi::tools
