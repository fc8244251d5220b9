// What this process's /proc files say about its memory: peak and current resident set size
// (/proc/self/status), the mapping of a file (/proc/self/maps) and a mapping's resident bytes
// (/proc/self/smaps). The builder and the commands report peak RSS, the store finds and trims
// LMDB's map, and the benchmarks check memory caps with these. Internal.
#ifndef PBGI_BASE_PROC_H_
#define PBGI_BASE_PROC_H_

#include <sys/stat.h>

#include <cstdint>
#include <string>

#include "absl/status/statusor.h"

namespace pbgi::internal {

// VmHWM (peak resident set size) of this process in bytes; 0 where /proc is not there.
uint64_t PeakRssBytes();
// VmRSS (resident set size now) of this process in bytes; 0 where /proc is not there.
uint64_t CurrentRssBytes();
// Returns the free pages of every malloc arena to the system (glibc's malloc_trim; nothing
// elsewhere): memory that other threads freed stays in their arenas and in the RSS otherwise,
// and a thread that allocates next does not reuse it.
void ReleaseFreeHeap();

// The mapping of `file` (at file offset 0) that holds `inside` (or, with nullptr, the first such
// mapping), from /proc/self/maps. `file_name` is what error messages call it.
struct FileMapping {
  const uint8_t* start = nullptr;
  uint64_t bytes = 0;
};
absl::StatusOr<FileMapping> FindFileMapping(const struct stat& file, const void* inside,
                                            const std::string& file_name);

// Rss of the mapping that starts at `start`, from /proc/self/smaps.
absl::StatusOr<uint64_t> MappingRssBytes(const void* start);

}  // namespace pbgi::internal

#endif  // PBGI_BASE_PROC_H_
