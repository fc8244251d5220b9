// Log-log charts written as PNG through PLplot (Debian's libplplot, the cairo driver): run time
// against error for `pbgi eval`. PLplot draws the axes with their decades labelled (10^-3), the
// titles, the legend and anti-aliased text; a chart reads without the JSON beside it.
//
// Thread safety: PLplot keeps global state; charts are written from one thread at a time.
#ifndef PBGI_TOOLS_CHART_H_
#define PBGI_TOOLS_CHART_H_

#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "glm/vec3.hpp"

namespace pbgi::tools {

struct ChartSeries {
  std::string name;  // the legend's text
  glm::vec3 color{1.0f};
  bool connect = false;      // draw lines between consecutive points
  std::vector<double> x, y;  // both > 0 (log axes)
  // Optional, parallel to x: a short label written beside each point (e.g. "64 rays").
  std::vector<std::string> labels;
};

struct ChartPoint {
  double x = 0, y = 0;
  std::string label;
};

struct ChartOptions {
  std::string title;
  std::string x_label;  // e.g. "mean absolute error (log scale)"
  std::string y_label;
  std::string legend_title;             // a line below the legend's entries
  std::optional<ChartPoint> highlight;  // ringed and labelled (the default setting)
  int width = 1000;
  int height = 640;
};

// Both axes logarithmic, from the data's decades. Errors: no positive data, or PLplot's cairo
// driver missing. Written through a temporary file and renamed (tools/outputs.h).
absl::Status WriteLogLogChart(const std::string& path, const std::vector<ChartSeries>& series,
                              const ChartOptions& options = {});

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_CHART_H_
