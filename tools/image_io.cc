#include "tools/image_io.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>

#include "ImfRgbaFile.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "tools/outputs.h"

#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STBI_WRITE_NO_STDIO_OVERRIDE
#include "stb/stb_image_write.h"

namespace pbgi::tools {
namespace {

uint8_t ToSrgb8(float v) {
  v = std::clamp(v, 0.0f, 1.0f);
  const float s = v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
  return static_cast<uint8_t>(std::lround(s * 255.0f));
}
// (ToneMap8 in pbgi/ply.h is the same curve for the PLY writers' colours.)

}  // namespace

absl::Status WriteExr(const std::string& path, const Image& image) {
  // Written under a temporary name and renamed when complete (tools/outputs.h).
  OutputFile out(path);
  // OpenEXR reports errors with exceptions: they stop here, at the library boundary.
  try {
    std::vector<Imf::Rgba> px(image.pixels.size());
    for (size_t i = 0; i < px.size(); ++i) {
      const glm::vec3& c = image.pixels[i];
      px[i] = Imf::Rgba(c.x, c.y, c.z, 1.0f);
    }
    {
      Imf::RgbaOutputFile file(out.tmp_path().c_str(), image.width, image.height, Imf::WRITE_RGBA);
      file.setFrameBuffer(px.data(), 1, size_t(image.width));
      file.writePixels(image.height);
    }  // the file is complete when it closes
  } catch (const std::exception& e) {
    return absl::UnavailableError(absl::StrFormat("cannot write %s: %s", path, e.what()));
  }
  return out.Commit();
}

absl::Status WritePng(const std::string& path, const Image& image, float exposure, bool tonemap) {
  std::vector<uint8_t> rgb(image.pixels.size() * 3);
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    for (int c = 0; c < 3; ++c) {
      float v = image.pixels[i][c] * exposure;
      if (!std::isfinite(v)) v = 0.0f;
      if (tonemap) v = v / (1.0f + v);
      rgb[i * 3 + c] = ToSrgb8(v);
    }
  }
  OutputFile out(path);
  if (stbi_write_png(out.tmp_path().c_str(), image.width, image.height, 3, rgb.data(),
                     image.width * 3) == 0) {
    return absl::UnavailableError(absl::StrFormat("cannot write %s", path));
  }
  return out.Commit();
}

absl::Status WriteImage(const std::string& path, const Image& image, float exposure) {
  if (absl::EndsWith(path, ".exr")) return WriteExr(path, image);
  if (absl::EndsWith(path, ".png")) return WritePng(path, image, exposure);
  return absl::InvalidArgumentError(
      absl::StrFormat("%s: unknown image type (use .exr or .png)", path));
}

}  // namespace pbgi::tools
