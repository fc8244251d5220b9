#include "tools/budget.h"

#include <algorithm>
#include <cstdio>
#include <string>

#include "absl/strings/str_format.h"
#include "base/memory_limit.h"
#include "pbgi/status.h"
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
    PBGI_ASSIGN_OR_RETURN(bytes, ParseBytes(text));
    if (bytes < minimum) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s %s is below the %s this job needs (%s): give at least %s %s", option, text,
          FormatBytes(minimum), minimum_why, option,
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

}  // namespace pbgi::tools
