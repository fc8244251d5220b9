// What every command parses the same way: counts ("50k", "2M", "1e8"), memory budgets (a unit is
// required: "--memory 100" is never 100 bytes on purpose), thread counts (0: all cores), and the
// tool's version and the date for provenance.
#ifndef PBGI_TOOLS_ARGS_H_
#define PBGI_TOOLS_ARGS_H_

#include <cstdint>
#include <string>

#include "CLI/CLI.hpp"
#include "absl/status/statusor.h"

namespace pbgi::tools {

inline constexpr const char* kToolVersion = "pbgi 0.1.0";

// "1000", "50k", "2.5M", "1e8", "1G" -> a count (decimal suffixes k, M, G, T; a whole number
// after the suffix). `what` names the option in errors.
absl::StatusOr<int64_t> ParseCount(const std::string& text, const std::string& what = "count");
// A CLI11 validator for counts, within [lo, hi]; as a ->transform() it also rewrites the text
// to the plain number, so that an integer option takes "50k".
CLI::Validator CountValidator(int64_t lo = 0, int64_t hi = int64_t{1} << 62);

// A memory budget: ParseBytes() with a unit required (512M, 1G, 4096B).
absl::StatusOr<uint64_t> ParseBudget(const std::string& text, const std::string& what);
CLI::Validator BudgetValidator();

// --threads: 0 means every core.
int ResolveThreads(int threads);

// The local date and time, ISO 8601 ("2026-12-01T21:45:03+0100").
std::string NowIso8601();

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_ARGS_H_
