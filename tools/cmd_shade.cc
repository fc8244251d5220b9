// `pbgi shade`: occlusion, colour bleeding or glossy light from a database, for a point file of
// receivers (RenderMan's ptfilter workflow) or for the pixels of a camera view of a scene.
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "base/proc.h"
#include "pbgi/ply.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/budget.h"
#include "tools/command.h"
#include "tools/footprint_flags.h"
#include "tools/mesh_flags.h"
#include "tools/outputs.h"
#include "tools/progress.h"
#include "tools/report.h"
#include "tools/scene_views.h"
#include "tools/sharing_flags.h"

namespace pbgi::tools {
namespace {

struct ShadeArgs {
  SharingFlags sharing;
  std::string db;
  std::string receivers;
  std::string scene;
  std::string out;
  std::string mode = "irradiance";
  std::string cache = "auto";
  int threads = 0;
  float max_solid_angle = 0.03f;
  // or "plain", or "lobe"; glossy uses the lobe-aware cut (ShadeOptions::lobe_cut) unless plain
  std::string cut = "cosine";
  FootprintFlags footprint;
  float max_distance = std::numeric_limits<float>::infinity();
  int raster_res = 12;
  float bias = 0.0f;
  std::string hitsides = "front";
  float phong_exponent = 32.0f;
  uint64_t seed = 1;
  int size = 0;
  std::string up = "z";
  std::string orient = "auto";  // a mesh file: auto | none (pbgi import --orient)
  bool any_scene = false;
  std::string eye, look_at;
  float fov = 0.0f;
  int width = 640;
  int height = 360;
  std::string chunk = "1M";
  std::string invalid = "fail";
};

enum class Mode { kOcclusion, kIrradiance, kGlossy };

// `distinct`: Database::DistinctPagesRead(), the pages read at least once.
void PrintSummary(const char* what, uint64_t receivers, const ShadeStats& s, int threads,
                  uint64_t cache, uint64_t distinct) {
  std::printf("shaded %llu %s in %.2f s: %.0f receivers/s, %.1f us/receiver on %d threads\n",
              static_cast<unsigned long long>(receivers), what, s.seconds,
              double(receivers) / std::max(1e-9, s.seconds),
              s.seconds * 1e6 / double(std::max<uint64_t>(1, receivers)), threads);
  std::printf(
      "  gather %.1f us, raster %.1f us per receiver (CPU time); %.1f clusters + %.1f "
      "surfels, %.1f nodes visited per receiver\n",
      s.gather_seconds * 1e6 / double(std::max<uint64_t>(1, receivers)),
      s.raster_seconds * 1e6 / double(std::max<uint64_t>(1, receivers)),
      double(s.query.clusters) / double(std::max<uint64_t>(1, receivers)),
      double(s.query.surfels) / double(std::max<uint64_t>(1, receivers)),
      double(s.query.nodes_visited) / double(std::max<uint64_t>(1, receivers)));
  std::printf("  cache %s: %s; peak memory %s\n", FormatBytes(cache).c_str(),
              CacheSummary(s.cache, distinct, receivers).c_str(),
              FormatBytes(internal::PeakRssBytes()).c_str());
  std::printf("%s\n", SharingSummary(s).c_str());
}

// Why a receiver cannot be shaded, or nullptr (ShadeBatch refuses the same ones).
const char* InvalidReceiver(const ShadeReceiver& r) {
  const bool finite = std::isfinite(r.position.x) && std::isfinite(r.position.y) &&
                      std::isfinite(r.position.z) && std::isfinite(r.normal.x) &&
                      std::isfinite(r.normal.y) && std::isfinite(r.normal.z);
  if (!finite) return "a NaN or infinite coordinate";
  if (glm::dot(r.normal, r.normal) == 0.0f) return "a zero normal";
  return nullptr;
}

// The float results that follow each receiver's own properties, and the colour point viewers
// show (tone-mapped light: irradiance / pi, the radiance of a white diffuse surface; glossy
// radiance; or grey 1 - occlusion).
std::vector<std::string> ResultNames(Mode mode) {
  std::vector<std::string> n = {"occlusion"};
  if (mode != Mode::kOcclusion) {
    const char* prefix = mode == Mode::kGlossy ? "glossy" : "irradiance";
    for (const char* c : {"r", "g", "b"}) n.push_back(absl::StrFormat("%s_%s", prefix, c));
  }
  return n;
}

void AppendResult(Mode mode, const ShadeResult& r, std::vector<float>* extra,
                  std::vector<uint8_t>* rgb) {
  extra->push_back(r.occlusion);
  glm::vec3 shown(1.0f - std::clamp(r.occlusion, 0.0f, 1.0f));
  if (mode != Mode::kOcclusion) {
    const glm::vec3 c = mode == Mode::kGlossy ? r.glossy : r.irradiance;
    extra->insert(extra->end(), {c.x, c.y, c.z});
    shown = mode == Mode::kGlossy ? c : c * float(1.0 / 3.14159265358979);
  }
  for (int k = 0; k < 3; ++k) rgb->push_back(ToneMap8(shown[k]));
}

absl::Status ShadePoints(const ShadeArgs& a, Database& db, const ShadeOptions& base, Mode mode,
                         uint64_t cache, int64_t chunk_size) {
  // Receivers need a position and a normal; a radius is never used.
  PlyReadOptions ro;
  ro.allow_missing_radius = true;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlySource> in, OpenPlyFile(a.receivers, ro));
  const bool reflections = in->header().has_reflection;
  if (mode == Mode::kGlossy && !reflections) {
    std::fprintf(stderr,
                 "pbgi shade: note: %s has no rx ry rz properties: each glossy lobe is centred on "
                 "the receiver's normal\n",
                 a.receivers.c_str());
  }
  PlyWriterOptions wo;
  wo.radiance = false;
  wo.colors = PlyColors::kGiven;
  wo.extra = ResultNames(mode);
  wo.comments = {"pbgi shade.db " + a.db, "pbgi shade.mode " + a.mode,
                 "pbgi shade.receivers " + a.receivers, "pbgi tool " + std::string(kToolVersion)};
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyWriter> out, PlyWriter::Create(a.out, wo));
  // Receivers stream through in chunks (Z-ordered within each chunk), so a receiver file of any
  // size shades inside the cache budget plus one chunk.
  std::vector<Surfel> chunk(static_cast<size_t>(chunk_size));
  std::vector<glm::vec3> refl(chunk.size());
  std::vector<ShadeReceiver> receivers;
  std::vector<uint32_t> index_of;  // chunk slot of each valid receiver
  std::vector<ShadeResult> results;
  std::vector<Surfel> kept;
  std::vector<float> extra;
  std::vector<uint8_t> rgb;
  ShadeStats total, s;
  uint64_t done = 0, invalid = 0, chunks = 0;
  Progress progress("shade", "receivers", in->KnownCount());
  ShadeOptions so = base;
  so.progress = [&](const ShadeProgress& p) { progress.Update(done + p.done); };
  const InterruptGuard interrupt;
  for (;;) {
    if (const absl::Status st = interrupt.Check("pbgi shade"); !st.ok()) {
      progress.Abandon();
      return st;
    }
    PBGI_ASSIGN_OR_RETURN(size_t n,
                          in->NextWithReflections(absl::MakeSpan(chunk), absl::MakeSpan(refl)));
    if (n == 0) break;
    receivers.clear();
    index_of.clear();
    for (size_t i = 0; i < n; ++i) {
      const glm::vec3 r = reflections && glm::dot(refl[i], refl[i]) > 0 ? refl[i] : chunk[i].normal;
      const ShadeReceiver sr{chunk[i].position, chunk[i].normal, r, chunk[i].sheet};
      if (const char* why = InvalidReceiver(sr)) {
        if (a.invalid == "fail") {
          progress.Abandon();
          return absl::InvalidArgumentError(absl::StrFormat(
              "%s: receiver %d (counting from 0) has %s; nothing was written (--invalid skip "
              "leaves such receivers out, --invalid zero writes them with zero results)",
              a.receivers, done + i, why));
        }
        if (invalid < 5) {
          std::fprintf(stderr, "pbgi shade: receiver %llu has %s: %s\n",
                       static_cast<unsigned long long>(done + i), why,
                       a.invalid == "skip" ? "skipped" : "written with zero results");
        }
        ++invalid;
        if (a.invalid == "skip") continue;
      }
      index_of.push_back(static_cast<uint32_t>(i));
      receivers.push_back(sr);
    }
    // Shade the valid ones; invalid ones kept under --invalid zero get zero results.
    std::vector<ShadeReceiver> valid;
    std::vector<uint32_t> valid_slot;
    for (size_t j = 0; j < receivers.size(); ++j) {
      if (InvalidReceiver(receivers[j]) == nullptr) {
        valid.push_back(receivers[j]);
        valid_slot.push_back(static_cast<uint32_t>(j));
      }
    }
    std::vector<ShadeResult> shaded(valid.size());
    PBGI_RETURN_IF_ERROR(ShadeBatch(db, valid, so, absl::MakeSpan(shaded), &s));
    results.assign(receivers.size(), ShadeResult{});
    for (size_t j = 0; j < valid.size(); ++j) results[valid_slot[j]] = shaded[j];
    kept.clear();
    extra.clear();
    rgb.clear();
    for (size_t j = 0; j < receivers.size(); ++j) {
      kept.push_back(chunk[index_of[j]]);
      AppendResult(mode, results[j], &extra, &rgb);
    }
    PBGI_RETURN_IF_ERROR(out->Write(kept, extra, rgb));
    done += n;
    ++chunks;
    total.Add(s);
  }
  PBGI_RETURN_IF_ERROR(out->Close());
  progress.Finish(done, invalid > 0 ? absl::StrFormat("%d invalid (%s)", invalid,
                                                      a.invalid == "skip" ? "skipped" : "zero")
                                    : std::string());
  PrintSummary("receivers", done, total, ResolveThreads(so.threads), cache, db.DistinctPagesRead());
  if (invalid > 0) {
    std::printf("  %llu invalid receivers %s\n", static_cast<unsigned long long>(invalid),
                a.invalid == "skip" ? "skipped" : "written with zero results");
  }
  // The chunks show that the receivers in flight stay inside the --cache budget.
  std::printf("  wrote %s (%llu points, shaded in %llu chunks of at most %zu)\n", a.out.c_str(),
              static_cast<unsigned long long>(out->count()),
              static_cast<unsigned long long>(chunks), chunk.size());
  return absl::OkStatus();
}

// The EXR and PNG paths of a view's output.
absl::StatusOr<std::pair<std::string, std::string>> ViewOutputs(const std::string& out) {
  if (absl::EndsWith(out, ".exr"))
    return std::make_pair(out, out.substr(0, out.size() - 4) + ".png");
  if (absl::EndsWith(out, ".png"))
    return std::make_pair(out.substr(0, out.size() - 4) + ".exr", out);
  return absl::InvalidArgumentError(
      absl::StrFormat("-o %s: the output of a camera view is an .exr or a .png", out));
}

absl::Status ShadeCamera(const ShadeArgs& a, Database& db, const ShadeOptions& base, Mode mode,
                         uint64_t cache) {
  PBGI_ASSIGN_OR_RETURN(UpAxis up, ParseUpAxis(a.up));
  PBGI_ASSIGN_OR_RETURN(const bool orient, ParseOrient(a.orient));
  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<const Scene> scene,
                        LoadScene(a.scene, a.seed, a.size, up, orient));
  std::string warning;
  const absl::Status match = CheckSceneMatchesDatabase(
      *scene, SpecFingerprint(*scene, a.scene, a.seed, a.size, up, orient), db.meta(), a.db,
      &warning);
  if (!match.ok()) {
    if (!a.any_scene) return match;
    std::fprintf(stderr, "pbgi shade: warning (--any-scene): %s\n",
                 std::string(match.message()).c_str());
  }
  if (!warning.empty()) std::fprintf(stderr, "pbgi shade: warning: %s\n", warning.c_str());
  // A mesh file has no lights of its own: those that baked its surfels (pbgi import).
  scene = WithRecordedLights(scene, db.meta().stats);
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Tracer> tracer, Tracer::Create(*scene));
  Camera camera = DefaultCamera(*scene, a.width, a.height);
  if (!a.eye.empty()) {
    PBGI_ASSIGN_OR_RETURN(camera.eye, ParseVec3(a.eye));
  }
  if (!a.look_at.empty()) {
    PBGI_ASSIGN_OR_RETURN(camera.look_at, ParseVec3(a.look_at));
  }
  if (a.fov > 0.0f) camera.fov_y_degrees = a.fov;
  Progress progress("shade", "pixels", int64_t(a.width) * a.height);
  ShadeOptions so = base;
  so.progress = [&](const ShadeProgress& p) { progress.Update(p.done, int64_t(p.total)); };
  PBGI_ASSIGN_OR_RETURN(ViewImages view, RenderView(*tracer, db, camera, so));
  progress.Finish(view.receivers, absl::StrFormat("%dx%d view", a.width, a.height));
  // Glossy: the lobe around each pixel's reflection direction; occlusion: 1 - occlusion; else
  // direct plus diffuse indirect light.
  const Image* image = mode == Mode::kOcclusion ? &view.occlusion
                       : mode == Mode::kGlossy  ? &view.glossy
                                                : &view.composite;
  PBGI_ASSIGN_OR_RETURN(auto paths, ViewOutputs(a.out));
  const auto& [exr, png] = paths;
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(exr));
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(png));
  PBGI_RETURN_IF_ERROR(WriteExr(exr, *image));
  PBGI_RETURN_IF_ERROR(WritePng(png, *image, 1.0f, mode != Mode::kOcclusion));
  std::printf("traced %dx%d primary rays in %.2f s\n", a.width, a.height, view.trace_seconds);
  PrintSummary("pixels", view.receivers, view.shade, ResolveThreads(so.threads), cache,
               db.DistinctPagesRead());
  std::printf("  wrote %s and %s (%s)\n", exr.c_str(), png.c_str(),
              mode == Mode::kOcclusion ? "1 - occlusion"
              : mode == Mode::kGlossy  ? "glossy light around each pixel's reflection direction"
                                       : "direct + diffuse indirect light");
  return absl::OkStatus();
}

// Outputs that do not fit the job, and outputs that are inputs: refused before anything is
// opened.
absl::Status CheckOutputs(const ShadeArgs& a) {
  std::vector<std::string> outputs;
  if (!a.receivers.empty()) {
    if (!absl::EndsWith(a.out, ".ply")) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "-o %s: with --receivers the output is a PLY point file (-o NAME.ply)", a.out));
    }
    outputs = {a.out};
  } else {
    PBGI_ASSIGN_OR_RETURN(auto paths, ViewOutputs(a.out));
    outputs = {paths.first, paths.second};
  }
  return CheckOutputsAreNotInputs({a.db, a.receivers, a.scene}, outputs);
}

absl::Status RunShade(const ShadeArgs& a) {
  if (a.receivers.empty() == a.scene.empty()) {
    return absl::InvalidArgumentError("give either --receivers IN.ply or --scene SCENE");
  }
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out));
  PBGI_RETURN_IF_ERROR(CheckOutputs(a));
  Mode mode = Mode::kIrradiance;
  if (a.mode == "occlusion")
    mode = Mode::kOcclusion;
  else if (a.mode == "glossy")
    mode = Mode::kGlossy;
  else if (a.mode != "irradiance") {
    return absl::InvalidArgumentError(
        absl::StrFormat("--mode %s: use occlusion, irradiance or glossy", a.mode));
  }
  PBGI_ASSIGN_OR_RETURN(int64_t chunk, ParseCount(a.chunk, "--chunk"));
  // One budget, --cache, for the page cache and what the job holds besides: a chunk of
  // receivers (at most a quarter of the budget, at least kMinChunk of them) or the view's pixels
  // (the demo splits its --cache the same way, and counts what its process holds besides).
  constexpr uint64_t kMinChunk = 1024;
  const uint64_t job_min =
      a.scene.empty() ? std::min<uint64_t>(kMinChunk, uint64_t(chunk)) * kShadeBytesPerReceiver
                      : ViewJobBytes(a.width, a.height);
  PBGI_ASSIGN_OR_RETURN(
      const uint64_t budget,
      ResolveBudget("shade", "--cache", a.cache, uint64_t{256} << 20, kMinCacheBytes + job_min,
                    a.scene.empty() ? "a few pages and 1024 receivers"
                                    : "a few pages and the view's pixels"));
  uint64_t chunk_receivers = 0, job = job_min;
  std::string job_what = ViewJobWhat(a.width, a.height);
  if (a.scene.empty()) {
    chunk_receivers =
        std::clamp<uint64_t>(budget / 4 / kShadeBytesPerReceiver,
                             std::min<uint64_t>(kMinChunk, uint64_t(chunk)), uint64_t(chunk));
    job = chunk_receivers * kShadeBytesPerReceiver;
    job_what = absl::StrFormat("a chunk of %d receivers", chunk_receivers);
  }
  DatabaseOptions dbo;
  dbo.cache_bytes = budget > job ? budget - job : 0;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(a.db, dbo));
  // Every Reader (one per thread) pins two pages at least; below that the cache cannot hold.
  PBGI_ASSIGN_OR_RETURN(const ShadeBudget split,
                        SplitShadeBudget("--cache", a.cache, budget, 0, job, "", job_what,
                                         ResolveThreads(a.threads), db->meta().page_size));
  const uint64_t cache = split.cache;
  if (mode != Mode::kOcclusion && !HasRadiance(db->meta().channels)) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s stores occlusion only (built with --channels occlusion): --mode %s needs radiance",
        a.db, a.mode));
  }
  ShadeOptions so;
  so.threads = ResolveThreads(a.threads);
  so.cut.max_solid_angle = a.max_solid_angle;
  so.cut.max_distance = a.max_distance;
  // The cosine weight suits integrals against the cosine (occlusion, irradiance), not a lobe.
  so.cut.cosine_weighted = a.cut == "cosine" && mode != Mode::kGlossy;
  if (a.cut == "lobe" && mode != Mode::kGlossy) {
    return absl::InvalidArgumentError("--cut lobe is for --mode glossy (a glossy lobe)");
  }
  // Glossy refines the cut by its lobe (Cut::lobe) unless --cut plain asks for the cut that
  // knows nothing of it.
  so.lobe_cut = mode == Mode::kGlossy && a.cut != "plain";
  so.raster.resolution = a.raster_res;
  ApplyFootprintFlags(a.footprint, &so);
  so.raster.bias = a.bias;
  so.raster.max_distance = a.max_distance;
  so.raster.compute_radiance = mode != Mode::kOcclusion;
  so.raster.hitsides = a.hitsides == "back"   ? HitSides::kBack
                       : a.hitsides == "both" ? HitSides::kBoth
                                              : HitSides::kFront;
  if (mode == Mode::kGlossy) {
    so.raster.lobe = GlossyLobe::kPhong;
    so.raster.phong_exponent = a.phong_exponent;
  }
  ApplySharingFlags(a.sharing, &so);
  ApplyFarSharingFlags(a.sharing.far, db->meta().bounds, &so);
  return a.scene.empty() ? ShadePoints(a, *db, so, mode, cache, chunk_receivers)
                         : ShadeCamera(a, *db, so, mode, cache);
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<ShadeArgs>();
    app->add_option("db", a->db, "Database directory")->required();
    app->add_option("--receivers", a->receivers,
                    "Point file (PLY) of receivers: x y z nx ny nz, optionally rx ry rz (the "
                    "reflection direction of a glossy lobe); a radius is not needed");
    app->add_option("--scene", a->scene,
                    "Scene of a camera view: procedural name or mesh file (the one the database "
                    "was built from)");
    app->add_option("-o,--output", a->out, "Output: .ply for receivers, .exr/.png for a view")
        ->required();
    app->add_option("--mode", a->mode, "occlusion, irradiance or glossy")
        ->check(CLI::IsMember({"occlusion", "irradiance", "glossy"}))
        ->capture_default_str();
    app->add_option("--cache", a->cache,
                    "Memory budget: the page cache and the receivers in flight; auto: 256 MiB, or "
                    "half of what the machine or the memory cgroup leaves (a size needs a unit: "
                    "256M, 2G)")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option("--threads", a->threads, "Shading threads (0: all cores)")
        ->check(CLI::Range(0, 1024))
        ->capture_default_str();
    app->add_option("--cut", a->cut,
                    "cosine: the solid angle weighted by the cosine to the normal (fewer clusters "
                    "near the horizon; occlusion and irradiance only), plain, or lobe: weighted "
                    "by the glossy lobe (glossy only; glossy's cut unless plain)")
        ->check(CLI::IsMember({"cosine", "plain", "lobe"}))
        ->capture_default_str();
    AddFootprintFlags(app, &a->footprint);
    app->add_option("--max-solid-angle", a->max_solid_angle,
                    "Accept a node as a cluster below this solid angle (sr): smaller is finer")
        ->check(CLI::Range(0.0f, 10.0f))
        ->capture_default_str();
    app->add_option("--max-distance", a->max_distance, "Ignore what is farther than this")
        ->check(CLI::PositiveNumber);
    app->add_option("--raster-res", a->raster_res, "Micro-buffer pixels per cube face edge")
        ->check(CLI::Range(4, 64))
        ->capture_default_str();
    app->add_option("--bias", a->bias, "Offset of each receiver along its normal (world units)")
        ->capture_default_str();
    app->add_option("--hitsides", a->hitsides,
                    "Which sides of a surfel occlude and emit: front, back or both")
        ->check(CLI::IsMember({"front", "back", "both"}))
        ->capture_default_str();
    app->add_option("--phong-exponent", a->phong_exponent,
                    "Glossy lobe: cos^n around the reflection")
        ->capture_default_str();
    app->add_option("--seed", a->seed, "Seed of a procedural scene")->capture_default_str();
    app->add_option("--size", a->size, "Scale of a procedural scene (0: its default)")
        ->capture_default_str();
    AddMeshFlags(app, &a->up, &a->orient);
    app->add_flag("--any-scene", a->any_scene,
                  "Shade a view even when the database was built from another scene");
    app->add_option("--eye", a->eye, "Camera position X,Y,Z");
    app->add_option("--look-at", a->look_at, "Camera target X,Y,Z");
    app->add_option("--fov", a->fov, "Vertical field of view, degrees");
    app->add_option("--width", a->width, "Image width, pixels")
        ->check(CLI::Range(1, 16384))
        ->capture_default_str();
    app->add_option("--height", a->height, "Image height, pixels")
        ->check(CLI::Range(1, 16384))
        ->capture_default_str();
    app->add_option("--chunk", a->chunk, "Receivers shaded per batch (e.g. 1M, 50k)")
        ->check(CountValidator(1, int64_t{1} << 28))
        ->capture_default_str();
    app->add_option("--invalid", a->invalid,
                    "A receiver with a zero normal or a NaN: fail (the default), skip it, or "
                    "write it with zero results")
        ->check(CLI::IsMember({"fail", "skip", "zero"}))
        ->capture_default_str();
    AddSharingFlags(app, &a->sharing);
    return [a]() { return RunShade(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(shade, "shade",
                      "Shade receivers (PLY) or a camera view of a scene from a database", Setup());
}  // namespace pbgi::tools
