// pbgi: build, inspect, query and shade Coherent PBGI databases from a terminal.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "pbgi/store.h"
#include "tools/command.h"

namespace pbgi::tools {
namespace {

struct Entry {
  std::string name;
  std::string help;
  CommandSetup setup;
};

std::vector<Entry>& Registry() {
  static auto* registry = new std::vector<Entry>();
  return *registry;
}

}  // namespace

bool RegisterCommand(const char* name, const char* help, CommandSetup setup) {
  Registry().push_back({name, help, std::move(setup)});
  return true;
}

absl::StatusOr<uint64_t> ParseBytes(const std::string& text) {
  std::string s = text;
  while (!s.empty() && (s.back() == 'B' || s.back() == 'b' || s.back() == 'i')) s.pop_back();
  double mult = 1;
  if (!s.empty()) {
    switch (s.back()) {
      case 'k':
      case 'K':
        mult = 1024.0;
        break;
      case 'm':
      case 'M':
        mult = 1024.0 * 1024;
        break;
      case 'g':
      case 'G':
        mult = 1024.0 * 1024 * 1024;
        break;
      case 't':
      case 'T':
        mult = 1024.0 * 1024 * 1024 * 1024;
        break;
      default:
        break;
    }
    if (mult != 1) s.pop_back();
  }
  double v = 0;
  if (s.empty() || !absl::SimpleAtod(s, &v) || !(v >= 0) || !std::isfinite(v)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("'%s' is not a size (examples: 4096, 512M, 1G)", text));
  }
  // 2^64 and more do not fit (the conversion would be undefined, and came out as 0).
  if (v * mult >= 18446744073709551616.0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("'%s' is too large a size (at most 16 EiB)", text));
  }
  return static_cast<uint64_t>(v * mult);
}

CLI::Validator BytesValidator() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        if (s == "auto") return std::string();  // budgets: see tools/budget.h
        auto r = ParseBytes(s);
        return r.ok() ? std::string() : std::string(r.status().message());
      },
      "SIZE");
}

std::string FormatBytes(uint64_t bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  double v = static_cast<double>(bytes);
  int u = 0;
  while (v >= 1024.0 && u < 4) {
    v /= 1024.0;
    ++u;
  }
  return u == 0 ? absl::StrFormat("%d B", bytes) : absl::StrFormat("%.1f %s", v, units[u]);
}

void NoteStoreLeftovers(const char* command, const std::string& db) {
  const StoreLeftovers left = FindStoreLeftovers(db);
  if (!left.active_writer.empty()) {
    std::fprintf(stderr,
                 "pbgi %s: note: a build (pid %s) is writing %s now; it replaces the store when "
                 "it finishes\n",
                 command, left.active_writer.c_str(), db.c_str());
  } else if (!left.files.empty()) {
    std::fprintf(stderr,
                 "pbgi %s: note: %s (%s) is left over from a build that did not finish; the next "
                 "build to %s removes it (or delete it)\n",
                 command, left.files.front().c_str(), FormatBytes(left.bytes).c_str(), db.c_str());
  }
}

bool StderrIsTerminal() { return isatty(STDERR_FILENO) != 0; }

}  // namespace pbgi::tools

int main(int argc, char** argv) {
  using pbgi::tools::Registry;
  CLI::App app{"pbgi: coherent out-of-core point-based global illumination"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "pbgi 0.1.0");
  std::map<CLI::App*, std::function<absl::Status()>> runners;
  std::map<CLI::App*, std::string> names;
  for (auto& e : Registry()) {
    CLI::App* sub = app.add_subcommand(e.name, e.help);
    runners[sub] = e.setup(sub);
    names[sub] = e.name;
  }
  CLI11_PARSE(app, argc, argv);
  for (auto& [sub, run] : runners) {
    if (sub->parsed()) {
      absl::Status s = run();
      if (!s.ok()) {
        std::fprintf(stderr, "pbgi %s: %s\n", names[sub].c_str(), std::string(s.message()).c_str());
        return 1;
      }
      return 0;
    }
  }
  return 2;
}
