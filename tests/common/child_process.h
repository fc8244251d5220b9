// Runs a piece of a test in a forked child process, for limits that must not stay on the test
// process (RLIMIT_FSIZE standing in for a full disk) or for code that may crash or hang.
#ifndef PBGI_TESTS_COMMON_CHILD_PROCESS_H_
#define PBGI_TESTS_COMMON_CHILD_PROCESS_H_

#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdint>
#include <functional>
#include <string>

namespace pbgi::testing_common {

struct ChildResult {
  bool exited = false;  // exited normally (not killed by a signal, e.g. the alarm)
  int signal = 0;       // the signal that ended it, when !exited
  std::string report;   // what `body` returned
};

// Forks; the child ignores SIGXFSZ, sets RLIMIT_FSIZE to `file_size_limit` bytes (0: none), arms
// an alarm of `timeout_seconds` (a hang fails instead of blocking the suite), runs `body` and
// sends its string back. Call it before the test process starts threads.
inline ChildResult RunInChild(const std::function<std::string()>& body,
                              uint64_t file_size_limit = 0, unsigned timeout_seconds = 120) {
  ChildResult r;
  int fds[2];
  if (pipe(fds) != 0) {
    r.report = "pipe() failed";
    return r;
  }
  const pid_t pid = fork();
  if (pid < 0) {
    close(fds[0]);
    close(fds[1]);
    r.report = "fork() failed";
    return r;
  }
  if (pid == 0) {
    close(fds[0]);
    alarm(timeout_seconds);
    signal(SIGXFSZ, SIG_IGN);
    if (file_size_limit > 0) {
      rlimit lim{static_cast<rlim_t>(file_size_limit), static_cast<rlim_t>(file_size_limit)};
      setrlimit(RLIMIT_FSIZE, &lim);
    }
    const std::string report = body();
    (void)!write(fds[1], report.data(), report.size());
    _exit(0);
  }
  close(fds[1]);
  char buf[512];
  ssize_t n;
  while ((n = read(fds[0], buf, sizeof(buf))) > 0) r.report.append(buf, static_cast<size_t>(n));
  close(fds[0]);
  int status = 0;
  if (waitpid(pid, &status, 0) != pid) return r;
  r.exited = WIFEXITED(status);
  r.signal = WIFSIGNALED(status) ? WTERMSIG(status) : 0;
  return r;
}

}  // namespace pbgi::testing_common

#endif  // PBGI_TESTS_COMMON_CHILD_PROCESS_H_
