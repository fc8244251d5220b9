// Shared by the fuzz targets: an input as a file that the code under test opens by path.
#ifndef PBGI_FUZZ_FUZZ_UTIL_H_
#define PBGI_FUZZ_FUZZ_UTIL_H_

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <string>

namespace pbgi::fuzz {

// A memory file (memfd) rewritten with every input; its /proc/self/fd path opens it.
class MemFile {
 public:
  MemFile() : fd_(memfd_create("pbgi-fuzz", MFD_CLOEXEC)) {
    if (fd_ < 0) std::abort();
    path_ = "/proc/self/fd/" + std::to_string(fd_);
  }
  const std::string& Set(const uint8_t* data, size_t size) {
    if (ftruncate(fd_, 0) != 0) std::abort();
    size_t done = 0;
    while (done < size) {
      const ssize_t n = pwrite(fd_, data + done, size - done, static_cast<off_t>(done));
      if (n <= 0) std::abort();
      done += static_cast<size_t>(n);
    }
    return path_;
  }
  const std::string& path() const { return path_; }

 private:
  int fd_;
  std::string path_;
};

// Fails the run (a crash libFuzzer records, an abort the replay driver reports).
inline void Require(bool ok) {
  if (!ok) __builtin_trap();
}

}  // namespace pbgi::fuzz

#endif  // PBGI_FUZZ_FUZZ_UTIL_H_
