// /proc readers (base/proc.h).
#include "base/proc.h"

#include <sys/sysmacros.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"

namespace pbgi::internal {
namespace {

// A "Name:   1234 kB" line of /proc/self/status, in bytes; 0 if absent.
uint64_t StatusBytes(const char* name) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const size_t len = std::strlen(name);
  while (std::getline(in, line)) {
    if (line.rfind(name, 0) == 0) return std::strtoull(line.c_str() + len, nullptr, 10) * 1024;
  }
  return 0;
}

}  // namespace

uint64_t PeakRssBytes() { return StatusBytes("VmHWM:"); }
uint64_t CurrentRssBytes() { return StatusBytes("VmRSS:"); }

void ReleaseFreeHeap() {
#if defined(__GLIBC__)
  malloc_trim(0);
#endif
}

// Where LMDB mapped data.mdb. mdb_env_info's me_mapaddr is only filled in with MDB_FIXEDMAP,
// so the map is found in /proc/self/maps: the mapping of this file (device and inode) that
// holds `inside`, a pointer LMDB returned into it.
absl::StatusOr<FileMapping> FindFileMapping(const struct stat& file, const void* inside,
                                            const std::string& file_name) {
  std::FILE* f = std::fopen("/proc/self/maps", "r");
  if (f == nullptr) {
    return absl::UnavailableError(absl::StrFormat(
        "cannot read /proc/self/maps to find the map of %s (is /proc mounted?)", file_name));
  }
  const auto want = reinterpret_cast<uintptr_t>(inside);
  char line[4096];
  absl::StatusOr<FileMapping> result = absl::InternalError(
      absl::StrFormat("no mapping of %s holds LMDB's pointer %p", file_name, inside));
  while (std::fgets(line, sizeof(line), f) != nullptr) {
    unsigned long start = 0, end = 0, offset = 0, inode = 0;
    unsigned dev_major = 0, dev_minor = 0;
    char perms[8];
    if (std::sscanf(line, "%lx-%lx %7s %lx %x:%x %lu", &start, &end, perms, &offset, &dev_major,
                    &dev_minor, &inode) != 7) {
      continue;
    }
    if (inode != file.st_ino || makedev(dev_major, dev_minor) != file.st_dev) continue;
    if (offset != 0 || (inside != nullptr && (want < start || want >= end))) continue;
    result = FileMapping{reinterpret_cast<const uint8_t*>(start), end - start};
    break;
  }
  std::fclose(f);
  return result;
}

absl::StatusOr<uint64_t> MappingRssBytes(const void* start) {
  std::FILE* f = std::fopen("/proc/self/smaps", "r");
  if (f == nullptr) {
    return absl::UnavailableError("cannot read /proc/self/smaps (is /proc mounted?)");
  }
  const std::string want = absl::StrFormat("%x-", reinterpret_cast<uintptr_t>(start));
  char line[512];
  bool in_mapping = false;
  absl::StatusOr<uint64_t> result =
      absl::NotFoundError(absl::StrFormat("no mapping at %p in /proc/self/smaps", start));
  while (std::fgets(line, sizeof(line), f) != nullptr) {
    // A mapping's header line starts with "start-end"; its fields follow, one per line.
    if (std::strncmp(line, want.c_str(), want.size()) == 0) {
      in_mapping = true;
    } else if (in_mapping && std::strncmp(line, "Rss:", 4) == 0) {
      result = uint64_t{std::strtoull(line + 4, nullptr, 10)} * 1024;
      break;
    }
  }
  std::fclose(f);
  return result;
}

}  // namespace pbgi::internal
