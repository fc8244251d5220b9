// `pbgi generate SCENE -n POINTS -o OUT.ply [--seed S]`: streams a procedural scene's surfels,
// with direct light baked, to a PLY file (or, with `-o -`, standard output) in constant memory.
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "base/proc.h"
#include "base/stopwatch.h"
#include "pbgi/ply.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/command.h"
#include "tools/outputs.h"
#include "tools/progress.h"
#include "tools/scene_views.h"

namespace pbgi::tools {
namespace {

struct Options {
  std::string scene;
  std::string points = "1M";
  std::string out;
  uint64_t seed = 1;
  int size = 0;
  bool ascii = false;
  bool no_bake = false;
  bool keep_hidden = false;
};

// `pbgi KEY VALUE` header comments: where the points came from (pbgi/ply.h, Provenance()).
std::vector<std::string> ProvenanceComments(const std::map<std::string, std::string>& fields) {
  std::vector<std::string> c;
  for (const auto& [k, v] : fields) c.push_back(absl::StrFormat("pbgi %s %s", k, v));
  return c;
}

absl::Status Run(const Options& o) {
  const bool to_stdout = o.out == "-";
  if (!to_stdout && !absl::EndsWith(o.out, ".ply")) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "-o %s: the output is a PLY point file (-o NAME.ply, or -o - for standard output)",
        o.out));
  }
  if (!to_stdout) PBGI_RETURN_IF_ERROR(CheckOutsideStores(o.out));
  PBGI_ASSIGN_OR_RETURN(int64_t count, ParseCount(o.points, "-n"));
  if (count <= 0) return absl::InvalidArgumentError("-n must be at least 1");
  SceneOptions so;
  so.seed = o.seed;
  so.size = o.size;
  PBGI_ASSIGN_OR_RETURN(Scene scene, MakeScene(o.scene, so));
  auto shared = std::make_shared<const Scene>(std::move(scene));
  SamplerOptions sampler;
  sampler.count = count;
  sampler.seed = o.seed;
  sampler.bake = !o.no_bake;
  sampler.drop_hidden = !o.keep_hidden;
  const internal::Stopwatch start;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<SurfelSource> source,
                        MakeSceneSurfelSource(shared, sampler));
  PlyWriterOptions wo;
  wo.ascii = o.ascii;
  wo.radiance = source->HasRadiance();
  // Thin materials become two-sided surfels (scene/sampler.cc): the flag goes into the file.
  for (const Material& m : shared->materials) wo.two_sided = wo.two_sided || m.thin;
  auto fields = SceneFingerprint(*shared, o.seed, o.size, UpAxis::kZ);
  fields["source"] = "pbgi generate";
  fields["tool"] = kToolVersion;
  fields["date"] = NowIso8601();
  wo.comments = ProvenanceComments(fields);
  // The sampler's bounds hold every surfel: `pbgi build` then needs no bounds pass, and can
  // read the file from a pipe (docs/format.md, "Streamed input").
  wo.bounds = source->KnownBounds();
  const InterruptGuard interrupt;
  if (to_stdout) {
    wo.vertex_count = source->KnownCount();
    if (wo.vertex_count < 0) {
      // Hidden samples are dropped, so the count is known only after sampling: count them first
      // without baking (which decides nothing about which samples are kept; the writer checks
      // that the second pass makes as many).
      SamplerOptions count_only = sampler;
      count_only.bake = false;
      PBGI_ASSIGN_OR_RETURN(std::unique_ptr<SurfelSource> counter,
                            MakeSceneSurfelSource(shared, count_only));
      std::vector<Surfel> buf(1 << 16);
      int64_t n = 0;
      for (;;) {
        PBGI_RETURN_IF_ERROR(interrupt.Check("pbgi generate"));
        PBGI_ASSIGN_OR_RETURN(size_t k, counter->Next(absl::MakeSpan(buf)));
        if (k == 0) break;
        n += static_cast<int64_t>(k);
      }
      wo.vertex_count = n;
    }
  }
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyWriter> writer, PlyWriter::Create(o.out, wo));

  absl::FPrintF(stderr, "pbgi generate: %s, %d triangles (%d instances), area %.6g, %s\n",
                shared->name.c_str(), shared->TriangleCount(), shared->instances.size(),
                shared->SurfaceArea(),
                source->HasRadiance() ? "direct light baked" : "occlusion only");
  Progress progress("generate", "points", count);
  std::vector<Surfel> buf(1 << 16);
  int64_t done = 0;
  for (;;) {
    PBGI_RETURN_IF_ERROR(interrupt.Check("pbgi generate"));
    PBGI_ASSIGN_OR_RETURN(size_t n, source->Next(absl::MakeSpan(buf)));
    if (n == 0) break;
    PBGI_RETURN_IF_ERROR(writer->Write(absl::MakeConstSpan(buf.data(), n)));
    done += static_cast<int64_t>(n);
    progress.Update(static_cast<uint64_t>(done));
  }
  // Exact without hidden-sample dropping; within about 1% with it (the pilot's estimate).
  const bool exact = source->KnownCount() >= 0;
  if (exact ? done != count
            : std::abs(static_cast<double>(done - count)) > 0.02 * static_cast<double>(count) + 2) {
    return absl::InternalError(
        absl::StrFormat("the sampler made %d points, %d were asked for", done, count));
  }
  PBGI_RETURN_IF_ERROR(writer->Close());
  progress.Finish(static_cast<uint64_t>(done));
  const double secs = start.Seconds();
  absl::FPrintF(
      to_stdout ? stderr : stdout, "%s: %d points%s, %.2f s, %.0f points/s, peak memory %s\n", o.out.c_str(), done,
      exact ? "" : absl::StrFormat(" (%d asked; samples inside solid geometry dropped)", count),
      secs, static_cast<double>(done) / secs, FormatBytes(internal::PeakRssBytes()).c_str());
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto o = std::make_shared<Options>();
    app->add_option("scene", o->scene,
                    "Procedural scene: " + absl::StrJoin(ProceduralSceneNames(), ", "))
        ->required();
    app->add_option("-n,--points", o->points, "Number of surfels (50k, 10M, 1e8, ...)")
        ->check(CountValidator(1))
        ->capture_default_str();
    app->add_option("-o,--output", o->out, "Output PLY file, or - for standard output")
        ->required();
    app->add_option("--seed", o->seed, "Seed of the scene layout and the sampling")
        ->capture_default_str();
    app->add_option("--size", o->size,
                    "Scene scale (city blocks or forest trees per side; 0: default)");
    app->add_flag("--ascii", o->ascii, "Write ASCII PLY instead of binary");
    app->add_flag("--no-bake", o->no_bake, "Geometry only: do not bake direct light");
    app->add_flag("--keep-hidden", o->keep_hidden,
                  "Keep samples inside solid geometry (the floor under a block, the ground under "
                  "a building); the count is then exact");
    return [o]() { return Run(*o); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(generate, "generate",
                      "Stream a procedural scene's surfels (direct light baked) to a PLY file",
                      Setup());
}  // namespace pbgi::tools
