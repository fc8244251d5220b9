// The image writers and the chart of tools/.
#include "tools/image_io.h"

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

TEST(ChartTest, WritesAPictureWithTheSeriesColours) {
  const testing_common::ScratchDir scratch;
  const std::string dir = scratch.path().string();
  ChartSeries s{"a", glm::vec3(1.0f, 0.0f, 0.0f), true, {0.01, 0.1}, {1e-5, 1e-3}};
  ASSERT_TRUE(WriteLogLogChart(dir + "/c.png", {s}, 200, 120).ok());
  int w = 0, h = 0, c = 0;
  unsigned char* data = stbi_load((dir + "/c.png").c_str(), &w, &h, &c, 3);
  ASSERT_NE(data, nullptr);
  int red = 0;
  for (int i = 0; i < w * h; ++i) red += data[i * 3] == 255 && data[i * 3 + 1] == 0;
  EXPECT_GT(red, 20);  // the legend box, two markers and a line
  stbi_image_free(data);
  EXPECT_FALSE(WriteLogLogChart(dir + "/d.png", {ChartSeries{}}).ok());
}

}  // namespace
}  // namespace pbgi::tools
