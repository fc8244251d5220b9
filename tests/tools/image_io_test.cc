// The image writers and the chart of tools/.
#include "tools/image_io.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "ImfRgbaFile.h"
#include "gtest/gtest.h"
#include "tests/common/scratch_dir.h"
#include "tools/chart.h"

#define STB_IMAGE_IMPLEMENTATION
#include "stb/stb_image.h"

namespace pbgi::tools {
namespace {

TEST(ImageIoTest, ExrRoundTripAndPngDecodes) {
  const testing_common::ScratchDir scratch;
  const std::string dir = scratch.path().string();
  Image img(7, 5);
  for (int y = 0; y < 5; ++y)
    for (int x = 0; x < 7; ++x) img.at(x, y) = glm::vec3(0.25f * x, 0.5f * y, 4.0f);
  ASSERT_TRUE(WriteImage(dir + "/a.exr", img).ok());
  ASSERT_TRUE(WriteImage(dir + "/a.png", img).ok());
  EXPECT_FALSE(WriteImage(dir + "/a.tiff", img).ok());
  EXPECT_FALSE(WriteImage(dir + "/no/such/dir/a.png", img).ok());
  EXPECT_FALSE(WriteExr(dir + "/no/such/dir/a.exr", img).ok());

  Imf::RgbaInputFile in((dir + "/a.exr").c_str());
  const Imath::Box2i dw = in.dataWindow();
  ASSERT_EQ(dw.max.x - dw.min.x + 1, 7);
  ASSERT_EQ(dw.max.y - dw.min.y + 1, 5);
  std::vector<Imf::Rgba> px(35);
  in.setFrameBuffer(px.data(), 1, 7);
  in.readPixels(dw.min.y, dw.max.y);
  for (int y = 0; y < 5; ++y) {
    for (int x = 0; x < 7; ++x) {
      EXPECT_NEAR(float(px[y * 7 + x].r), 0.25f * x, 1e-3f);
      EXPECT_NEAR(float(px[y * 7 + x].g), 0.5f * y, 1e-3f);
      EXPECT_NEAR(float(px[y * 7 + x].b), 4.0f, 1e-3f);
    }
  }
  int w = 0, h = 0, c = 0;
  unsigned char* data = stbi_load((dir + "/a.png").c_str(), &w, &h, &c, 3);
  ASSERT_NE(data, nullptr);
  EXPECT_EQ(w, 7);
  EXPECT_EQ(h, 5);
  EXPECT_EQ(data[0], 0);  // black stays black
  // Monotonic in the input along a row.
  for (int x = 1; x < 7; ++x) EXPECT_GT(data[x * 3], data[(x - 1) * 3]);
  stbi_image_free(data);
}

// Counts the pixels of `data` (w x h, RGB) inside columns [x0, x1) that satisfy `pred`.
template <typename Pred>
int CountPixels(const unsigned char* data, int w, int h, int x0, int x1, Pred pred) {
  int n = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = std::max(0, x0); x < std::min(w, x1); ++x) {
      const unsigned char* p = data + (y * w + x) * 3;
      n += pred(p[0], p[1], p[2]);
    }
  }
  return n;
}

TEST(ChartTest, DrawsTheSeriesInThePlotAndTheLegendAndLabelsTheAxes) {
  const testing_common::ScratchDir scratch;
  const std::string dir = scratch.path().string();
  ChartSeries s{"a", glm::vec3(1.0f, 0.0f, 0.0f), true, {0.01, 0.1}, {1e-5, 1e-3}, {"p", "q"}};
  ChartOptions o;
  o.width = 400;
  o.height = 260;
  o.title = "a title";
  o.x_label = "mean absolute error (log scale)";
  o.y_label = "seconds per receiver (log scale)";
  o.highlight = ChartPoint{0.01, 1e-5, "default"};
  ASSERT_TRUE(WriteLogLogChart(dir + "/c.png", {s}, o).ok()) << dir;
  ChartOptions bare;
  bare.width = 400;
  bare.height = 260;
  ASSERT_TRUE(WriteLogLogChart(dir + "/bare.png", {s}, bare).ok());
  // No temporary file is left beside the chart.
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 2);

  int w = 0, h = 0, c = 0;
  unsigned char* data = stbi_load((dir + "/c.png").c_str(), &w, &h, &c, 3);
  ASSERT_NE(data, nullptr);
  EXPECT_EQ(w, 400);
  EXPECT_EQ(h, 260);
  auto red = [](int r, int g, int b) { return r > 200 && g < 80 && b < 80; };
  auto dark = [](int r, int g, int b) { return r < 100 && g < 100 && b < 100; };
  // The plot spans [0.09, 0.60] of the width, the legend lies to its right.
  EXPECT_GT(CountPixels(data, w, h, int(0.09 * w), int(0.60 * w), red), 20);
  EXPECT_GT(CountPixels(data, w, h, int(0.64 * w), w, red), 3);
  EXPECT_GT(CountPixels(data, w, h, int(0.64 * w), w, dark), 20);  // the legend's text
  // The y axis title is drawn in the left margin, left of the decade numbers.
  const int left_labelled = CountPixels(data, w, h, 0, int(0.03 * w), dark);
  stbi_image_free(data);
  data = stbi_load((dir + "/bare.png").c_str(), &w, &h, &c, 3);
  ASSERT_NE(data, nullptr);
  const int left_bare = CountPixels(data, w, h, 0, int(0.03 * w), dark);
  stbi_image_free(data);
  EXPECT_GT(left_labelled, left_bare + 20);

  EXPECT_FALSE(WriteLogLogChart(dir + "/d.png", {ChartSeries{}}).ok());
  EXPECT_FALSE(std::filesystem::exists(dir + "/d.png"));
  EXPECT_FALSE(WriteLogLogChart(dir + "/no/such/dir/e.png", {s}, bare).ok());
}

}  // namespace
}  // namespace pbgi::tools
