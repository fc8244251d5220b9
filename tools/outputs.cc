#include "tools/outputs.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "absl/strings/str_format.h"

namespace pbgi::tools {
namespace {

std::string Resolved(const std::string& p) {
  std::error_code ec;
  std::filesystem::path r = std::filesystem::weakly_canonical(std::filesystem::absolute(p), ec);
  if (ec) return std::filesystem::absolute(p).lexically_normal().string();
  std::string s = r.string();
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}

bool SameFile(const std::string& a, const std::string& b) {
  if (Resolved(a) == Resolved(b)) return true;
  std::error_code ec;
  return std::filesystem::exists(a, ec) && std::filesystem::exists(b, ec) &&
         std::filesystem::equivalent(a, b, ec) && !ec;
}

}  // namespace

absl::Status CheckOutputsAreNotInputs(const std::vector<std::string>& inputs,
                                      const std::vector<std::string>& outputs) {
  for (size_t o = 0; o < outputs.size(); ++o) {
    if (outputs[o].empty()) continue;
    for (const std::string& in : inputs) {
      if (!in.empty() && SameFile(in, outputs[o])) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "the output %s is the input %s: writing it would destroy what is being read (give "
            "another -o)",
            outputs[o], in));
      }
    }
    for (size_t p = 0; p < o; ++p) {
      if (!outputs[p].empty() && SameFile(outputs[p], outputs[o])) {
        return absl::InvalidArgumentError(
            absl::StrFormat("two outputs are the same file: %s and %s", outputs[p], outputs[o]));
      }
    }
  }
  return absl::OkStatus();
}

OutputFile::OutputFile(std::string path)
    : path_(std::move(path)), tmp_path_(absl::StrFormat("%s.tmp-%d", path_, getpid())) {}

OutputFile::~OutputFile() {
  if (!committed_) std::remove(tmp_path_.c_str());
}

absl::Status OutputFile::Commit() {
  const int fd = open(tmp_path_.c_str(), O_RDONLY);
  if (fd < 0 || fsync(fd) != 0) {
    const std::string why = std::strerror(errno);
    if (fd >= 0) close(fd);
    return absl::UnavailableError(absl::StrFormat("cannot sync %s: %s", tmp_path_, why));
  }
  close(fd);
  if (std::rename(tmp_path_.c_str(), path_.c_str()) != 0) {
    return absl::UnavailableError(
        absl::StrFormat("cannot rename %s to %s: %s", tmp_path_, path_, std::strerror(errno)));
  }
  committed_ = true;
  return absl::OkStatus();
}

namespace {
std::atomic<bool> g_interrupted{false};
extern "C" void OnInterruptSignal(int) { g_interrupted.store(true); }
}  // namespace

InterruptGuard::InterruptGuard() {
  g_interrupted.store(false);
  previous_int_ = std::signal(SIGINT, OnInterruptSignal);
  previous_term_ = std::signal(SIGTERM, OnInterruptSignal);
  // A closed pipe (`pbgi shade ... 2>&1 | head`) and a closed terminal end the job the same way,
  // instead of killing it with its temporary files left behind.
  previous_hup_ = std::signal(SIGHUP, OnInterruptSignal);
  previous_pipe_ = std::signal(SIGPIPE, OnInterruptSignal);
}

InterruptGuard::~InterruptGuard() {
  std::signal(SIGINT, previous_int_);
  std::signal(SIGTERM, previous_term_);
  std::signal(SIGHUP, previous_hup_);
  std::signal(SIGPIPE, previous_pipe_);
}

const std::atomic<bool>* InterruptGuard::flag() const { return &g_interrupted; }

absl::Status InterruptGuard::Check(const std::string& what) const {
  if (!interrupted()) return absl::OkStatus();
  return absl::CancelledError(
      absl::StrFormat("%s was interrupted; the previous outputs are as they were", what));
}

absl::Status WriteFileAtomically(const std::string& path, const std::string& bytes) {
  OutputFile out(path);
  std::FILE* f = std::fopen(out.tmp_path().c_str(), "wb");
  if (f == nullptr) {
    return absl::UnavailableError(
        absl::StrFormat("cannot create %s: %s", out.tmp_path(), std::strerror(errno)));
  }
  bool ok = std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size();
  ok = std::fclose(f) == 0 && ok;
  if (!ok) {
    return absl::UnavailableError(
        absl::StrFormat("cannot write %s: %s (disk full?)", out.tmp_path(), std::strerror(errno)));
  }
  return out.Commit();
}

}  // namespace pbgi::tools
