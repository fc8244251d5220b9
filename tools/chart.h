// A small log-log scatter chart written as a PNG: run time against error for `pbgi eval`.
#ifndef PBGI_TOOLS_CHART_H_
#define PBGI_TOOLS_CHART_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "glm/vec3.hpp"

namespace pbgi::tools {

struct ChartSeries {
  std::string name;
  glm::vec3 color{1.0f};
  bool connect = false;      // draw lines between consecutive points
  std::vector<double> x, y;  // both > 0 (log axes)
};

// x: error (log), y: seconds per receiver (log). Axes at decades, labelled with the exponent
// (10^k); the legend is one coloured box per series in series order.
absl::Status WriteLogLogChart(const std::string& path, const std::vector<ChartSeries>& series,
                              int width = 800, int height = 500);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_CHART_H_
