#include "tools/reference_stats.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace pbgi::tools {

double HalvesMae(absl::Span<const double> a, absl::Span<const double> b) {
  const size_t n = std::min(a.size(), b.size());
  if (n == 0) return 0.0;
  double sum = 0.0;
  for (size_t i = 0; i < n; ++i) sum += std::fabs(a[i] - b[i]);
  return 0.5 * sum / static_cast<double>(n);
}

double ReferenceSecondsAt(absl::Span<const SweepPoint> sweep, double mae, SweepReading* reading) {
  SweepReading r;
  struct Point {
    double x, y, log_rays;  // log MAE, log seconds, log rays
    bool operator<(const Point& o) const { return x < o.x; }
  };
  std::vector<Point> curve;  // by MAE
  for (const SweepPoint& p : sweep) {
    if (p.rays > 0 && p.mae > 0.0 && p.seconds > 0.0) {
      curve.push_back({std::log(p.mae), std::log(p.seconds), std::log(double(p.rays))});
    }
  }
  double out = 0.0;
  if (!curve.empty() && mae > 0.0) {
    std::sort(curve.begin(), curve.end());
    const double x = std::log(mae);
    if (x < curve.front().x) {
      r.extrapolated = r.below = true;
      r.exponent = 2.0;
      // p = -d log(MAE) / d log(rays) over the last segment, k = 1 / p.
      if (curve.size() >= 2 && curve[1].x > curve[0].x && curve[0].log_rays > curve[1].log_rays) {
        const double p = (curve[1].x - curve[0].x) / (curve[0].log_rays - curve[1].log_rays);
        r.exponent = std::clamp(1.0 / p, 1.0, 2.0);
        r.from_sweep = true;
      }
      out = std::exp(curve.front().y - r.exponent * (x - curve.front().x));
    } else if (x > curve.back().x) {
      r.extrapolated = true;
      r.exponent = 2.0;
      out = std::exp(curve.back().y - 2.0 * (x - curve.back().x));
    } else {
      out = std::exp(curve.back().y);
      for (size_t i = 1; i < curve.size(); ++i) {
        if (x <= curve[i].x) {
          const Point& a = curve[i - 1];
          const Point& b = curve[i];
          const double f = b.x > a.x ? (x - a.x) / (b.x - a.x) : 0.0;
          out = std::exp(a.y + f * (b.y - a.y));
          break;
        }
      }
    }
  }
  if (reading != nullptr) *reading = r;
  return out;
}

}  // namespace pbgi::tools
