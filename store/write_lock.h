// The writer lock of a store directory: one PageWriter per directory at a time, across threads
// and processes. Internal.
//
// The lock is an open-file-description lock (fcntl F_OFD_SETLK, Linux 3.15+) on
// `dir`/writer.lock. Unlike a POSIX record lock it is not dropped when another descriptor of the
// file is closed in the same process, and unlike flock() it can be queried (F_OFD_GETLK) without
// being taken, so `pbgi info` can ask whether a build is running without ever making a real
// writer fail. The kernel releases it when the holder dies, so a killed build never leaves a
// stale lock. The holder writes its pid into the file for the loser's message. The file is
// removed on release; a writer that opened it just before then notices (the path no longer
// names the inode it locked) and retries, so two writers can never hold two different files.
#ifndef PBGI_STORE_WRITE_LOCK_H_
#define PBGI_STORE_WRITE_LOCK_H_

#include <optional>
#include <string>

#include "absl/status/statusor.h"

namespace pbgi::internal {

inline constexpr char kWriterLockFile[] = "writer.lock";

class WriterLock {
 public:
  // Takes the lock of the existing directory `dir` without waiting. FailedPrecondition naming
  // the directory and the holder's pid when another writer has it.
  static absl::StatusOr<WriterLock> Acquire(const std::string& dir);

  WriterLock(WriterLock&& o) noexcept : path_(std::move(o.path_)), fd_(o.fd_) { o.fd_ = -1; }
  WriterLock& operator=(WriterLock&& o) noexcept;
  WriterLock(const WriterLock&) = delete;
  WriterLock& operator=(const WriterLock&) = delete;
  ~WriterLock() { Release(); }

  // Removes the lock file and drops the lock (also done by the destructor).
  void Release();

 private:
  WriterLock(std::string path, int fd) : path_(std::move(path)), fd_(fd) {}
  std::string path_;
  int fd_ = -1;
};

// Who holds the writer lock of `dir` now: the holder's pid as the lock file records it ("?" when
// it cannot be read), or nullopt when nobody does. Never takes the lock.
std::optional<std::string> WriterLockHolder(const std::string& dir);

}  // namespace pbgi::internal

#endif  // PBGI_STORE_WRITE_LOCK_H_
