#include "tools/args.h"

#include <cctype>
#include <cmath>
#include <ctime>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "tools/command.h"

namespace pbgi::tools {
namespace {

// The power of a unit suffix, k 1, m 2, g 3, t 4 in either case (ParseCount counts in 1000s,
// ParseBytes in 1024s); 0 for anything else.
int SuffixPower(char c) {
  switch (std::tolower(static_cast<unsigned char>(c))) {
    case 'k':
      return 1;
    case 'm':
      return 2;
    case 'g':
      return 3;
    case 't':
      return 4;
    default:
      return 0;
  }
}

}  // namespace

absl::StatusOr<int64_t> ParseCount(const std::string& text, const std::string& what) {
  std::string s = text;
  double mult = 1.0;
  if (const int p = s.empty() ? 0 : SuffixPower(s.back()); p > 0) {
    constexpr double kDecimal[] = {1.0, 1e3, 1e6, 1e9, 1e12};
    mult = kDecimal[p];
    s.pop_back();
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

absl::StatusOr<uint64_t> ParseBytes(const std::string& text) {
  std::string s = text;
  while (!s.empty() && (s.back() == 'B' || s.back() == 'b' || s.back() == 'i')) s.pop_back();
  double mult = 1;
  if (const int p = s.empty() ? 0 : SuffixPower(s.back()); p > 0) {
    constexpr double kBinary[] = {1.0, 1024.0, 1024.0 * 1024, 1024.0 * 1024 * 1024,
                                  1024.0 * 1024 * 1024 * 1024};
    mult = kBinary[p];
    s.pop_back();
  }
  double v = 0;
  if (s.empty() || !absl::SimpleAtod(s, &v) || !(v >= 0) || !std::isfinite(v)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("'%s' is not a size (examples: 4096, 512M, 1G)", text));
  }
  // 2^64 and more do not fit (the conversion would be undefined, and came out as 0).
  if (v * mult >= 18446744073709551616.0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("'%s' is too large a size (at most 16 EiB)", text));
  }
  return static_cast<uint64_t>(v * mult);
}

CLI::Validator BytesValidator() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        if (s == "auto") return std::string();  // budgets: see tools/budget.h
        auto r = ParseBytes(s);
        return r.ok() ? std::string() : std::string(r.status().message());
      },
      "SIZE");
}

absl::StatusOr<uint64_t> ParseBudget(const std::string& text, const std::string& what) {
  if (!text.empty() && std::isdigit(static_cast<unsigned char>(text.back()))) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s %s has no unit: give one (%sM, %sG; %sB if you mean bytes)", what, text,
                        text, text, text));
  }
  return ParseBytes(text);
}

CLI::Validator BudgetValidator() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        if (s == "auto") return std::string();  // budgets: see tools/budget.h
        auto r = ParseBudget(s, "the budget");
        return r.ok() ? std::string() : std::string(r.status().message());
      },
      "SIZE");
}

std::string FormatBytes(uint64_t bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  double v = static_cast<double>(bytes);
  int u = 0;
  while (v >= 1024.0 && u < 4) {
    v /= 1024.0;
    ++u;
  }
  return u == 0 ? absl::StrFormat("%d B", bytes) : absl::StrFormat("%.1f %s", v, units[u]);
}

}  // namespace pbgi::tools
