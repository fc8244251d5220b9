#include "store/write_lock.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "store/lmdb_status.h"

namespace pbgi::internal {
namespace {

std::string LockPath(const std::string& dir) { return absl::StrCat(dir, "/", kWriterLockFile); }

std::string ReadHolder(int fd) {
  char buf[32] = {};
  const ssize_t n = pread(fd, buf, sizeof(buf) - 1, 0);
  if (n <= 0) return "?";
  std::string s(buf, static_cast<size_t>(n));
  absl::StripAsciiWhitespace(&s);
  return s.empty() ? std::string("?") : s;
}

struct flock WholeFile(short type) {
  struct flock fl;
  std::memset(&fl, 0, sizeof(fl));
  fl.l_type = type;
  fl.l_whence = SEEK_SET;
  fl.l_start = 0;
  fl.l_len = 0;  // to the end, whatever the size
  return fl;
}

}  // namespace

WriterLock& WriterLock::operator=(WriterLock&& o) noexcept {
  if (this != &o) {
    Release();
    path_ = std::move(o.path_);
    fd_ = o.fd_;
    o.fd_ = -1;
  }
  return *this;
}

void WriterLock::Release() {
  if (fd_ < 0) return;
  // Unlink while still holding the lock: whoever opens the path afterwards gets a new file.
  unlink(path_.c_str());
  close(fd_);
  fd_ = -1;
}

absl::StatusOr<WriterLock> WriterLock::Acquire(const std::string& dir) {
  const std::string path = LockPath(dir);
  for (int attempt = 0; attempt < 100; ++attempt) {
    const int fd = open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) {
      return LmdbStatus(errno, absl::StrFormat("store %s: creating the writer lock %s", dir, path));
    }
    struct flock fl = WholeFile(F_WRLCK);
    if (fcntl(fd, F_OFD_SETLK, &fl) != 0) {
      const int err = errno;
      if (err == EAGAIN || err == EACCES) {
        const std::string holder = ReadHolder(fd);
        close(fd);
        return absl::FailedPreconditionError(absl::StrFormat(
            "store %s is being written by another build (pid %s holds %s): two builds to one "
            "path would mix their files; wait for it to finish or build to another path",
            dir, holder, path));
      }
      close(fd);
      return LmdbStatus(err, absl::StrFormat("store %s: locking %s", dir, path));
    }
    // The previous holder may have unlinked the file between our open and our lock: then the
    // lock is on a file nobody else will look at. Start again with the file the path names now.
    struct stat mine, named;
    if (fstat(fd, &mine) != 0 || stat(path.c_str(), &named) != 0 || mine.st_ino != named.st_ino ||
        mine.st_dev != named.st_dev) {
      close(fd);
      continue;
    }
    // The pid is for the loser's message only, but a disk that cannot take these few bytes
    // will not take a store either: say so now.
    const std::string pid = absl::StrCat(getpid(), "\n");
    int err = 0;
    if (ftruncate(fd, 0) != 0) {
      err = errno;
    } else if (const ssize_t n = pwrite(fd, pid.data(), pid.size(), 0);
               n != static_cast<ssize_t>(pid.size())) {
      err = n < 0 ? errno : EIO;  // a short write sets no errno
    }
    if (err != 0) {
      unlink(path.c_str());
      close(fd);
      return LmdbStatus(err, absl::StrFormat("store %s: writing the writer lock %s", dir, path));
    }
    return WriterLock(path, fd);
  }
  return absl::UnavailableError(
      absl::StrFormat("store %s: the writer lock %s kept changing hands", dir, path));
}

std::optional<std::string> WriterLockHolder(const std::string& dir) {
  const int fd = open(LockPath(dir).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return std::nullopt;
  // F_GETLK-style queries need a descriptor that could take the lock asked about; a read lock
  // conflicts with the writer's lock just as well and needs only O_RDONLY.
  struct flock fl = WholeFile(F_RDLCK);
  std::optional<std::string> holder;
  if (fcntl(fd, F_OFD_GETLK, &fl) == 0 && fl.l_type != F_UNLCK) holder = ReadHolder(fd);
  close(fd);
  return holder;
}

}  // namespace pbgi::internal
