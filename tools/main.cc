// pbgi: build, inspect, query and shade Coherent PBGI databases from a terminal.
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "pbgi/store.h"
#include "tools/args.h"
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
  app.set_version_flag("--version", pbgi::tools::kToolVersion);
  std::map<CLI::App*, std::function<absl::Status()>> runners;
  std::map<CLI::App*, std::string> names;
  for (auto& e : Registry()) {
    CLI::App* sub = app.add_subcommand(e.name, e.help);
    runners[sub] = e.setup(sub);
    names[sub] = e.name;
  }
  // PBGI_LIST_OPTIONS=1: every subcommand's options, one per line (name, then its help text),
  // for the test that every option is explained and spelled alike.
  if (std::getenv("PBGI_LIST_OPTIONS") != nullptr) {
    for (auto& [sub, name] : names) {
      for (const CLI::Option* o : sub->get_options()) {
        if (o->get_name() == "--help") continue;
        std::printf("%s\t%s\t%s\n", name.c_str(), o->get_name().c_str(),
                    o->get_description().c_str());
      }
    }
    return 0;
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
