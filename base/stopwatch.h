// A monotonic stopwatch (steady_clock) for the timings that builds, shading and the commands
// report. Internal.
#ifndef PBGI_BASE_STOPWATCH_H_
#define PBGI_BASE_STOPWATCH_H_

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

}  // namespace pbgi::internal

#endif  // PBGI_BASE_STOPWATCH_H_
