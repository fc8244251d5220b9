// `pbgi import MESH -o OUT.ply [-n N | --density D] [--sun DX,DY,DZ[,R,G,B]] [--sky R,G,B]`:
// a mesh file through Assimp, sampled into surfels with direct light baked, streamed to PLY.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "base/proc.h"
#include "pbgi/ply.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/command.h"
#include "tools/mesh_flags.h"
#include "tools/outputs.h"
#include "tools/progress.h"
#include "tools/scene_views.h"

namespace pbgi::tools {
namespace {

struct Options {
  std::string mesh;
  std::string out;
  std::string points;
  double density = 0.0;
  LightFlags lights;
  uint64_t seed = 1;
  bool ascii = false;
  std::string up = "z";
  std::string orient = "auto";
};

absl::Status Run(const Options& o) {
  if (!absl::EndsWith(o.out, ".ply")) {
    return absl::InvalidArgumentError(
        absl::StrFormat("-o %s: the output is a PLY point file (-o NAME.ply)", o.out));
  }
  PBGI_RETURN_IF_ERROR(CheckOutputsAreNotInputs({o.mesh}, {o.out}));
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(o.out));
  int64_t points = 0;
  if (!o.points.empty()) {
    PBGI_ASSIGN_OR_RETURN(points, ParseCount(o.points, "-n"));
  }
  if ((points > 0) == (o.density > 0)) {
    return absl::InvalidArgumentError("give exactly one of -n POINTS and --density D");
  }
  PBGI_ASSIGN_OR_RETURN(UpAxis up, ParseUpAxis(o.up));
  // A PLY of points only is a surfel (or point) cloud already: it is built, not sampled.
  if (absl::EndsWithIgnoreCase(o.mesh, ".ply")) {
    absl::StatusOr<PlyHeader> h = ReadPlyHeader(o.mesh);
    if (h.ok() && h->FaceCount() == 0) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s is a point cloud (%d vertices, no faces), not a mesh: build a database from it "
          "with `pbgi build %s -o DB` (radii and normals it lacks are estimated)",
          o.mesh, h->vertex_count, o.mesh));
    }
  }
  PBGI_ASSIGN_OR_RETURN(const bool orient, ParseOrient(o.orient));
  ImportReport report;
  ImportOptions import_options;
  import_options.orient = orient;
  PBGI_ASSIGN_OR_RETURN(Scene scene, ImportMesh(o.mesh, import_options, &report));
  if (up == UpAxis::kY) RotateYUpToZUp(&scene);
  for (const std::string& w : report.warnings) {
    absl::FPrintF(stderr, "pbgi import: warning: %s\n", w.c_str());
  }
  bool white_sky = false;
  PBGI_RETURN_IF_ERROR(ApplyLightFlags(o.lights, /*mesh=*/true, &scene, &white_sky));
  if (white_sky) {
    absl::FPrintF(stderr, "pbgi import: no --sun or --sky given: lighting with a white sky\n");
  }
  absl::FPrintF(stderr,
                "pbgi import: %s: %d meshes, %d placements, %d triangles placed, %d materials, "
                "area %.6g\n",
                o.mesh.c_str(), report.meshes, report.instances, scene.TriangleCount(),
                report.materials, scene.SurfaceArea());
  if (report.oriented) {
    absl::FPrintF(stderr, "pbgi import: %s: orientation: %s\n", o.mesh,
                  DescribeOrientation(report.orientation));
  } else {
    absl::FPrintF(stderr,
                  "pbgi import: %s: orientation: none (--orient none: as the file winds it)\n",
                  o.mesh);
  }
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
  // The parts that orientation marked thin (open sheets) are two-sided surfels: the flag goes
  // into the PLY, or `pbgi build` would read them one-sided.
  for (const Material& m : shared->materials) wo.two_sided = wo.two_sided || m.thin;
  auto fields = SceneFingerprint(*shared, o.seed, 0, up, orient);
  fields["scene.file"] = o.mesh;
  for (const auto& [k, v] : LightsProvenance(shared->lights)) fields[k] = v;
  fields["source"] = "pbgi import";
  fields["tool"] = kToolVersion;
  fields["date"] = NowIso8601();
  for (const auto& [k, v] : fields) wo.comments.push_back(absl::StrFormat("pbgi %s %s", k, v));
  // The sampler's bounds hold every surfel: `pbgi build` then needs no bounds pass
  // (docs/format.md, "Streamed input").
  wo.bounds = source->KnownBounds();
  const InterruptGuard interrupt;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyWriter> writer, PlyWriter::Create(o.out, wo));
  const int64_t count = source->KnownCount();
  Progress progress("import", "points", count);
  std::vector<Surfel> buf(1 << 16);
  int64_t done = 0;
  for (;;) {
    PBGI_RETURN_IF_ERROR(interrupt.Check("pbgi import"));
    PBGI_ASSIGN_OR_RETURN(size_t n, source->Next(absl::MakeSpan(buf)));
    if (n == 0) break;
    PBGI_RETURN_IF_ERROR(writer->Write(absl::MakeConstSpan(buf.data(), n)));
    done += static_cast<int64_t>(n);
    progress.Update(static_cast<uint64_t>(done));
  }
  PBGI_RETURN_IF_ERROR(writer->Close());
  progress.Finish(static_cast<uint64_t>(done));
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
    app->add_option("-n,--points", o->points, "Number of surfels (50k, 10M, 1e8, ...)")
        ->check(CountValidator(1));
    app->add_option("--density", o->density, "Surfels per unit area (instead of -n)");
    AddMeshFlags(app, &o->up, &o->orient);
    AddLightFlags(app, &o->lights, " (neither: a white sky)");
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
