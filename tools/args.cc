#include "tools/args.h"

#include <cmath>
#include <ctime>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"

namespace pbgi::tools {

absl::StatusOr<int64_t> ParseCount(const std::string& text, const std::string& what) {
  std::string s = text;
  double mult = 1.0;
  if (!s.empty()) {
    switch (s.back()) {
      case 'k':
      case 'K':
        mult = 1e3;
        break;
      case 'm':
      case 'M':
        mult = 1e6;
        break;
      case 'g':
      case 'G':
        mult = 1e9;
        break;
      case 't':
      case 'T':
        mult = 1e12;
        break;
      default:
        break;
    }
    if (mult != 1.0) s.pop_back();
  }
  double v = 0.0;
  const auto bad = [&](const char* why) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s '%s' %s (examples: 1000000, 50k, 2M, 1e8)", what, text, why));
  };
  if (s.empty() || !absl::SimpleAtod(s, &v) || !std::isfinite(v)) return bad("is not a count");
  const double n = v * mult;
  if (n < 0) return bad("is negative");
  // Above 2^62 the double has no exact integers left to tell apart, and int64 is near.
  if (n > 4.6e18) return bad("is too large");
  if (n != std::floor(n)) return bad("is not a whole number");
  return static_cast<int64_t>(n);
}

CLI::Validator CountValidator(int64_t lo, int64_t hi) {
  return CLI::Validator(
      [lo, hi](std::string& s) -> std::string {
        auto r = ParseCount(s);
        if (!r.ok()) return std::string(r.status().message());
        if (*r < lo || *r > hi) return absl::StrFormat("%s is outside [%d, %d]", s, lo, hi);
        s = absl::StrFormat("%d", *r);  // as a transform: "50k" reaches an integer option as 50000
        return std::string();
      },
      "COUNT");
}

int ResolveThreads(int threads) {
  if (threads > 0) return threads;
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

std::string NowIso8601() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  localtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S%z", &tm);
  return buf;
}

}  // namespace pbgi::tools
