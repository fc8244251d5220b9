#include "tools/chart.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <mutex>

#include "absl/strings/str_format.h"
#include "plplot.h"
#include "tools/outputs.h"

namespace pbgi::tools {
namespace {

bool HasDevice(const char* name) {
  // plgDevs fills arrays the caller owns; n is their size on input, the device count on output.
  std::vector<const char*> menu(256), devs(256);
  const char** menu_p = menu.data();
  const char** devs_p = devs.data();
  PLINT n = static_cast<PLINT>(devs.size());
  plgDevs(&menu_p, &devs_p, &n);
  for (PLINT i = 0; i < n && i < static_cast<PLINT>(devs.size()); ++i) {
    if (devs_p[i] != nullptr && std::strcmp(devs_p[i], name) == 0) return true;
  }
  return false;
}

PLINT Channel(float v) { return static_cast<PLINT>(std::lround(std::clamp(v, 0.0f, 1.0f) * 255)); }

}  // namespace

absl::Status WriteLogLogChart(const std::string& path, const std::vector<ChartSeries>& series,
                              const ChartOptions& options) {
  static std::mutex mu;  // PLplot's state is global
  std::lock_guard<std::mutex> lock(mu);
  double xmin = std::numeric_limits<double>::max(), xmax = 0, ymin = xmin, ymax = 0;
  for (const ChartSeries& s : series) {
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!(s.x[i] > 0) || !(s.y[i] > 0)) continue;
      xmin = std::min(xmin, s.x[i]), xmax = std::max(xmax, s.x[i]);
      ymin = std::min(ymin, s.y[i]), ymax = std::max(ymax, s.y[i]);
    }
  }
  if (xmax == 0) return absl::InvalidArgumentError("chart: no positive data");
  if (!HasDevice("pngcairo")) {
    return absl::FailedPreconditionError(
        "chart: PLplot has no pngcairo device (install plplot-driver-cairo)");
  }
  // Whole decades around the data, at least one.
  const double lx0 = std::floor(std::log10(xmin)),
               lx1 = std::max(lx0 + 1, std::ceil(std::log10(xmax)));
  const double ly0 = std::floor(std::log10(ymin)),
               ly1 = std::max(ly0 + 1, std::ceil(std::log10(ymax)));

  OutputFile out(path);
  // PLplot ends the process on a fatal error (its exit handler cannot return to us), and asks
  // on stdin for another name when it cannot open its file: both are checked here first.
  if (std::FILE* f = std::fopen(out.tmp_path().c_str(), "wb")) {
    std::fclose(f);
  } else {
    return absl::UnavailableError(
        absl::StrFormat("chart: cannot write %s: %s", out.tmp_path(), std::strerror(errno)));
  }
  plsdev("pngcairo");
  plsfnam(out.tmp_path().c_str());
  plspage(0, 0, options.width, options.height, 0, 0);
  plscolbg(255, 255, 255);
  plscol0(1, 0, 0, 0);  // pen 1: black axes and text
  plinit();
  pladv(0);
  plvpor(0.09, 0.60, 0.12, 0.88);  // the legend sits to the right of the plot
  plwind(lx0, lx1, ly0, ly1);
  plcol0(1);
  plschr(0, 0.9);
  // Grid (g), log labels 10^n (l), ticks (ts), numbers (n), vertical y numbers (v).
  plscol0(15, 215, 215, 215);
  plcol0(15);
  plbox("g", 1, 0, "g", 1, 0);
  plcol0(1);
  plbox("bclnst", 1, 0, "bclnstv", 1, 0);
  pllab(options.x_label.c_str(), options.y_label.c_str(), "");
  plschr(0, 1.1);
  plmtex("t", 1.5, 0.0, 0.0, options.title.c_str());
  plschr(0, 0.9);

  std::vector<PLINT> opts, colors, symbol_colors, line_styles;
  std::vector<PLFLT> widths, scales;
  std::vector<PLINT> numbers;
  std::vector<const char*> texts, symbols;
  const char* kSymbols[] = {"#(728)", "#(727)", "#(841)", "#(843)", "#(851)", "#(852)"};
  int pen = 2;
  for (size_t k = 0; k < series.size(); ++k) {
    const ChartSeries& s = series[k];
    plscol0(pen, Channel(s.color.x), Channel(s.color.y), Channel(s.color.z));
    plcol0(pen);
    std::vector<PLFLT> lx, ly;
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (s.x[i] > 0 && s.y[i] > 0)
        lx.push_back(std::log10(s.x[i])), ly.push_back(std::log10(s.y[i]));
    }
    const char* symbol = kSymbols[k % 6];
    if (s.connect && lx.size() > 1) {
      plwidth(2);
      plline(static_cast<PLINT>(lx.size()), lx.data(), ly.data());
      plwidth(1);
    }
    plschr(0, 1.3);
    plstring(static_cast<PLINT>(lx.size()), lx.data(), ly.data(), symbol);
    plschr(0, 0.75);
    for (size_t i = 0, j = 0; i < s.x.size() && i < s.labels.size(); ++i) {
      if (!(s.x[i] > 0 && s.y[i] > 0)) continue;
      plptex(std::log10(s.x[i]) + 0.02 * (lx1 - lx0), std::log10(s.y[i]), 1, 0, 0,
             s.labels[i].c_str());
      ++j;
    }
    plschr(0, 0.9);
    opts.push_back(PL_LEGEND_LINE | PL_LEGEND_SYMBOL);
    colors.push_back(pen);
    symbol_colors.push_back(pen);
    line_styles.push_back(1);
    widths.push_back(s.connect ? 2 : 0);
    scales.push_back(1.3);
    numbers.push_back(1);
    texts.push_back(s.name.c_str());
    symbols.push_back(symbol);
    ++pen;
  }
  if (options.highlight && options.highlight->x > 0 && options.highlight->y > 0) {
    const ChartPoint& h = *options.highlight;
    PLFLT x = std::log10(h.x), y = std::log10(h.y);
    plcol0(1);
    plschr(0, 2.6);
    plstring(1, &x, &y, "#(840)");  // a large ring around the point
    plschr(0, 0.85);
    plptex(x + 0.03 * (lx1 - lx0), y - 0.05 * (ly1 - ly0), 1, 0, 0, h.label.c_str());
    opts.push_back(PL_LEGEND_SYMBOL);
    colors.push_back(1);
    symbol_colors.push_back(1);
    line_styles.push_back(1);
    widths.push_back(0);
    scales.push_back(1.8);
    numbers.push_back(1);
    texts.push_back(h.label.c_str());
    symbols.push_back("#(840)");
  }
  if (!options.legend_title.empty()) {  // a line of text only, below the entries
    opts.push_back(PL_LEGEND_NONE);
    colors.push_back(1);
    symbol_colors.push_back(1);
    line_styles.push_back(1);
    widths.push_back(0);
    scales.push_back(1);
    numbers.push_back(0);
    texts.push_back(options.legend_title.c_str());
    symbols.push_back("");
  }
  std::vector<PLINT> text_colors(colors.size(), 1), box_colors(colors.size(), 0),
      box_patterns(colors.size(), 0);
  std::vector<PLFLT> box_scales(colors.size(), 1.0), box_widths(colors.size(), 1.0);
  PLFLT legend_w = 0, legend_h = 0;
  plschr(0, 0.8);
  pllegend(&legend_w, &legend_h, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
           PL_POSITION_RIGHT | PL_POSITION_OUTSIDE | PL_POSITION_VIEWPORT, 0.02, 0.0, 0.05, 0, 1, 1,
           0, 0, static_cast<PLINT>(opts.size()), opts.data(), 0.6, 0.75, 2.0, 0.0,
           text_colors.data(), texts.data(), box_colors.data(), box_patterns.data(),
           box_scales.data(), box_widths.data(), colors.data(), line_styles.data(), widths.data(),
           symbol_colors.data(), scales.data(), numbers.data(), symbols.data());
  plend();
  return out.Commit();
}

}  // namespace pbgi::tools
