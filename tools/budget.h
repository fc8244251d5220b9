// Memory budgets of the commands (--memory, --cache) that fit the machine: "auto", the default,
// is the command's preferred size capped at half of what this process may use (its memory
// cgroup's limit less what it holds, and MemAvailable: base/memory_limit.h), so that a small
// container is not OOM-killed without a word; a size given above that gets a warning; a size
// below what the job can run in is refused with the minimum.
#ifndef PBGI_TOOLS_BUDGET_H_
#define PBGI_TOOLS_BUDGET_H_

#include <cstdint>
#include <string>

#include "absl/status/statusor.h"

namespace pbgi::tools {

// `text` of option `option` ("--memory") of `command` ("build") as bytes (see above).
// `minimum_why` says what the minimum is made of, for the refusal.
absl::StatusOr<uint64_t> ResolveBudget(const char* command, const char* option,
                                       const std::string& text, uint64_t preferred,
                                       uint64_t minimum, const char* minimum_why);

// What shading one receiver from a point file costs besides the cache: the surfel read, the
// receiver, its result and its place in the Z-order. The chunk of receivers comes out of the
// --cache budget.
inline constexpr uint64_t kShadeBytesPerReceiver = 144;

// The smallest page cache a command accepts before it knows the page size: 16 pages of the
// default size (the cache keeps two pinned per Reader; `pbgi shade` checks its own minimum
// once the database is open).
inline constexpr uint64_t kMinCacheBytes = uint64_t{1} << 20;

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_BUDGET_H_
