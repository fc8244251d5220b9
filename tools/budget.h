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

// What shading one receiver from a point file costs besides the cache (tools/cmd_shade.cc,
// ShadePoints): the surfel read and its reflection direction, the receiver (and its copy among
// the valid ones), its results (ShadeBatch's and the chunk's), its place in the Z-order, the
// surfel kept for the output with its result columns and colour. The chunk of receivers comes
// out of the --cache budget.
inline constexpr uint64_t kShadeBytesPerReceiver = 352;

// The smallest page cache a command accepts before it knows the page size: 16 pages of the
// default size (the cache keeps two pinned per Reader; `pbgi shade` and `pbgi demo` check their
// own minimum once the database is open, MinShadeCacheBytes()).
inline constexpr uint64_t kMinCacheBytes = uint64_t{1} << 20;

// What a camera view holds besides the page cache, per pixel of the image, at its largest: the
// traced hits, the receivers, their pixels and materials, the results, image sharing's buffers,
// the images (docs/design.md, "The shade step's budget"). Comes out of --cache.
inline constexpr uint64_t kViewBytesPerPixel = 256;
// A width x height view's share of the budget, and how messages name it ("the view's 2400x1350
// pixels (256 bytes each)").
inline uint64_t ViewJobBytes(int width, int height) {
  return uint64_t(width) * uint64_t(height) * kViewBytesPerPixel;
}
std::string ViewJobWhat(int width, int height);

// The smallest page cache that `threads` Readers work in: 4 pages each (every Reader pins two
// at least), pages counted at 4 KiB at least.
uint64_t MinShadeCacheBytes(int threads, uint64_t page_size);

// A shading budget (`pbgi shade --cache`, `pbgi demo --cache`) split: what the process holds
// already when shading starts (the demo: its code, the scene and its tracer; `pbgi shade`
// counts none), the job (a chunk of receivers, or a view's pixels), and the page cache, the
// rest. resident + job + cache == total.
struct ShadeBudget {
  uint64_t total = 0;
  uint64_t resident = 0;
  uint64_t job = 0;
  uint64_t cache = 0;  // DatabaseOptions::cache_bytes
};

// Splits `total`, given as `option` `text` ("--cache", "1536M"), into a ShadeBudget.
// `resident_what` and `job_what` name the parts in messages, as nouns: "the process (its code,
// the scene and its tracer)", "the view's 2400x1350 pixels (256 bytes each)".
// InvalidArgument when the cache left is below MinShadeCacheBytes(threads, page_size), naming
// each part and the smallest budget that does.
absl::StatusOr<ShadeBudget> SplitShadeBudget(const char* option, const std::string& text,
                                             uint64_t total, uint64_t resident, uint64_t job,
                                             const std::string& resident_what,
                                             const std::string& job_what, int threads,
                                             uint64_t page_size);

// One line: "1.5 GiB: 98.0 MiB held by the process (...), 791.0 MiB for the view's ..., 647.0
// MiB for the page cache" (without the resident part when it is 0).
std::string DescribeShadeBudget(const ShadeBudget& b, const std::string& resident_what,
                                const std::string& job_what);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_BUDGET_H_
