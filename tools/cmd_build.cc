// `pbgi build IN.ply -o DB`: the out-of-core octree builder from a terminal (pbgi/build.h).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>

#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "pbgi/build.h"
#include "pbgi/ply.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/budget.h"
#include "tools/command.h"
#include "tools/report.h"

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
  int threads = 0;
};

// Throttled progress: redraws one line on a terminal, prints a line per second otherwise.
class Progress {
 public:
  explicit Progress(bool tty) : tty_(tty), start_(std::chrono::steady_clock::now()) {}
  void operator()(const BuildProgress& p) {
    const auto now = std::chrono::steady_clock::now();
    const double since = std::chrono::duration<double>(now - last_).count();
    if (since < (tty_ ? 0.1 : 1.0) && std::string(p.pass) == last_pass_) return;
    last_ = now;
    last_pass_ = p.pass;
    const double t = std::chrono::duration<double>(now - start_).count();
    std::string line =
        p.points_total > 0
            ? absl::StrFormat("[%7.1fs] %-13s %12d / %d points (%.0f%%)", t, p.pass, p.points_done,
                              p.points_total,
                              100.0 * double(p.points_done) / double(p.points_total))
            : absl::StrFormat("[%7.1fs] %-13s %12d points", t, p.pass, p.points_done);
    std::fprintf(stderr, tty_ ? "\r%s\033[K" : "%s\n", line.c_str());
    drew_ = true;
  }
  void Done() {
    if (tty_ && drew_) std::fprintf(stderr, "\n");
  }

 private:
  bool tty_;
  bool drew_ = false;
  std::chrono::steady_clock::time_point start_, last_{};
  std::string last_pass_;
};

absl::Status Run(const Args& a) {
  if (!a.stats_json.empty()) PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.stats_json));
  BuildOptions o;
  o.leaf_size = a.leaf_size;
  if (!a.page_size.empty()) {
    PBGI_ASSIGN_OR_RETURN(uint64_t ps, ParseBytes(a.page_size));
    if (ps > (uint64_t{1} << 30)) return absl::InvalidArgumentError("--page-size is too large");
    o.page_size = static_cast<uint32_t>(ps);
  }
  PBGI_ASSIGN_OR_RETURN(o.memory_bytes,
                        ResolveBudget("build", "--memory", a.memory, uint64_t{1} << 30,
                                      MinimumBuildMemory(o),
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
  o.threads = a.threads;
  auto progress = std::make_shared<Progress>(StderrIsTerminal());
  o.progress = [progress](const BuildProgress& p) { (*progress)(p); };
  o.cancel = &g_interrupted;

  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<SurfelSource> src, OpenPly(a.input));
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
  progress->Done();
  if (!st.ok()) {
    // Name the input file unless the message already does (PLY reader errors do).
    if (st.status().message().find(a.input) == absl::string_view::npos) {
      return absl::Status(st.status().code(),
                          absl::StrFormat("%s: %s", a.input, st.status().message()));
    }
    return st.status();
  }
  const BuildStats& s = *st;
  // The library's own VmHWM reading is taken after Finish; ours includes the PLY reader too.
  BuildStats shown = s;
  shown.peak_rss_bytes = std::max(s.peak_rss_bytes, internal::PeakRssBytes());
  PrintBuildStats(shown, o, a.input, a.output, a.channels);
  if (!a.stats_json.empty()) {
    std::ofstream f(a.stats_json);
    f << DumpJson(BuildStatsJson(shown, o, a.input, a.output, a.channels));
    if (!f) {
      return absl::InternalError(absl::StrFormat("cannot write %s", a.stats_json));
    }
  }
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<Args>();
    app->add_option("IN", a->input, "Input PLY point file (binary or ASCII)")->required();
    app->add_option("-o,--output", a->output, "Database directory to create")->required();
    app->add_option("--memory", a->memory,
                    "Memory budget (sort, merge, write batch); auto: 1 GiB, or half of what the "
                    "machine or the memory cgroup leaves")
        ->check(BytesValidator())
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
                    "merge and the LMDB writes (measured no faster on 2 cores); 0 means 1")
        ->check(CLI::Range(0, 64))
        ->capture_default_str();
    return [a]() { return Run(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(build, "build", "Build a database from a PLY point file (out of core)",
                      Setup());
}  // namespace pbgi::tools
