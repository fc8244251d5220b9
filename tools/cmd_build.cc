// `pbgi build IN.ply -o DB`: the out-of-core octree builder from a terminal (pbgi/build.h).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "pbgi/build.h"
#include "pbgi/ply.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/budget.h"
#include "tools/command.h"
#include "tools/outputs.h"
#include "tools/progress.h"
#include "tools/report.h"
#include "tools/scene_views.h"

namespace pbgi::tools {
namespace {

std::atomic<bool> g_interrupted{false};

extern "C" void OnInterrupt(int) { g_interrupted.store(true); }

struct Args {
  std::string input;
  std::string output;
  std::string memory = "auto";
  uint32_t leaf_size = 16;
  std::string page_size;
  std::string channels = "radiance";
  std::string layout = "coherent";
  std::string tmp_dir;
  bool skip_invalid = false;
  std::string stats_json;
  int threads = 1;
  bool force = false;
  float radius = 0.0f;
  int neighbours = 16;
  std::string viewpoint;
};

// What a build may write to: a new path, an empty directory, or an existing database with
// --force (swapped in by rename: readers that have the old one open keep reading it). A
// directory that holds anything else is not ours to fill.
absl::Status CheckBuildOutput(const std::string& out, bool force) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::file_status st = fs::status(out, ec);
  if (!fs::exists(st)) return absl::OkStatus();
  if (!fs::is_directory(st)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("-o %s is a file, not a database directory: give a new path", out));
  }
  bool database = false;
  std::vector<std::string> others;
  for (const fs::directory_entry& e : fs::directory_iterator(out, ec)) {
    const std::string name = e.path().filename().string();
    if (name == "data.mdb") {
      database = true;
    } else if (name.rfind("data.mdb", 0) != 0 && name != "writer.lock" && name != "lock.mdb") {
      others.push_back(name);  // not a store's own file (its leftovers start with data.mdb)
    }
  }
  if (!others.empty()) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "-o %s is a directory that holds other files (%s%s), not a database: give a new or "
        "empty directory",
        out, others.front(),
        others.size() > 1 ? absl::StrFormat(" and %d more", others.size() - 1) : std::string()));
  }
  if (database && !force) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "-o %s is a database already: pass --force to replace it (readers that have it open "
        "keep the old one until they close it)",
        out));
  }
  return absl::OkStatus();
}

absl::Status Run(const Args& a) {
  PBGI_RETURN_IF_ERROR(CheckOutputsAreNotInputs({a.input}, {a.output, a.stats_json}));
  PBGI_RETURN_IF_ERROR(CheckBuildOutput(a.output, a.force));
  if (!a.stats_json.empty()) PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.stats_json));
  BuildOptions o;
  o.leaf_size = a.leaf_size;
  if (!a.page_size.empty()) {
    PBGI_ASSIGN_OR_RETURN(uint64_t ps, ParseBytes(a.page_size));
    if (ps > (uint64_t{1} << 30)) return absl::InvalidArgumentError("--page-size is too large");
    o.page_size = static_cast<uint32_t>(ps);
  }
  PBGI_ASSIGN_OR_RETURN(
      o.memory_bytes,
      ResolveBudget("build", "--memory", a.memory, uint64_t{1} << 30, MinimumBuildMemory(o),
                    "fixed buffers, one write batch and the smallest sort run"));
  if (a.channels == "radiance") {
    o.channels = Channels::kRadiance;
  } else if (a.channels == "occlusion") {
    o.channels = Channels::kOcclusion;
  } else {
    return absl::InvalidArgumentError(
        absl::StrFormat("--channels must be occlusion or radiance, not '%s'", a.channels));
  }
  PBGI_ASSIGN_OR_RETURN(o.layout, ParseLayout(a.layout));
  o.tmp_dir = a.tmp_dir;
  o.skip_invalid = a.skip_invalid;
  o.threads = ResolveThreads(a.threads);
  auto progress = std::make_shared<Progress>("build", "points", -1);
  auto pass = std::make_shared<std::string>();
  o.progress = [progress, pass](const BuildProgress& p) {
    if (*pass != p.pass) {
      *pass = p.pass;
      progress->Phase(absl::StrFormat("build: %s", p.pass), p.points_total);
    }
    progress->Update(p.points_done, p.points_total);
  };
  o.cancel = &g_interrupted;

  PlyReadOptions ro;
  ro.allow_missing_radius = true;
  ro.allow_missing_normals = true;
  ro.uniform_radius = a.radius;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlySource> src, OpenPlyFile(a.input, ro));
  const PlyHeader& header = src->header();
  if (header.FaceCount() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s is a mesh (%d faces), not a point cloud: sample its surfaces into surfels with "
        "`pbgi import %s -o SURFELS.ply -n COUNT` and build from that",
        a.input, header.FaceCount(), a.input));
  }
  for (const std::string& n : header.notes) {
    std::fprintf(stderr, "pbgi build: note: %s: %s\n", a.input.c_str(), n.c_str());
  }
  if (header.has_radius && a.radius > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s has its own 'radius' property: --radius is for files without one", a.input));
  }
  o.estimate.neighbours = a.neighbours;
  if (!a.viewpoint.empty()) {
    PBGI_ASSIGN_OR_RETURN(o.estimate.viewpoint, ParseVec3(a.viewpoint));
    o.estimate.towards_viewpoint = true;
  }
  if (!header.has_radius) {
    if (a.radius > 0) {
      o.provenance["radius"] = absl::StrFormat("uniform %g (--radius)", a.radius);
      std::fprintf(stderr,
                   "pbgi build: %s has no 'radius' property: every surfel gets --radius %g\n",
                   a.input.c_str(), a.radius);
    } else {
      o.estimate.radius = true;
      std::fprintf(stderr,
                   "pbgi build: %s has no 'radius' property: estimating each surfel's radius from "
                   "its %d nearest neighbours (or give --radius R for a uniform one)\n",
                   a.input.c_str(), a.neighbours);
    }
  }
  if (!header.has_normals) {
    o.estimate.normals = true;
    std::fprintf(stderr,
                 "pbgi build: %s has no normals (nx ny nz): estimating them from the %d nearest "
                 "neighbours (PCA), oriented %s\n",
                 a.input.c_str(), a.neighbours,
                 a.viewpoint.empty() ? "away from the centre of the bounds (--viewpoint X,Y,Z "
                                       "turns them towards a scanner's position instead)"
                                     : ("towards " + a.viewpoint).c_str());
  }
  o.provenance = [&] {
    auto p = header.Provenance();
    p.erase("tool");
    p.erase("date");
    for (const auto& [k, v] : o.provenance) p[k] = v;
    return p;
  }();
  o.provenance["input"] = std::filesystem::absolute(a.input).lexically_normal().string();
  o.provenance["tool"] = kToolVersion;
  o.provenance["built_at"] = NowIso8601();
  if (o.channels == Channels::kRadiance && !src->HasRadiance()) {
    std::fprintf(stderr,
                 "pbgi build: note: %s has no colour properties; radiance will be zero (use "
                 "--channels occlusion for a smaller database)\n",
                 a.input.c_str());
  }
  auto prev_int = std::signal(SIGINT, OnInterrupt);
  auto prev_term = std::signal(SIGTERM, OnInterrupt);
  absl::StatusOr<BuildStats> st = BuildDatabase(*src, a.output, o);
  std::signal(SIGINT, prev_int);
  std::signal(SIGTERM, prev_term);
  if (!st.ok()) {
    progress->Abandon();
    // Name the input file unless the message already does (PLY reader errors do).
    if (st.status().message().find(a.input) == absl::string_view::npos) {
      return absl::Status(st.status().code(),
                          absl::StrFormat("%s: %s", a.input, st.status().message()));
    }
    return st.status();
  }
  const BuildStats& s = *st;
  progress->Finish(s.points, absl::StrFormat("%s on disk", FormatBytes(s.bytes_on_disk)));
  // The library's own VmHWM reading is taken after Finish; ours includes the PLY reader too.
  BuildStats shown = s;
  shown.peak_rss_bytes = std::max(s.peak_rss_bytes, internal::PeakRssBytes());
  PrintBuildStats(shown, o, a.input, a.output, a.channels);
  if (!a.stats_json.empty()) {
    PBGI_RETURN_IF_ERROR(WriteFileAtomically(
        a.stats_json, DumpJson(BuildStatsJson(shown, o, a.input, a.output, a.channels))));
  }
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<Args>();
    app->add_option("IN", a->input,
                    "Input PLY point file (binary or ASCII): x y z [nx ny nz] [radius] [r g b]")
        ->required();
    app->add_option("-o,--output", a->output, "Database directory to create")->required();
    app->add_option("--memory", a->memory,
                    "Memory budget of the build, with a unit (512M, 1G), or auto: 1 GiB, or half "
                    "of what the machine or the memory cgroup leaves (sort, merge, write batch)")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option("--leaf-size", a->leaf_size, "Maximum points per leaf")
        ->check(CLI::Range(1, 65535))
        ->capture_default_str();
    app->add_option("--page-size", a->page_size,
                    "Bytes per page (k*4096-16 is efficient; default 65520)")
        ->check(BytesValidator());
    app->add_option("--channels", a->channels, "occlusion or radiance")
        ->check(CLI::IsMember({"occlusion", "radiance"}))
        ->capture_default_str();
    app->add_option("--layout", a->layout, "coherent, postorder, breadth-first or shuffled")
        ->check(CLI::IsMember({"coherent", "postorder", "breadth-first", "shuffled"}))
        ->capture_default_str();
    app->add_option("--tmp", a->tmp_dir,
                    "Directory for sort runs (default: the database's parent directory)");
    app->add_flag("--skip-invalid", a->skip_invalid,
                  "Drop invalid surfels (NaN/Inf, zero normal, radius <= 0) and count them");
    app->add_option("--stats-json", a->stats_json, "Write the build statistics as JSON");
    app->add_option("--threads", a->threads,
                    "Threads: 1 runs every pass on one thread; 2 or more pipeline the sort, the "
                    "merge and the LMDB writes (measured no faster on 2 cores); 0: all cores")
        ->check(CLI::Range(0, 64))
        ->capture_default_str();
    app->add_flag("--force", a->force,
                  "Replace an existing database at -o (readers that have it open keep the old "
                  "one)");
    app->add_option("--radius", a->radius,
                    "For a PLY without 'radius': give every surfel this radius instead of "
                    "estimating each one from its neighbours")
        ->check(CLI::PositiveNumber);
    app->add_option("--neighbours", a->neighbours,
                    "Neighbours (k) of the radius and normal estimates of a PLY that lacks them")
        ->check(CLI::Range(3, 64))
        ->capture_default_str();
    app->add_option("--viewpoint", a->viewpoint,
                    "For a PLY without normals: turn the estimated normals towards this point "
                    "X,Y,Z (a scanner's position) instead of away from the centre");
    return [a]() { return Run(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(build, "build", "Build a database from a PLY point file (out of core)",
                      Setup());
}  // namespace pbgi::tools
