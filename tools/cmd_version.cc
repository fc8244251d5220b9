// `pbgi version`: what this binary is and which formats it reads.
#include <cstdio>

#include "pbgi/store.h"
#include "tools/command.h"

namespace pbgi::tools {
namespace {

CommandSetup Setup() {
  return [](CLI::App*) -> std::function<absl::Status()> {
    return []() {
      std::printf("pbgi 0.1.0, store format version %u\n", kStoreFormatVersion);
      return absl::OkStatus();
    };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(version, "version", "Print the version and the store format it reads",
                      Setup());
}  // namespace pbgi::tools
