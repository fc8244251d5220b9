#include "base/memory_limit.h"

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace pbgi::internal {
namespace {

// v1 says "no limit" with a huge number (the largest page-aligned int64).
constexpr uint64_t kNoLimit = uint64_t{1} << 60;

// The first number in the file, or 0 for "max", a missing file or anything else.
uint64_t ReadNumber(const std::string& file) {
  std::ifstream in(file);
  std::string word;
  if (!(in >> word) || word.empty() || word[0] < '0' || word[0] > '9') return 0;
  const uint64_t v = std::strtoull(word.c_str(), nullptr, 10);
  return v >= kNoLimit ? 0 : v;
}

const char* Env(const char* name) {
  const char* v = std::getenv(name);
  return v != nullptr && v[0] != '\0' ? v : nullptr;
}

// The smallest limit along `path` and its parents under `root`, with the usage of the cgroup
// that sets it.
void Walk(const std::string& root, std::string path, const char* limit_name, const char* usage_name,
          MemoryLimit* out) {
  for (;;) {
    const std::string dir = root + path;
    const uint64_t limit = ReadNumber(dir + "/" + limit_name);
    if (limit > 0 && (out->cgroup_limit == 0 || limit < out->cgroup_limit)) {
      out->cgroup_limit = limit;
      out->cgroup_file = dir + "/" + limit_name;
      out->cgroup_usage = ReadNumber(dir + "/" + usage_name);
    }
    if (path.empty() || path == "/") break;
    path = path.substr(0, path.find_last_of('/'));
  }
}

}  // namespace

uint64_t MemoryLimit::Headroom() const {
  uint64_t h = 0;
  if (cgroup_limit > 0) h = cgroup_limit > cgroup_usage ? cgroup_limit - cgroup_usage : 1;
  if (available > 0) h = h == 0 ? available : std::min(h, available);
  return h;
}

MemoryLimit ReadMemoryLimit() {
  MemoryLimit m;
  if (const char* f = Env("PBGI_CGROUP_MEMORY_LIMIT_FILE")) {
    m.cgroup_limit = ReadNumber(f);
    m.cgroup_file = f;
    if (const char* u = Env("PBGI_CGROUP_MEMORY_USAGE_FILE")) m.cgroup_usage = ReadNumber(u);
  } else {
    // /proc/self/cgroup: "0::/path" (v2), "N:memory:/path" or "N:...,memory,...:/path" (v1).
    std::ifstream in("/proc/self/cgroup");
    std::string line;
    while (std::getline(in, line)) {
      const size_t a = line.find(':'), b = line.find(':', a + 1);
      if (a == std::string::npos || b == std::string::npos) continue;
      const std::string controllers = line.substr(a + 1, b - a - 1);
      const std::string path = line.substr(b + 1);
      if (controllers.empty()) {
        Walk("/sys/fs/cgroup", path, "memory.max", "memory.current", &m);
      } else if (("," + controllers + ",").find(",memory,") != std::string::npos) {
        Walk("/sys/fs/cgroup/memory", path, "memory.limit_in_bytes", "memory.usage_in_bytes", &m);
      }
    }
  }
  std::ifstream meminfo(Env("PBGI_MEMINFO_FILE") ? Env("PBGI_MEMINFO_FILE") : "/proc/meminfo");
  std::string key;
  uint64_t kb = 0;
  std::string unit;
  while (meminfo >> key >> kb) {
    std::getline(meminfo, unit);
    if (key == "MemAvailable:") {
      m.available = kb * 1024;
      break;
    }
  }
  return m;
}

}  // namespace pbgi::internal
