// A monotonic stopwatch (steady_clock) for the timings that builds, shading and the commands
// report, and the process's CPU time. Internal.
#ifndef PBGI_BASE_STOPWATCH_H_
#define PBGI_BASE_STOPWATCH_H_

#include <time.h>

#include <chrono>

namespace pbgi::internal {

class Stopwatch {
 public:
  using Clock = std::chrono::steady_clock;
  Stopwatch() : start_(Clock::now()) {}
  // Seconds since construction or the last Restart().
  double Seconds() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }
  double Milliseconds() const { return 1e3 * Seconds(); }
  void Restart() { start_ = Clock::now(); }

 private:
  Clock::time_point start_;
};

// CPU time of this process so far, all threads (CLOCK_PROCESS_CPUTIME_ID): unlike a stopwatch
// it does not count the time a thread waits for a core on a busy machine.
inline double ProcessCpuSeconds() {
  timespec ts{};
  if (clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts) != 0) return 0;
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

}  // namespace pbgi::internal

#endif  // PBGI_BASE_STOPWATCH_H_
