// Progress of a long job on stderr, the same for every command: done / total, rate and ETA; a
// bar redrawn in place on a terminal, a line every few seconds otherwise (logs, CI), and a
// final summary line. PBGI_PROGRESS=bar|lines|none overrides the choice, and
// PBGI_PROGRESS_SECONDS the interval between lines (default 5; bars redraw every 0.1 s).
//
// Thread safety: Update() may be called from several threads (it drops the calls that come
// while another one prints); the other methods belong to one thread.
#ifndef PBGI_TOOLS_PROGRESS_H_
#define PBGI_TOOLS_PROGRESS_H_

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <mutex>
#include <string>

namespace pbgi::tools {

class Progress {
 public:
  enum class Style { kBar, kLines, kNone };
  // Seconds since some fixed point (injectable for tests).
  using Clock = std::function<double()>;

  // `label` names the job ("shade"), `unit` what is counted ("receivers"); total < 0: unknown.
  Progress(std::string label, std::string unit, int64_t total = -1);
  // For tests: a given style, interval, clock and stream.
  Progress(std::string label, std::string unit, int64_t total, Style style, double interval,
           Clock clock, std::FILE* out);
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  // A new phase of the job (e.g. the build's passes): its own label, count and clock for the
  // rate and ETA. Prints the phase's last state first.
  void Phase(const std::string& label, int64_t total);
  // `done` units of the current phase so far; prints when the interval has passed.
  void Update(uint64_t done);
  // The same, with the phase's total learnt late (e.g. the receivers a camera's rays found).
  void Update(uint64_t done, int64_t total);
  // Prints the final summary: "label: N unit in T s (R unit/s)" plus `detail` (the label given
  // to the constructor, the time since then), and ends the bar.
  void Finish(uint64_t done, const std::string& detail = "");
  // Ends the bar's line without a summary (before an error message).
  void Abandon();

  // What the line says now (for tests): done / total (percent), rate, ETA.
  std::string Line(uint64_t done, double now) const;
  static Style StyleFromEnvironment();

 private:
  static constexpr int64_t kKeepTotal = -2;
  void Print(uint64_t done, double now);

  std::string job_;  // the label given at construction: the summary's
  std::string label_, unit_;
  int64_t total_;
  Style style_;
  double interval_;
  Clock clock_;
  std::FILE* out_;
  double start_ = 0, phase_start_ = 0, last_ = -1e30;
  uint64_t last_done_ = 0;
  bool drew_ = false;  // a bar is on the current line
  bool finished_ = false;
  std::mutex mu_;
};

// "1.2k", "3.4M": a count or rate, 3 significant digits.
std::string ShortCount(double v);
// "0:07", "1:02:03": a duration in seconds.
std::string Clocklike(double seconds);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_PROGRESS_H_
