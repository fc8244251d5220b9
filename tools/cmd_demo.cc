// `pbgi demo`: the whole pipeline in one command. Generates the city, bakes direct light into
// its surfels, builds the database out of core under a memory cap, shades a camera view with
// colour bleeding, and writes the occlusion, the indirect light and the composite as EXR and PNG.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "base/stopwatch.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/budget.h"
#include "tools/command.h"
#include "tools/footprint_flags.h"
#include "tools/progress.h"
#include "tools/report.h"
#include "tools/scene_views.h"
#include "tools/sharing_flags.h"

namespace pbgi::tools {
namespace {

struct DemoArgs {
  std::string out_dir = "out/demo";
  std::string scene = "city";
  std::string points = "4M";
  std::string memory = "auto";
  std::string cache = "auto";
  int width = 960;
  int height = 540;
  int threads = 0;
  float max_solid_angle = 0.03f;
  std::string cut = "cosine";  // or "plain"
  FootprintFlags footprint;
  int raster_res = 12;
  uint64_t seed = 1;
  SharingFlags sharing;
};

// What the demo made, for its summary.
struct DemoRun {
  std::shared_ptr<const Scene> scene;
  std::string db_path;
  BuildStats build;
  uint64_t scene_bytes = 0;   // the scene's resident set when the build started
  uint64_t build_memory = 0;  // the build's budget: --memory less scene_bytes
  double build_seconds = 0;   // sampling, baking and the build
  ViewImages view;
  double shade_seconds = 0;     // tracing the view and shading it
  uint64_t distinct_pages = 0;  // Database::DistinctPagesRead() once the view is shaded
  ShadeBudget budget;           // --cache split for shading
  uint64_t shaded_rss = 0;      // the RSS once the view is shaded, its cache full
};

struct DemoImage {
  const char* name;
  const Image* image;
};

std::vector<DemoImage> Images(const ViewImages& v) {
  return {{"occlusion", &v.occlusion},
          {"indirect", &v.indirect},
          {"direct", &v.direct},
          {"composite", &v.composite}};
}

// The build's share of the demo's --memory: what is left once the scene is loaded. The scene
// (its triangles, Embree's BVH for the sampler's hidden-sample test and baking, the sampler's
// buffers) lives in the same process through the build, and the build's plan counts only the
// process it starts from (docs/design.md, "Memory plan"). So the scene's resident set, measured
// as the growth of this process's RSS since `rss_before` (the process before the scene), comes
// off --memory; the plan's fixed part already counts the rest of the process.
absl::StatusOr<uint64_t> BuildShareOfMemory(uint64_t memory, uint64_t rss_before,
                                            uint64_t rss_scene, uint64_t* scene_bytes) {
  *scene_bytes = rss_scene > rss_before ? rss_scene - rss_before : 0;
  const uint64_t minimum = MinimumBuildMemory(BuildOptions{});
  if (*scene_bytes >= memory || memory - *scene_bytes < minimum) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "--memory %s leaves the build %s once the scene holds %s (its triangles, BVH and "
        "sampler), below the build's minimum of %s: give --memory at least %s",
        FormatBytes(memory), FormatBytes(*scene_bytes >= memory ? 0 : memory - *scene_bytes),
        FormatBytes(*scene_bytes), FormatBytes(minimum), FormatBytes(*scene_bytes + minimum)));
  }
  return memory - *scene_bytes;
}

// 1. The scene and its surfels, direct light baked in with Embree shadow rays; 2. the
// out-of-core build, surfels streamed straight from the sampler, under --memory less the scene.
absl::Status BuildDemoDatabase(const DemoArgs& a, uint64_t memory, DemoRun* run) {
  const internal::Stopwatch t;
  const uint64_t rss_before = internal::CurrentRssBytes();
  PBGI_ASSIGN_OR_RETURN(
      run->scene, LoadLitScene(a.scene, a.seed, 0, UpAxis::kZ, true, LightFlags{}, "pbgi demo"));
  const Scene& scene = *run->scene;
  PBGI_ASSIGN_OR_RETURN(int64_t points, ParseCount(a.points, "--points"));
  SamplerOptions sampler;
  sampler.count = points;
  sampler.seed = a.seed;
  sampler.bake = scene.has_radiance;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<SurfelSource> surfels,
                        MakeSceneSurfelSource(run->scene, sampler));
  std::fprintf(stderr, "demo: scene %s, %lld triangles, %s surfels requested\n", scene.name.c_str(),
               static_cast<long long>(scene.TriangleCount()),
               absl::StrFormat("%d", points).c_str());
  PBGI_ASSIGN_OR_RETURN(
      run->build_memory,
      BuildShareOfMemory(memory, rss_before, internal::CurrentRssBytes(), &run->scene_bytes));
  std::fprintf(stderr, "demo: the scene holds %s of --memory %s: the build gets %s\n",
               FormatBytes(run->scene_bytes).c_str(), FormatBytes(memory).c_str(),
               FormatBytes(run->build_memory).c_str());
  run->db_path = a.out_dir + "/" + scene.name + ".pbgi";
  BuildOptions build;
  build.memory_bytes = run->build_memory;
  build.channels = scene.has_radiance ? Channels::kRadiance : Channels::kOcclusion;
  build.tmp_dir = a.out_dir;
  build.provenance = SceneFingerprint(scene, a.seed, 0, UpAxis::kZ);
  build.provenance["source"] = "pbgi demo";
  build.provenance["tool"] = kToolVersion;
  build.provenance["built_at"] = NowIso8601();
  Progress progress("demo: build", "points", points);
  std::string pass;
  build.progress = [&](const BuildProgress& p) {
    if (pass != p.pass) {
      pass = p.pass;
      progress.Phase(absl::StrFormat("demo: build: %s", p.pass), p.points_total);
    }
    progress.Update(p.points_done, p.points_total);
  };
  PBGI_ASSIGN_OR_RETURN(run->build, BuildDatabase(*surfels, run->db_path, build));
  progress.Finish(run->build.points);
  run->build_seconds = t.Seconds();
  return absl::OkStatus();
}

// What the demo's process holds when shading starts, and what a view holds: the parts of
// --cache besides the page cache (SplitShadeBudget).
constexpr const char* kDemoResident = "the process (its code, the scene and its tracer)";
// What --cache auto allows for that process: the city's demo holds about 20 MiB then, at 200 k
// and at 128 M surfels alike (the build's buffers given back); a large mesh file more.
constexpr uint64_t kDemoProcessBytes = uint64_t{64} << 20;

// 3. A camera view shaded from the database, within --cache: the process as it stands once the
// build is over and the tracer made (its code, the scene, Embree's BVH), the view's pixels and
// the page cache share it (docs/design.md, "The shade step's budget").
absl::Status ShadeDemoView(const DemoArgs& a, uint64_t budget, DemoRun* run) {
  const internal::Stopwatch t;
  const Scene& scene = *run->scene;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Tracer> tracer, Tracer::Create(scene));
  // The build's buffers are freed, but some stay in malloc's arenas, in the RSS, until trimmed.
  internal::ReleaseFreeHeap();
  const uint64_t resident = internal::CurrentRssBytes();
  const uint64_t job = ViewJobBytes(a.width, a.height);
  DatabaseOptions dbo;
  // What is left for pages; SplitShadeBudget below refuses it once the page size is known.
  dbo.cache_bytes = std::max(budget > resident + job ? budget - resident - job : 0, kMinCacheBytes);
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(run->db_path, dbo));
  const int threads = ResolveThreads(a.threads);
  absl::StatusOr<ShadeBudget> split =
      SplitShadeBudget("--cache", a.cache, budget, resident, job, kDemoResident,
                       ViewJobWhat(a.width, a.height), threads, db->meta().page_size);
  if (!split.ok()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s (the database %s is built: `pbgi shade` can shade it)",
                        split.status().message(), run->db_path));
  }
  run->budget = *split;
  std::fprintf(
      stderr, "demo: shade: --cache %s\n",
      DescribeShadeBudget(run->budget, kDemoResident, ViewJobWhat(a.width, a.height)).c_str());
  ShadeOptions so;
  so.cut.max_solid_angle = a.max_solid_angle;
  so.cut.cosine_weighted = a.cut == "cosine";
  so.raster.resolution = a.raster_res;
  ApplyFootprintFlags(a.footprint, &so);
  so.raster.compute_radiance = scene.has_radiance;
  so.threads = threads;
  ApplySharingFlags(a.sharing, &so);
  ApplyFarSharingFlags(a.sharing.far, db->meta().bounds, &so);
  Progress progress("demo: shade", "receivers");  // the total: the pixels whose rays hit
  so.progress = [&](const ShadeProgress& p) { progress.Update(p.done, int64_t(p.total)); };
  const Camera camera = DefaultCamera(scene, a.width, a.height);
  // The database closes once the view is shaded: its page cache (up to --cache) is not held
  // beside the images while they are composed; the pages that the shading threads freed go
  // back to the system, or they would stay in those threads' arenas, in the RSS.
  PBGI_ASSIGN_OR_RETURN(run->view, RenderView(*tracer, *db, camera, so, [&db, run]() {
                          run->distinct_pages = db->DistinctPagesRead();
                          run->shaded_rss = internal::CurrentRssBytes();
                          db.reset();
                          internal::ReleaseFreeHeap();
                        }));
  progress.Finish(run->view.receivers);
  run->shade_seconds = t.Seconds();
  return absl::OkStatus();
}

// 4. Images, EXR and PNG.
absl::Status WriteDemoImages(const std::string& base, const ViewImages& view) {
  for (const DemoImage& o : Images(view)) {
    PBGI_RETURN_IF_ERROR(WriteExr(absl::StrFormat("%s_%s.exr", base, o.name), *o.image));
    PBGI_RETURN_IF_ERROR(WritePng(absl::StrFormat("%s_%s.png", base, o.name), *o.image, 1.0f,
                                  std::string(o.name) != "occlusion"));
  }
  return absl::OkStatus();
}

void PrintDemoSummary(const DemoArgs& a, const DemoRun& run, uint64_t memory,
                      const std::string& base, double total_seconds) {
  const BuildStats& bs = run.build;
  const ViewImages& view = run.view;
  const double receivers = double(std::max<uint64_t>(1, view.receivers));
  std::printf("Coherent PBGI demo: %s\n", run.scene->name.c_str());
  std::printf("  surfels        %llu (%s on disk, %.1f bytes/point)\n",
              static_cast<unsigned long long>(bs.points), FormatBytes(bs.bytes_on_disk).c_str(),
              bs.points ? double(bs.bytes_on_disk) / double(bs.points) : 0.0);
  std::printf(
      "  build          %.1f s (%.2f M points/s incl. sampling and baking), %llu nodes, "
      "%llu runs spilled, build memory cap %s (--memory %s less the scene's %s), peak memory "
      "%s by the end of the build\n",
      run.build_seconds, double(bs.points) / run.build_seconds / 1e6,
      static_cast<unsigned long long>(bs.nodes), static_cast<unsigned long long>(bs.runs_spilled),
      FormatBytes(run.build_memory).c_str(), FormatBytes(memory).c_str(),
      FormatBytes(run.scene_bytes).c_str(), FormatBytes(bs.peak_rss_bytes).c_str());
  std::printf(
      "  shade          %.1f s: %llu receivers (%dx%d), %.1f us/receiver on %d threads, "
      "trace %.2f s, ShadeBatch %.1f s, compose %.2f s\n",
      run.shade_seconds, static_cast<unsigned long long>(view.receivers), a.width, a.height,
      view.shade.seconds * 1e6 / receivers, ResolveThreads(a.threads), view.trace_seconds,
      view.shade.seconds, view.compose_seconds);
  std::printf("%s\n", SharingSummary(view.shade).c_str());
  std::printf(
      "  budget         --cache %s; RSS %s once shaded\n",
      DescribeShadeBudget(run.budget, kDemoResident, ViewJobWhat(a.width, a.height)).c_str(),
      FormatBytes(run.shaded_rss).c_str());
  std::printf("  cache          %s cap, %s\n", FormatBytes(run.budget.cache).c_str(),
              CacheSummary(view.shade.cache, run.distinct_pages, view.receivers).c_str());
  std::printf(
      "  cut            max_solid_angle %.3g (%s), raster %d^2 x 6, %.1f clusters + %.1f "
      "surfels per receiver\n",
      a.max_solid_angle, a.cut.c_str(), a.raster_res, double(view.shade.query.clusters) / receivers,
      double(view.shade.query.surfels) / receivers);
  std::printf("  total          %.1f s, peak memory %s\n", total_seconds,
              FormatBytes(internal::PeakRssBytes()).c_str());
  std::printf("  database       %s\n", run.db_path.c_str());
  for (const DemoImage& o : Images(view)) {
    std::printf("  image          %s_%s.png (.exr)\n", base.c_str(), o.name);
  }
}

absl::Status RunDemo(const DemoArgs& a) {
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out_dir));
  PBGI_ASSIGN_OR_RETURN(uint64_t memory,
                        ResolveBudget("demo", "--memory", a.memory, uint64_t{512} << 20,
                                      MinimumBuildMemory(BuildOptions{}),
                                      "fixed buffers, one write batch and the smallest sort run"));
  // --cache bounds the shade step: the process, the view's pixels and the page cache. What the
  // view needs is refused here, before the build; the rest once the process is measured.
  const uint64_t view_bytes = ViewJobBytes(a.width, a.height);
  const std::string why = absl::StrFormat("a few pages and %s", ViewJobWhat(a.width, a.height));
  // auto: 256 MiB of pages beside the view and kDemoProcessBytes for the process.
  PBGI_ASSIGN_OR_RETURN(uint64_t cache,
                        ResolveBudget("demo", "--cache", a.cache,
                                      (uint64_t{256} << 20) + view_bytes + kDemoProcessBytes,
                                      kMinCacheBytes + view_bytes, why.c_str()));
  std::error_code ec;
  std::filesystem::create_directories(a.out_dir, ec);
  if (ec) {
    return absl::UnavailableError(absl::StrFormat("cannot create %s: %s", a.out_dir, ec.message()));
  }
  const internal::Stopwatch total;
  DemoRun run;
  PBGI_RETURN_IF_ERROR(BuildDemoDatabase(a, memory, &run));
  PBGI_RETURN_IF_ERROR(ShadeDemoView(a, cache, &run));
  const std::string base = a.out_dir + "/" + run.scene->name;
  PBGI_RETURN_IF_ERROR(WriteDemoImages(base, run.view));
  PrintDemoSummary(a, run, memory, base, total.Seconds());
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<DemoArgs>();
    app->add_option("-o,--output", a->out_dir, "Output directory (database and images)")
        ->capture_default_str();
    app->add_option("--scene", a->scene, "Procedural scene or mesh file")->capture_default_str();
    app->add_option("--points", a->points, "Surfels to generate (e.g. 500k, 4M)")
        ->check(CountValidator(1, int64_t{1} << 40))
        ->capture_default_str();
    app->add_option("--memory", a->memory,
                    "Memory cap of the scene and the build, with a unit (512M, 1G), or auto (512 "
                    "MiB, less in a small machine): the build gets what the loaded scene leaves")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option(
           "--cache", a->cache,
           "Memory cap of shading, with a unit (1G), or auto (256 MiB of pages beside the view "
           "and the process, less in a small machine): the page cache gets what the process "
           "and the view's pixels (256 bytes each) leave")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option("--width", a->width, "Image width, pixels")
        ->check(CLI::Range(16, 8192))
        ->capture_default_str();
    app->add_option("--height", a->height, "Image height, pixels")
        ->check(CLI::Range(16, 8192))
        ->capture_default_str();
    app->add_option("--threads", a->threads, "Shading threads (0: all cores)")
        ->check(CLI::Range(0, 1024))
        ->capture_default_str();
    app->add_option("--max-solid-angle", a->max_solid_angle,
                    "Accept a node as a cluster below this solid angle (sr)")
        ->check(CLI::Range(0.0f, 10.0f))
        ->capture_default_str();
    app->add_option("--cut", a->cut, "cosine (solid angle weighted by the cosine) or plain")
        ->check(CLI::IsMember({"cosine", "plain"}))
        ->capture_default_str();
    AddFootprintFlags(app, &a->footprint);
    app->add_option("--raster-res", a->raster_res, "Micro-buffer pixels per cube face edge")
        ->check(CLI::Range(4, 64))
        ->capture_default_str();
    app->add_option("--seed", a->seed, "Seed of the scene and its sampling")->capture_default_str();
    AddSharingFlags(app, &a->sharing);
    return [a]() { return RunDemo(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(demo, "demo",
                      "Generate the city, build its database under a memory cap, shade a view",
                      Setup());
}  // namespace pbgi::tools
