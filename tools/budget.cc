#include "tools/budget.h"

#include <algorithm>
#include <cstdio>
#include <string>

#include "absl/strings/str_format.h"
#include "base/memory_limit.h"
#include "pbgi/status.h"
#include "tools/args.h"
#include "tools/command.h"

namespace pbgi::tools {

absl::StatusOr<uint64_t> ResolveBudget(const char* command, const char* option,
                                       const std::string& text, uint64_t preferred,
                                       uint64_t minimum, const char* minimum_why) {
  const internal::MemoryLimit limit = internal::ReadMemoryLimit();
  const uint64_t headroom = limit.Headroom();
  auto describe = [&]() {
    std::string s;
    if (limit.cgroup_limit > 0) {
      s = absl::StrFormat("the memory cgroup allows %s (%s), %s of it in use",
                          FormatBytes(limit.cgroup_limit), limit.cgroup_file,
                          FormatBytes(limit.cgroup_usage));
    }
    if (limit.available > 0) {
      s += absl::StrFormat("%s%s available on the machine", s.empty() ? "" : "; ",
                           FormatBytes(limit.available));
    }
    return s;
  };
  uint64_t bytes = 0;
  if (text == "auto") {
    bytes = headroom > 0 ? std::min(preferred, headroom / 2) : preferred;
    bytes = std::max(bytes, minimum);  // a warning below says when even that does not fit
  } else {
    PBGI_ASSIGN_OR_RETURN(bytes, ParseBudget(text, option));  // a unit is required
    if (bytes < minimum) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s %s is below the %s this job needs (%s): give at least %s %s", option,
                          text, FormatBytes(minimum), minimum_why, option,
                          absl::StrFormat("%dK", (minimum + 1023) / 1024)));
    }
  }
  if (headroom > 0 && bytes > headroom) {
    std::fprintf(stderr,
                 "pbgi %s: warning: %s %s is more than this process can use (%s): it may be "
                 "killed for lack of memory; %s%s\n",
                 command, option, FormatBytes(bytes).c_str(), describe().c_str(),
                 headroom / 2 >= minimum
                     ? absl::StrFormat("try %s %dM", option, headroom / 2 >> 20).c_str()
                     : "there is not room for the smallest budget: ",
                 headroom / 2 >= minimum ? "" : FormatBytes(minimum).c_str());
  }
  return bytes;
}

std::string ViewJobWhat(int width, int height) {
  return absl::StrFormat("the view's %dx%d pixels (%d bytes each)", width, height,
                         kViewBytesPerPixel);
}

uint64_t MinShadeCacheBytes(int threads, uint64_t page_size) {
  return 4 * uint64_t(std::max(threads, 1)) * std::max<uint64_t>(page_size, 4096);
}

absl::StatusOr<ShadeBudget> SplitShadeBudget(const char* option, const std::string& text,
                                             uint64_t total, uint64_t resident, uint64_t job,
                                             const std::string& resident_what,
                                             const std::string& job_what, int threads,
                                             uint64_t page_size) {
  const uint64_t min_cache = MinShadeCacheBytes(threads, page_size);
  const uint64_t held = resident + job;
  if (held >= total || total - held < min_cache) {
    const std::string resident_part =
        resident > 0
            ? absl::StrFormat(" and the %s held by %s", FormatBytes(resident), resident_what)
            : std::string();
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s %s leaves %s for pages after the %s of %s%s, less than the %s that %d threads need "
        "(4 pages of %d bytes each): give at least %s %dK",
        option, text, FormatBytes(held >= total ? 0 : total - held), FormatBytes(job), job_what,
        resident_part, FormatBytes(min_cache), std::max(threads, 1), page_size, option,
        (held + min_cache + 1023) / 1024));
  }
  ShadeBudget b;
  b.total = total;
  b.resident = resident;
  b.job = job;
  b.cache = total - held;
  return b;
}

std::string DescribeShadeBudget(const ShadeBudget& b, const std::string& resident_what,
                                const std::string& job_what) {
  std::string s = absl::StrFormat("%s: ", FormatBytes(b.total));
  if (b.resident > 0) {
    s += absl::StrFormat("%s held by %s, ", FormatBytes(b.resident), resident_what);
  }
  return s + absl::StrFormat("%s for %s, %s for the page cache", FormatBytes(b.job), job_what,
                             FormatBytes(b.cache));
}

}  // namespace pbgi::tools
