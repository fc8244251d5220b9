// `pbgi build IN.ply -o DB`: the out-of-core octree builder from a terminal (pbgi/build.h).
// IN may be `-` (standard input: docs/format.md, "Streamed input"); `--resume` continues an
// interrupted build from the sorted runs it kept (docs/format.md, "Resume").
#include <sys/stat.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
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
  int threads = 0;  // all cores: the pipelined build pays on 2 cores (docs/format.md)
  bool force = false;
  float radius = 0.0f;
  int neighbours = 16;
  std::string viewpoint;
  std::string bounds;
  bool resume = false;
  bool stop_after_sort = false;  // test hook (hidden)
};

// What identifies the input for --resume: a file by its path, size, modification time and
// header; a stream by its header alone (without the `pbgi date` comment that pbgi generate
// stamps on each run, so that the same command piped again matches).
std::string InputIdentity(const std::string& input, const PlyHeader& h) {
  std::string text = absl::StrFormat("%s %d", h.format, h.vertex_count);
  for (const auto& p : h.vertex_properties) absl::StrAppend(&text, " ", p.type, ":", p.name);
  for (const auto& [n, c] : h.other_elements) absl::StrAppend(&text, " ", n, "=", c);
  for (const std::string& c : h.comments) {
    if (input == "-" && c.rfind("pbgi date ", 0) == 0) continue;
    absl::StrAppend(&text, "\n", c);
  }
  uint64_t hash = 1469598103934665603ull;  // FNV-1a
  for (unsigned char ch : text) hash = (hash ^ ch) * 1099511628211ull;
  if (input == "-") {
    return absl::StrFormat("stdin, %d vertices, header %016x", h.vertex_count, hash);
  }
  struct stat st = {};
  (void)stat(input.c_str(), &st);
  return absl::StrFormat("%s, %d bytes, mtime %d.%09d, header %016x",
                         std::filesystem::absolute(input).lexically_normal().string(), st.st_size,
                         st.st_mtim.tv_sec, st.st_mtim.tv_nsec, hash);
}

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
  const bool from_stdin = a.input == "-";
  const std::string in_name = from_stdin ? std::string("standard input") : a.input;
  PBGI_RETURN_IF_ERROR(
      CheckOutputsAreNotInputs({from_stdin ? std::string() : a.input}, {a.output, a.stats_json}));
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
  if (!a.bounds.empty()) {
    std::vector<std::string> f = absl::StrSplit(a.bounds, ',');
    float v[6];
    bool ok = f.size() == 6;
    for (size_t i = 0; ok && i < 6; ++i) ok = absl::SimpleAtof(f[i], &v[i]) && std::isfinite(v[i]);
    if (!ok) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "--bounds '%s': want six finite numbers XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX", a.bounds));
    }
    ro.bounds.lo = glm::vec3(v[0], v[1], v[2]);
    ro.bounds.hi = glm::vec3(v[3], v[4], v[5]);
    if (ro.bounds.Empty()) {
      return absl::InvalidArgumentError(
          "--bounds XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX: each minimum must be at most its maximum");
    }
  }
  // A stream without bounds is copied to the temporary directory first (unless resuming, which
  // reads only the header).
  if (from_stdin && !a.resume) ro.spill_dir = BuildTempDir(a.output, o);
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlySource> src, OpenPlyFile(a.input, ro));
  const PlyHeader& header = src->header();
  if (header.spilled_bytes > 0) {
    std::fprintf(stderr,
                 "pbgi build: standard input has no `comment pbgi bounds` line and no --bounds "
                 "was given: copied its %s to %s to read it twice\n",
                 FormatBytes(header.spilled_bytes).c_str(), ro.spill_dir.c_str());
  }
  if (header.FaceCount() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s is a mesh (%d faces), not a point cloud: sample its surfaces into surfels with "
        "`pbgi import %s -o SURFELS.ply -n COUNT` and build from that",
        in_name, header.FaceCount(), a.input));
  }
  for (const std::string& n : header.notes) {
    std::fprintf(stderr, "pbgi build: note: %s: %s\n", in_name.c_str(), n.c_str());
  }
  if (header.has_radius && a.radius > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s has its own 'radius' property: --radius is for files without one", in_name));
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
                   in_name.c_str(), a.radius);
    } else {
      o.estimate.radius = true;
      std::fprintf(stderr,
                   "pbgi build: %s has no 'radius' property: estimating each surfel's radius from "
                   "its %d nearest neighbours (or give --radius R for a uniform one)\n",
                   in_name.c_str(), a.neighbours);
    }
  }
  if (!header.has_normals) {
    o.estimate.normals = true;
    std::fprintf(stderr,
                 "pbgi build: %s has no normals (nx ny nz): estimating them from the %d nearest "
                 "neighbours (PCA), oriented %s\n",
                 in_name.c_str(), a.neighbours,
                 a.viewpoint.empty() ? "away from the centre of the bounds (--viewpoint X,Y,Z "
                                       "turns them towards a scanner's position instead)"
                                     : ("towards " + a.viewpoint).c_str());
  }
  o.provenance = [&] {
    auto p = header.Provenance();
    p.erase("tool");
    p.erase("date");
    p.erase("bounds");  // the builder records the key bounds itself
    for (const auto& [k, v] : o.provenance) p[k] = v;
    return p;
  }();
  o.provenance["input"] =
      from_stdin ? in_name : std::filesystem::absolute(a.input).lexically_normal().string();
  o.resumable.input_identity = InputIdentity(a.input, header);
  o.resumable.resume = a.resume;
  o.resumable.stop_after_sort = a.stop_after_sort;
  o.provenance["tool"] = kToolVersion;
  o.provenance["built_at"] = NowIso8601();
  if (o.channels == Channels::kRadiance && !src->HasRadiance()) {
    std::fprintf(stderr,
                 "pbgi build: note: %s has no colour properties; radiance will be zero (use "
                 "--channels occlusion for a smaller database)\n",
                 in_name.c_str());
  }
  auto prev_int = std::signal(SIGINT, OnInterrupt);
  auto prev_term = std::signal(SIGTERM, OnInterrupt);
  absl::StatusOr<BuildStats> st = BuildDatabase(*src, a.output, o);
  std::signal(SIGINT, prev_int);
  std::signal(SIGTERM, prev_term);
  if (!st.ok()) {
    progress->Abandon();
    std::string hint;
    const std::string run_dir = BuildRunDirectory(a.output, o);
    std::error_code ec;
    // Not when resuming failed over the kept runs themselves (the message says what to do).
    const bool resume_refused =
        a.resume && (absl::IsFailedPrecondition(st.status()) || absl::IsDataLoss(st.status()) ||
                     absl::IsNotFound(st.status()));
    if (!resume_refused && std::filesystem::exists(run_dir + "/manifest", ec)) {
      hint = absl::StrFormat(
          "; the sorted runs are kept in %s: run the same command with --resume to continue "
          "from them (or delete that directory)",
          run_dir);
    }
    // Name the input unless the message already does (PLY reader errors do).
    if (st.status().message().find(in_name) == absl::string_view::npos) {
      return absl::Status(st.status().code(),
                          absl::StrFormat("%s: %s%s", in_name, st.status().message(), hint));
    }
    return absl::Status(st.status().code(), absl::StrCat(st.status().message(), hint));
  }
  if (st->resumed) {
    std::fprintf(stderr, "pbgi build: resumed from %d sorted runs kept by the interrupted build\n",
                 static_cast<int>(st->runs_spilled));
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
                    "Input PLY point file (binary or ASCII): x y z [nx ny nz] [radius] [r g b]; "
                    "- reads standard input")
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
                    "Bytes per page (k*4096-16 is efficient; default 32752)")
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
                    "merge and the LMDB writes (faster on 2 idle cores, no faster when the other "
                    "core is busy); 0: all cores")
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
    app->add_option("--bounds", a->bounds,
                    "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX: a box that holds every point (instead of the "
                    "header's `comment pbgi bounds` or a bounds pass); points outside are an "
                    "error");
    app->add_flag("--resume", a->resume,
                  "Continue an interrupted build of the same -o from the sorted runs it kept in "
                  "--tmp (the input and the options that decide the keys must match)");
    app->add_flag("--stop-after-sort", a->stop_after_sort,
                  "Test hook: stop as if interrupted right after the sort pass")
        ->group("");
    return [a]() { return Run(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(build, "build", "Build a database from a PLY point file (out of core)",
                      Setup());
}  // namespace pbgi::tools
