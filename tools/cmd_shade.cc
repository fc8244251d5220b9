// `pbgi shade`: occlusion, colour bleeding or glossy light from a database, for a point file of
// receivers (RenderMan's ptfilter workflow) or for the pixels of a camera view of a scene.
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "pbgi/ply.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/budget.h"
#include "tools/command.h"
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
  std::string cut = "cosine";  // or "plain"; glossy always uses the plain cut
  float max_distance = std::numeric_limits<float>::infinity();
  int raster_res = 12;
  float bias = 0.0f;
  std::string hitsides = "front";
  float phong_exponent = 32.0f;
  uint64_t seed = 1;
  std::string eye, look_at;
  float fov = 0.0f;
  int width = 640;
  int height = 360;
  int64_t chunk = 1 << 20;
};

enum class Mode { kOcclusion, kIrradiance, kGlossy };

// Output point file: the receivers' own properties, then what was computed.
class ResultPlyWriter {
 public:
  static absl::StatusOr<std::unique_ptr<ResultPlyWriter>> Create(const std::string& path,
                                                                 Mode mode) {
    auto w = std::unique_ptr<ResultPlyWriter>(new ResultPlyWriter());
    w->path_ = path;
    // Written beside the output and renamed over it by Close(): an output is never replaced
    // by a half-written one (a job that fails or is killed leaves the previous file).
    w->tmp_path_ = absl::StrFormat("%s.tmp-%d", path, getpid());
    w->mode_ = mode;
    w->file_ = std::fopen(w->tmp_path_.c_str(), "wb");
    if (w->file_ == nullptr) {
      return absl::UnavailableError(
          absl::StrFormat("cannot create %s: %s", w->tmp_path_, std::strerror(errno)));
    }
    std::string header =
        "ply\nformat binary_little_endian 1.0\ncomment written by pbgi shade\n"
        "element vertex 0000000000000000000\n";
    for (const char* p : {"x", "y", "z", "nx", "ny", "nz", "radius", "occlusion"}) {
      header += absl::StrFormat("property float %s\n", p);
    }
    if (mode != Mode::kOcclusion) {
      const char* prefix = mode == Mode::kGlossy ? "glossy" : "irradiance";
      for (const char* c : {"r", "g", "b"}) {
        header += absl::StrFormat("property float %s_%s\n", prefix, c);
      }
    }
    header += "end_header\n";
    w->count_offset_ = static_cast<long>(header.find("0000000000000000000"));
    if (std::fwrite(header.data(), 1, header.size(), w->file_) != header.size()) {
      return w->WriteError();
    }
    return w;
  }
  ~ResultPlyWriter() {
    if (file_ != nullptr) std::fclose(file_);
    if (!closed_) std::remove(tmp_path_.c_str());
  }
  absl::Status Write(const Surfel& s, const ShadeResult& r) {
    float v[11] = {s.position.x, s.position.y, s.position.z, s.normal.x,
                   s.normal.y,   s.normal.z,   s.radius,     r.occlusion};
    int n = 8;
    if (mode_ != Mode::kOcclusion) {
      const glm::vec3 c = mode_ == Mode::kGlossy ? r.glossy : r.irradiance;
      v[8] = c.x, v[9] = c.y, v[10] = c.z;
      n = 11;
    }
    if (std::fwrite(v, sizeof(float), n, file_) != size_t(n)) return WriteError();
    ++count_;
    return absl::OkStatus();
  }
  absl::Status Close() {
    const std::string count = absl::StrFormat("%019d", count_);
    if (std::fseek(file_, count_offset_, SEEK_SET) != 0 ||
        std::fwrite(count.data(), 1, count.size(), file_) != count.size()) {
      return WriteError();
    }
    bool ok = std::fflush(file_) == 0 && fsync(fileno(file_)) == 0;
    ok = std::fclose(file_) == 0 && ok;
    file_ = nullptr;
    if (!ok) return WriteError();
    if (std::rename(tmp_path_.c_str(), path_.c_str()) != 0) {
      return absl::UnavailableError(absl::StrFormat("cannot rename %s to %s: %s", tmp_path_, path_,
                                                    std::strerror(errno)));
    }
    closed_ = true;
    return absl::OkStatus();
  }

 private:
  absl::Status WriteError() {
    return absl::UnavailableError(
        absl::StrFormat("cannot write %s: %s (disk full?)", tmp_path_, std::strerror(errno)));
  }
  std::string path_;
  std::string tmp_path_;
  bool closed_ = false;
  Mode mode_ = Mode::kIrradiance;
  std::FILE* file_ = nullptr;
  long count_offset_ = 0;
  uint64_t count_ = 0;
};

void PrintSummary(const char* what, uint64_t receivers, const ShadeStats& s, int threads,
                  uint64_t cache) {
  const CacheStats& cs = s.cache;
  const uint64_t lookups = cs.reader.hits + cs.reader.misses;
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
  std::printf(
      "  cache %s: reader hits %.2f%%, shared hits %.2f%%, %llu pages read (%s); peak "
      "memory %s\n",
      FormatBytes(cache).c_str(),
      lookups ? 100.0 * double(cs.reader.hits) / double(lookups) : 100.0,
      100.0 * cs.shared.HitRate(), static_cast<unsigned long long>(cs.shared.pages_read),
      FormatBytes(cs.shared.bytes_read).c_str(), FormatBytes(internal::PeakRssBytes()).c_str());
  std::printf("%s\n", SharingSummary(s).c_str());
}

absl::Status ShadePoints(const ShadeArgs& a, Database& db, const ShadeOptions& so, Mode mode,
                         uint64_t cache, uint64_t chunk_receivers) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<SurfelSource> in, OpenPly(a.receivers));
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<ResultPlyWriter> out, ResultPlyWriter::Create(a.out, mode));
  // Receivers stream through in chunks (Z-ordered within each chunk), so a receiver file of any
  // size shades inside the budget: the cache plus one chunk (RunShade splits it).
  std::vector<Surfel> chunk(static_cast<size_t>(chunk_receivers));
  std::vector<ShadeReceiver> receivers;
  std::vector<ShadeResult> results;
  ShadeStats total, s;
  uint64_t done = 0;
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(size_t n, in->Next(absl::MakeSpan(chunk)));
    if (n == 0) break;
    receivers.resize(n);
    for (size_t i = 0; i < n; ++i) {
      receivers[i] = {chunk[i].position, chunk[i].normal, chunk[i].normal};
    }
    results.resize(n);
    PBGI_RETURN_IF_ERROR(ShadeBatch(db, receivers, so, absl::MakeSpan(results), &s));
    for (size_t i = 0; i < n; ++i) PBGI_RETURN_IF_ERROR(out->Write(chunk[i], results[i]));
    done += n;
    total.Add(s);
    std::fprintf(stderr, "shade: %llu receivers\n", static_cast<unsigned long long>(done));
  }
  PBGI_RETURN_IF_ERROR(out->Close());
  PrintSummary("receivers", done, total, so.threads > 0 ? so.threads : DefaultShadeThreads(),
               cache);
  std::printf("  wrote %s\n", a.out.c_str());
  return absl::OkStatus();
}

absl::Status ShadeCamera(const ShadeArgs& a, Database& db, const ShadeOptions& so, Mode mode,
                         uint64_t cache) {
  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<const Scene> scene, LoadScene(a.scene, a.seed, 0));
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Tracer> tracer, Tracer::Create(*scene));
  Camera camera = DefaultCamera(*scene, a.width, a.height);
  if (!a.eye.empty()) {
    PBGI_ASSIGN_OR_RETURN(camera.eye, ParseVec3(a.eye));
  }
  if (!a.look_at.empty()) {
    PBGI_ASSIGN_OR_RETURN(camera.look_at, ParseVec3(a.look_at));
  }
  if (a.fov > 0.0f) camera.fov_y_degrees = a.fov;
  PBGI_ASSIGN_OR_RETURN(ViewImages view, RenderView(*tracer, db, camera, so));
  const Image* image = &view.composite;
  if (mode == Mode::kOcclusion) image = &view.occlusion;
  std::string exr = a.out, png = a.out;
  if (absl::EndsWith(a.out, ".exr")) {
    png = a.out.substr(0, a.out.size() - 4) + ".png";
  } else if (absl::EndsWith(a.out, ".png")) {
    exr = a.out.substr(0, a.out.size() - 4) + ".exr";
  } else {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the output of a camera view is an .exr or a .png", a.out));
  }
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(exr));
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(png));
  PBGI_RETURN_IF_ERROR(WriteExr(exr, *image));
  PBGI_RETURN_IF_ERROR(WritePng(png, *image, 1.0f, mode != Mode::kOcclusion));
  std::printf("traced %dx%d primary rays in %.2f s\n", a.width, a.height, view.trace_seconds);
  PrintSummary("pixels", view.receivers, view.shade,
               so.threads > 0 ? so.threads : DefaultShadeThreads(), cache);
  std::printf("  wrote %s and %s\n", exr.c_str(), png.c_str());
  return absl::OkStatus();
}

absl::Status RunShade(const ShadeArgs& a) {
  if (a.receivers.empty() == a.scene.empty()) {
    return absl::InvalidArgumentError("give either --receivers IN.ply or --scene SCENE");
  }
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out));
  Mode mode = Mode::kIrradiance;
  if (a.mode == "occlusion")
    mode = Mode::kOcclusion;
  else if (a.mode == "glossy")
    mode = Mode::kGlossy;
  else if (a.mode != "irradiance") {
    return absl::InvalidArgumentError(
        absl::StrFormat("--mode %s: use occlusion, irradiance or glossy", a.mode));
  }
  // One budget, --cache, for the page cache and what the job holds besides: a chunk of
  // receivers (at most a quarter of the budget, at least kMinChunk of them) or the view's pixels.
  constexpr uint64_t kMinChunk = 1024;
  constexpr uint64_t kViewBytesPerPixel = 256;  // receivers, results, traced hits, images
  const uint64_t job_min =
      a.scene.empty() ? std::min<uint64_t>(kMinChunk, uint64_t(a.chunk)) * kShadeBytesPerReceiver
                      : uint64_t(a.width) * uint64_t(a.height) * kViewBytesPerPixel;
  PBGI_ASSIGN_OR_RETURN(const uint64_t budget,
                        ResolveBudget("shade", "--cache", a.cache, uint64_t{256} << 20,
                                      kMinCacheBytes + job_min,
                                      a.scene.empty() ? "a few pages and 1024 receivers"
                                                      : "a few pages and the view's pixels"));
  uint64_t chunk_receivers = 0, job = job_min;
  if (a.scene.empty()) {
    chunk_receivers = std::clamp<uint64_t>(budget / 4 / kShadeBytesPerReceiver,
                                           std::min<uint64_t>(kMinChunk, uint64_t(a.chunk)),
                                           uint64_t(a.chunk));
    job = chunk_receivers * kShadeBytesPerReceiver;
  }
  const uint64_t cache = budget - job;
  DatabaseOptions dbo;
  dbo.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(a.db, dbo));
  // Every Reader (one per thread) pins two pages at least; below that the cache cannot hold.
  const int threads = a.threads > 0 ? a.threads : DefaultShadeThreads();
  const uint64_t min_cache =
      4 * uint64_t(threads) * std::max<uint64_t>(db->meta().page_size, 4096);
  if (cache < min_cache) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "--cache %s leaves %s for pages after the job's %s, less than the %s that %d threads "
        "need (4 pages of %d bytes each): give at least --cache %dK",
        a.cache, FormatBytes(cache), FormatBytes(job), FormatBytes(min_cache), threads,
        db->meta().page_size, (min_cache + job + 1023) / 1024));
  }
  if (mode != Mode::kOcclusion && !HasRadiance(db->meta().channels)) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s stores occlusion only (built with --channels occlusion): --mode %s needs radiance",
        a.db, a.mode));
  }
  ShadeOptions so;
  so.threads = a.threads;
  so.cut.max_solid_angle = a.max_solid_angle;
  so.cut.max_distance = a.max_distance;
  // The cosine weight suits integrals against the cosine (occlusion, irradiance), not a lobe.
  so.cut.cosine_weighted = a.cut == "cosine" && mode != Mode::kGlossy;
  so.raster.resolution = a.raster_res;
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
  return a.scene.empty() ? ShadePoints(a, *db, so, mode, cache, chunk_receivers)
                         : ShadeCamera(a, *db, so, mode, cache);
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<ShadeArgs>();
    app->add_option("db", a->db, "Database directory")->required();
    app->add_option("--receivers", a->receivers, "Point file (PLY) of receivers");
    app->add_option("--scene", a->scene, "Scene of a camera view: procedural name or mesh file");
    app->add_option("-o,--out", a->out, "Output: .ply for receivers, .exr/.png for a view")
        ->required();
    app->add_option("--mode", a->mode, "occlusion, irradiance or glossy")
        ->check(CLI::IsMember({"occlusion", "irradiance", "glossy"}))
        ->capture_default_str();
    app->add_option("--cache", a->cache,
                    "Memory budget: the page cache and the receivers in flight; auto: 256 MiB, or "
                    "half of what the machine or the memory cgroup leaves")
        ->check(BytesValidator())
        ->capture_default_str();
    app->add_option("--threads", a->threads, "0: all cores")->capture_default_str();
    app->add_option("--cut", a->cut,
                    "cosine: the solid angle weighted by the cosine to the normal (fewer clusters "
                    "near the horizon; occlusion and irradiance only), or plain")
        ->check(CLI::IsMember({"cosine", "plain"}))
        ->capture_default_str();
    app->add_option("--max-solid-angle", a->max_solid_angle)
        ->check(CLI::Range(0.0f, 10.0f))
        ->capture_default_str();
    app->add_option("--max-distance", a->max_distance)->check(CLI::PositiveNumber);
    app->add_option("--raster-res", a->raster_res)->check(CLI::Range(4, 64))->capture_default_str();
    app->add_option("--bias", a->bias)->capture_default_str();
    app->add_option("--hitsides", a->hitsides)
        ->check(CLI::IsMember({"front", "back", "both"}))
        ->capture_default_str();
    app->add_option("--phong-exponent", a->phong_exponent, "Glossy lobe")->capture_default_str();
    app->add_option("--seed", a->seed, "Seed of a procedural scene")->capture_default_str();
    app->add_option("--eye", a->eye, "Camera position X,Y,Z");
    app->add_option("--look-at", a->look_at, "Camera target X,Y,Z");
    app->add_option("--fov", a->fov, "Vertical field of view, degrees");
    app->add_option("--width", a->width)->check(CLI::Range(1, 16384))->capture_default_str();
    app->add_option("--height", a->height)->check(CLI::Range(1, 16384))->capture_default_str();
    app->add_option("--chunk", a->chunk, "Receivers shaded per batch")
        ->check(CLI::Range(int64_t{1}, int64_t{1} << 28))
        ->capture_default_str();
    AddSharingFlags(app, &a->sharing);
    return [a]() { return RunShade(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(shade, "shade",
                      "Shade receivers (PLY) or a camera view of a scene from a database", Setup());
}  // namespace pbgi::tools
