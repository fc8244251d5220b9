// What every command does before and while writing its outputs: refuse an output that is one of
// its inputs before anything is opened for writing (`shade --receivers a.ply -o a.ply`
// truncated its input), and write through a temporary name beside the output that is renamed
// over it only when the output is complete.
#ifndef PBGI_TOOLS_OUTPUTS_H_
#define PBGI_TOOLS_OUTPUTS_H_

#include <atomic>
#include <string>
#include <vector>

#include "absl/status/status.h"

namespace pbgi::tools {

// InvalidArgument when an output names the same file or directory as an input (by path after
// resolving symbolic links and `..`, or by inode when both exist), or two outputs are the same.
absl::Status CheckOutputsAreNotInputs(const std::vector<std::string>& inputs,
                                      const std::vector<std::string>& outputs);

// A file written under `PATH.tmp-PID` and renamed over PATH by Commit(); destroyed without a
// Commit(), it removes the temporary file and PATH stays as it was.
class OutputFile {
 public:
  explicit OutputFile(std::string path);
  ~OutputFile();
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  const std::string& path() const { return path_; }
  const std::string& tmp_path() const { return tmp_path_; }
  // Syncs the temporary file and renames it over path().
  absl::Status Commit();

 private:
  std::string path_, tmp_path_;
  bool committed_ = false;
};

// SIGINT, SIGTERM, SIGHUP and SIGPIPE caught while it lives: a command checks interrupted() between
// batches and returns Cancelled, so that its outputs' destructors remove their temporary files and
// the previous outputs stay (the default action would kill it mid-write).
class InterruptGuard {
 public:
  InterruptGuard();
  ~InterruptGuard();
  InterruptGuard(const InterruptGuard&) = delete;
  InterruptGuard& operator=(const InterruptGuard&) = delete;
  const std::atomic<bool>* flag() const;
  bool interrupted() const { return flag()->load(std::memory_order_relaxed); }
  // Cancelled "`what` was interrupted" when a signal came, else OK.
  absl::Status Check(const std::string& what) const;

 private:
  void (*previous_int_)(int);
  void (*previous_term_)(int);
  void (*previous_hup_)(int);
  void (*previous_pipe_)(int);
};

// The whole of `bytes` into `path`, through an OutputFile.
absl::Status WriteFileAtomically(const std::string& path, const std::string& bytes);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_OUTPUTS_H_
