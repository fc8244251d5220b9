// The shading driver (gather + raster on several threads) and the image writers of tools/.
#include "tools/shading.h"

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "ImfRgbaFile.h"
#include "gtest/gtest.h"
#include "pbgi/testing.h"
#include "tools/chart.h"
#include "tools/image_io.h"

#define STB_IMAGE_IMPLEMENTATION
#include "stb/stb_image.h"

namespace pbgi::tools {
namespace {

std::string TempDir(const std::string& name) {
  const char* base = std::getenv("PBGI_TEST_TMPDIR");
  std::string dir = std::string(base ? base : "/tmp") + "/tools_" + name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

class ShadingTest : public ::testing::Test {
 protected:
  void SetUp() override {
    surfels_ = pbgi::testing::RandomSceneSurfels(20000, 7);
    auto db = pbgi::testing::TempDatabase::Create(surfels_);
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = std::move(db).value();
    receivers_ = pbgi::testing::RandomReceivers(600, 11);
  }
  std::vector<Surfel> surfels_;
  std::unique_ptr<pbgi::testing::TempDatabase> db_;
  std::vector<Receiver> receivers_;
};

// Each receiver's result depends only on that receiver: not on the thread that shaded it, nor on
// the order in which receivers were visited.
TEST_F(ShadingTest, ThreadsAndOrderDoNotChangeResults) {
  ShadeJobOptions one;
  one.threads = 1;
  one.z_order = false;
  std::vector<ShadeResult> a, b;
  ShadeJobStats sa, sb;
  ASSERT_TRUE(ShadeReceivers(db_->db(), receivers_, {}, one, &a, &sa).ok());
  ShadeJobOptions two = one;
  two.threads = 2;
  two.z_order = true;
  ASSERT_TRUE(ShadeReceivers(db_->db(), receivers_, {}, two, &b, &sb).ok());
  ASSERT_EQ(a.size(), receivers_.size());
  ASSERT_EQ(b.size(), receivers_.size());
  int open = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].occlusion, b[i].occlusion) << i;
    EXPECT_EQ(a[i].irradiance, b[i].irradiance) << i;
    EXPECT_GE(a[i].occlusion, 0.0f);
    EXPECT_LE(a[i].occlusion, 1.0f);
    if (a[i].occlusion < 1.0f) ++open;
  }
  EXPECT_GT(open, 0);
  EXPECT_EQ(sa.receivers, receivers_.size());
  EXPECT_EQ(sa.query.clusters + sa.query.surfels, sb.query.clusters + sb.query.surfels);
  EXPECT_GT(sa.query.nodes_visited, 0u);
}

TEST_F(ShadingTest, RejectsBadReceiversByIndex) {
  std::vector<Receiver> bad = receivers_;
  bad[17].normal = glm::vec3(0.0f);
  std::vector<ShadeResult> out;
  absl::Status s = ShadeReceivers(db_->db(), bad, {}, ShadeJobOptions{}, &out, nullptr);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("receiver 17"), absl::string_view::npos) << s;
  bad[17].normal = glm::vec3(0, 0, 1);
  bad[3].position.x = std::numeric_limits<float>::quiet_NaN();
  s = ShadeReceivers(db_->db(), bad, {}, ShadeJobOptions{}, &out, nullptr);
  EXPECT_NE(s.message().find("receiver 3"), absl::string_view::npos) << s;
  std::vector<glm::vec3> wrong(5);
  s = ShadeReceivers(db_->db(), receivers_, wrong, ShadeJobOptions{}, &out, nullptr);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
}

TEST(ImageIoTest, ExrRoundTripAndPngDecodes) {
  const std::string dir = TempDir("image");
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
  const std::string dir = TempDir("chart");
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
