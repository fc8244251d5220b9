// How much memory this process may use: the limit of its memory cgroup (v2 memory.max, v1
// memory.limit_in_bytes, the smallest along its cgroup's path) less what the cgroup already
// holds, and the machine's MemAvailable. The commands size their default budgets below it and
// warn when a budget given exceeds it: a container's limit is enforced by the OOM killer,
// without a word. Internal.
//
// For tests, environment variables replace the files: PBGI_CGROUP_MEMORY_LIMIT_FILE (a file
// holding a limit, or "max"), PBGI_CGROUP_MEMORY_USAGE_FILE (bytes in use) and
// PBGI_MEMINFO_FILE (a /proc/meminfo).
#ifndef PBGI_BASE_MEMORY_LIMIT_H_
#define PBGI_BASE_MEMORY_LIMIT_H_

#include <cstdint>
#include <string>

namespace pbgi::internal {

struct MemoryLimit {
  uint64_t cgroup_limit = 0;  // bytes; 0: no limit found
  uint64_t cgroup_usage = 0;  // bytes the cgroup holds now (0 when unknown)
  std::string cgroup_file;    // where cgroup_limit was read
  uint64_t available = 0;     // MemAvailable, bytes (0 when unknown)

  // What this process can still use: the smaller of the cgroup's free part and MemAvailable;
  // 0 when neither is known.
  uint64_t Headroom() const;
};

MemoryLimit ReadMemoryLimit();

}  // namespace pbgi::internal

#endif  // PBGI_BASE_MEMORY_LIMIT_H_
