#include "tools/progress.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"

namespace pbgi::tools {
namespace {

double SteadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double IntervalFromEnvironment(Progress::Style style) {
  if (style == Progress::Style::kBar) return 0.1;
  double v = 5.0;
  if (const char* e = std::getenv("PBGI_PROGRESS_SECONDS")) {
    double d = 0;
    if (absl::SimpleAtod(e, &d) && d >= 0) v = d;
  }
  return v;
}

}  // namespace

std::string ShortCount(double v) {
  const char* suffix[] = {"", "k", "M", "G", "T"};
  int s = 0;
  while (std::abs(v) >= 999.5 && s < 4) {
    v /= 1000.0;
    ++s;
  }
  if (s == 0) return absl::StrFormat("%.0f", v);
  // Constant formats (clang checks them at compile time).
  if (v < 9.995) return absl::StrFormat("%.2f%s", v, suffix[s]);
  if (v < 99.95) return absl::StrFormat("%.1f%s", v, suffix[s]);
  return absl::StrFormat("%.0f%s", v, suffix[s]);
}

std::string Clocklike(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const int64_t t = static_cast<int64_t>(std::llround(seconds));
  if (t >= 3600) return absl::StrFormat("%d:%02d:%02d", t / 3600, (t / 60) % 60, t % 60);
  return absl::StrFormat("%d:%02d", t / 60, t % 60);
}

Progress::Style Progress::StyleFromEnvironment() {
  if (const char* e = std::getenv("PBGI_PROGRESS")) {
    if (std::strcmp(e, "bar") == 0) return Style::kBar;
    if (std::strcmp(e, "lines") == 0) return Style::kLines;
    if (std::strcmp(e, "none") == 0) return Style::kNone;
  }
  return isatty(STDERR_FILENO) ? Style::kBar : Style::kLines;
}

Progress::Progress(std::string label, std::string unit, int64_t total)
    : Progress(std::move(label), std::move(unit), total, StyleFromEnvironment(),
               IntervalFromEnvironment(StyleFromEnvironment()), SteadySeconds, stderr) {}

Progress::Progress(std::string label, std::string unit, int64_t total, Style style, double interval,
                   Clock clock, std::FILE* out)
    : job_(label),
      label_(std::move(label)),
      unit_(std::move(unit)),
      total_(total),
      style_(style),
      interval_(interval),
      clock_(std::move(clock)),
      out_(out) {
  start_ = phase_start_ = clock_();
}

Progress::~Progress() { Abandon(); }

std::string Progress::Line(uint64_t done, double now) const {
  const double secs = std::max(1e-9, now - phase_start_);
  const double rate = double(done) / secs;
  std::string s = label_ + ": ";
  if (total_ > 0) {
    const double f = std::min(1.0, double(done) / double(total_));
    if (style_ == Style::kBar) {
      constexpr int kWidth = 24;
      const int full = static_cast<int>(f * kWidth);
      // Appended piece by piece: g++ 12's -O3 warned (-Wrestrict, a false positive) on
      // "[" + std::string(...).
      s += '[';
      s.append(size_t(full), '#');
      s.append(size_t(kWidth - full), '.');
      s += "] ";
    }
    s += absl::StrFormat("%d / %d %s (%.1f%%), %s %s/s", done, total_, unit_, 100.0 * f,
                         ShortCount(rate), unit_);
    const double left = rate > 0
                            ? double(uint64_t(total_) - std::min(done, uint64_t(total_))) / rate
                            : std::numeric_limits<double>::infinity();
    s += ", ETA " + Clocklike(left);
  } else {
    s += absl::StrFormat("%d %s, %s %s/s", done, unit_, ShortCount(rate), unit_);
  }
  s += absl::StrFormat(", %s elapsed", Clocklike(now - start_));
  return s;
}

void Progress::Print(uint64_t done, double now) {
  if (style_ == Style::kNone) return;
  const std::string line = Line(done, now);
  if (style_ == Style::kBar) {
    std::fprintf(out_, "\r%s\033[K", line.c_str());
    drew_ = true;
  } else {
    std::fprintf(out_, "%s\n", line.c_str());
  }
  std::fflush(out_);
  last_ = now;
}

void Progress::Phase(const std::string& label, int64_t total) {
  std::lock_guard<std::mutex> l(mu_);
  const double now = clock_();
  if (last_done_ > 0 && style_ == Style::kBar) Print(last_done_, now);
  if (drew_) {
    std::fputc('\n', out_);
    drew_ = false;
  }
  label_ = label;
  total_ = total;
  phase_start_ = now;
  last_done_ = 0;
  last_ = -1e30;
}

void Progress::Update(uint64_t done) { Update(done, kKeepTotal); }

void Progress::Update(uint64_t done, int64_t total) {
  std::unique_lock<std::mutex> l(mu_, std::try_to_lock);
  if (!l.owns_lock() || finished_) return;
  if (total != kKeepTotal) total_ = total;
  last_done_ = done;
  const double now = clock_();
  if (now - last_ < interval_) return;
  // The first line waits for one interval too: jobs shorter than that print only the summary.
  if (last_ < -1e29 && now - phase_start_ < interval_) return;
  Print(done, now);
}

void Progress::Finish(uint64_t done, const std::string& detail) {
  std::lock_guard<std::mutex> l(mu_);
  if (finished_) return;
  last_done_ = done;
  finished_ = true;
  if (style_ == Style::kNone) return;
  const double now = clock_();
  const double secs = now - start_;
  if (drew_) std::fputc('\r', out_);
  std::fprintf(out_, "%s: %llu %s in %.2f s (%s %s/s)%s%s%s\n", job_.c_str(),
               static_cast<unsigned long long>(last_done_), unit_.c_str(), secs,
               ShortCount(double(last_done_) / std::max(1e-9, secs)).c_str(), unit_.c_str(),
               detail.empty() ? "" : ", ", detail.c_str(), drew_ ? "\033[K" : "");
  drew_ = false;
  std::fflush(out_);
}

void Progress::Abandon() {
  std::lock_guard<std::mutex> l(mu_);
  finished_ = true;
  if (drew_) {
    std::fputc('\n', out_);
    drew_ = false;
  }
}

}  // namespace pbgi::tools
