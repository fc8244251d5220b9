#include "tools/chart.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "tools/image_io.h"

namespace pbgi::tools {
namespace {

// 3x5 bitmap glyphs for "0123456789-" (one row per 3 bits, top first).
const uint16_t kGlyphs[11] = {0x7B6F, 0x2C97, 0x73E7, 0x72CF, 0x5BC9, 0x79CF,
                              0x79EF, 0x7249, 0x7BEF, 0x7BCF, 0x01C0};

void Plot(Image* img, int x, int y, const glm::vec3& c) {
  if (x >= 0 && y >= 0 && x < img->width && y < img->height) img->at(x, y) = c;
}

void Line(Image* img, int x0, int y0, int x1, int y1, const glm::vec3& c) {
  const int n = std::max(std::abs(x1 - x0), std::abs(y1 - y0));
  for (int i = 0; i <= n; ++i) {
    const double t = n == 0 ? 0.0 : double(i) / n;
    Plot(img, int(std::lround(x0 + t * (x1 - x0))), int(std::lround(y0 + t * (y1 - y0))), c);
  }
}

void Text(Image* img, int x, int y, const std::string& s, const glm::vec3& c, int scale = 2) {
  for (char ch : s) {
    int g = ch == '-' ? 10 : (ch >= '0' && ch <= '9' ? ch - '0' : -1);
    if (g >= 0) {
      for (int row = 0; row < 5; ++row) {
        for (int col = 0; col < 3; ++col) {
          if ((kGlyphs[g] >> ((4 - row) * 3 + (2 - col))) & 1) {
            for (int a = 0; a < scale; ++a)
              for (int b = 0; b < scale; ++b)
                Plot(img, x + col * scale + a, y + row * scale + b, c);
          }
        }
      }
    }
    x += 4 * scale;
  }
}

}  // namespace

absl::Status WriteLogLogChart(const std::string& path, const std::vector<ChartSeries>& series,
                              int width, int height) {
  double xmin = std::numeric_limits<double>::max(), xmax = 0, ymin = xmin, ymax = 0;
  for (const ChartSeries& s : series) {
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!(s.x[i] > 0) || !(s.y[i] > 0)) continue;
      xmin = std::min(xmin, s.x[i]), xmax = std::max(xmax, s.x[i]);
      ymin = std::min(ymin, s.y[i]), ymax = std::max(ymax, s.y[i]);
    }
  }
  if (xmax == 0) return absl::InvalidArgumentError("chart: no positive data");
  const double lx0 = std::floor(std::log10(xmin)), lx1 = std::ceil(std::log10(xmax) + 1e-9);
  const double ly0 = std::floor(std::log10(ymin)), ly1 = std::ceil(std::log10(ymax) + 1e-9);
  Image img(width, height);
  for (auto& p : img.pixels) p = glm::vec3(1.0f);
  const int left = 60, right = width - 20, top = 40, bottom = height - 40;
  auto X = [&](double v) {
    return int(left + (std::log10(v) - lx0) / std::max(1.0, lx1 - lx0) * (right - left));
  };
  auto Y = [&](double v) {
    return int(bottom - (std::log10(v) - ly0) / std::max(1.0, ly1 - ly0) * (bottom - top));
  };
  const glm::vec3 grid(0.85f), axis(0.2f);
  for (double e = lx0; e <= std::max(lx1, lx0 + 1); e += 1) {
    const int x = X(std::pow(10.0, e));
    Line(&img, x, top, x, bottom, grid);
    Text(&img, x - 8, bottom + 8, std::to_string(int(e)), axis);
  }
  for (double e = ly0; e <= std::max(ly1, ly0 + 1); e += 1) {
    const int y = Y(std::pow(10.0, e));
    Line(&img, left, y, right, y, grid);
    Text(&img, 8, y - 5, std::to_string(int(e)), axis);
  }
  Line(&img, left, bottom, right, bottom, axis);
  Line(&img, left, top, left, bottom, axis);
  int legend_x = left + 10;
  for (const ChartSeries& s : series) {
    for (int a = 0; a < 14; ++a)
      for (int b = 0; b < 14; ++b) Plot(&img, legend_x + a, 12 + b, s.color);
    legend_x += 30;
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!(s.x[i] > 0) || !(s.y[i] > 0)) continue;
      const int x = X(s.x[i]), y = Y(s.y[i]);
      for (int a = -3; a <= 3; ++a)
        for (int b = -3; b <= 3; ++b)
          if (a * a + b * b <= 10) Plot(&img, x + a, y + b, s.color);
      if (s.connect && i > 0 && s.x[i - 1] > 0 && s.y[i - 1] > 0) {
        Line(&img, X(s.x[i - 1]), Y(s.y[i - 1]), x, y, s.color);
      }
    }
  }
  return WritePng(path, img, 1.0f, false);
}

}  // namespace pbgi::tools
