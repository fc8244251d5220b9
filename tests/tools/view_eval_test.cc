// The image metrics of `pbgi eval --view` (tools/view_eval.h) on images with known answers.
#include "tools/view_eval.h"

#include <cmath>
#include <vector>

#include "gtest/gtest.h"

namespace pbgi::tools {
namespace {

TEST(CompareImagesTest, MeanTailAndBiasOfAKnownError) {
  // 16 x 16 image, reference 0.5 everywhere; got = reference + 0.01 * (p % 100) / 99 * sign.
  const int w = 16, h = 16;
  std::vector<double> ref(w * h, 0.5), got(w * h);
  std::vector<uint8_t> covered(w * h, 1);
  double mae = 0, bias = 0, rmse = 0;
  for (int p = 0; p < w * h; ++p) {
    const double e = (p % 2 ? 1.0 : -0.5) * 0.01 * double(p) / double(w * h - 1);
    got[p] = ref[p] + e;
    mae += std::abs(e), bias += e, rmse += e * e;
  }
  const ImageErrors e = CompareImages(w, h, got, ref, covered);
  EXPECT_EQ(e.pixels, 256u);
  EXPECT_NEAR(e.mae, mae / 256, 1e-12);
  EXPECT_NEAR(e.bias, bias / 256, 1e-12);
  EXPECT_NEAR(e.rmse, std::sqrt(rmse / 256), 1e-12);
  EXPECT_NEAR(e.max, 0.01, 1e-12);
  EXPECT_NEAR(e.reference_mean, 0.5, 1e-12);
  // |error| is 0.01 * p / 255 for odd p and half that for even p: the 99th percentile (rank 253
  // of 256 sorted values) is the third largest value, pixel 251's 0.01 * 251 / 255.
  EXPECT_NEAR(e.p99, 0.01 * 251.0 / 255.0, 1e-12);
}

TEST(CompareImagesTest, WorstTileFindsABlockTheMeanHides) {
  const int w = 64, h = 32;
  std::vector<double> ref(w * h, 0.2), got = ref;
  std::vector<uint8_t> covered(w * h, 1);
  // One 8 x 8 block (tile (40, 16)) off by 0.2, the rest exact: the image MAE is 0.2 / 32.
  for (int y = 16; y < 24; ++y)
    for (int x = 40; x < 48; ++x) got[y * w + x] += 0.2;
  const ImageErrors e = CompareImages(w, h, got, ref, covered);
  EXPECT_NEAR(e.mae, 0.2 / 32.0, 1e-12);
  EXPECT_NEAR(e.worst_tile, 0.2, 1e-12);
  EXPECT_EQ(e.worst_tile_x, 40);
  EXPECT_EQ(e.worst_tile_y, 16);
}

TEST(CompareImagesTest, UncoveredPixelsAndSparseTilesDoNotCount) {
  const int w = 16, h = 8;
  std::vector<double> ref(w * h, 0.0), got(w * h, 0.0);
  std::vector<uint8_t> covered(w * h, 0);
  // Left tile fully covered with error 0.1; right tile: one covered pixel with error 0.9 (a tile
  // less than a quarter covered is left out of the worst tile, not of the mean).
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) covered[y * w + x] = 1, got[y * w + x] = 0.1;
  covered[3 * w + 12] = 1, got[3 * w + 12] = 0.9;
  got[5 * w + 13] = 5.0;  // not covered: ignored
  const ImageErrors e = CompareImages(w, h, got, ref, covered);
  EXPECT_EQ(e.pixels, 65u);
  EXPECT_NEAR(e.mae, (64 * 0.1 + 0.9) / 65, 1e-12);
  EXPECT_NEAR(e.max, 0.9, 1e-12);
  EXPECT_NEAR(e.worst_tile, 0.1, 1e-12);
  EXPECT_EQ(e.worst_tile_x, 0);
}

TEST(ErrorHeatMapTest, SignedColoursSaturateAtTheScale) {
  const int w = 4, h = 1;
  std::vector<double> ref = {0.5, 0.5, 0.5, 0.5}, got = {0.5, 0.55, 0.3, 0.9};
  std::vector<uint8_t> covered = {1, 1, 1, 0};
  const Image img = ErrorHeatMap(w, h, got, ref, covered, 0.1);
  EXPECT_EQ(img.pixels[0], glm::vec3(1.0f));                     // exact: white
  EXPECT_NEAR(img.pixels[1].x, 1.0f, 1e-6f);                     // too high: red
  EXPECT_NEAR(img.pixels[1].y, 0.5f, 1e-6f);                     // half way to the scale
  EXPECT_EQ(img.pixels[2], glm::vec3(0.0f, 0.0f, 1.0f));         // too low, saturated: blue
  EXPECT_EQ(img.pixels[3], glm::vec3(0.35f));                    // not covered: grey
}

}  // namespace
}  // namespace pbgi::tools
