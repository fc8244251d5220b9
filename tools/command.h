// The `pbgi` command's subcommand registry. Each subcommand lives in its own tools/cmd_*.cc and
// registers itself with a static PBGI_REGISTER_COMMAND; main.cc parses and dispatches. Only
// tools/ turns an absl::Status into an exit code and a one-line message for a person.
#ifndef PBGI_TOOLS_COMMAND_H_
#define PBGI_TOOLS_COMMAND_H_

#include <cstdint>
#include <functional>
#include <string>

#include "CLI/CLI.hpp"
#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace pbgi::tools {

// Adds the subcommand's options to `app` and returns what runs it after parsing.
using CommandSetup = std::function<std::function<absl::Status()>(CLI::App* app)>;

bool RegisterCommand(const char* name, const char* help, CommandSetup setup);

#define PBGI_REGISTER_COMMAND(ident, name, help, setup) \
  static const bool kPbgiCommand_##ident = ::pbgi::tools::RegisterCommand(name, help, setup)

// "512M", "1G", "1.5GiB", "4096" -> bytes. (These three live in tools/args.cc.)
absl::StatusOr<uint64_t> ParseBytes(const std::string& text);
// A CLI11 validator for byte sizes.
CLI::Validator BytesValidator();
// "1.5 GiB"
std::string FormatBytes(uint64_t bytes);
// Prints to stderr what a build that did not finish left in the store directory `db` (or that a
// build is writing it now), if anything: `pbgi info` and `pbgi verify` mention it.
void NoteStoreLeftovers(const char* command, const std::string& db);
// Whether stderr is a terminal (progress redraws a line) or not (a line per second).
bool StderrIsTerminal();

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_COMMAND_H_
