// Writing images: HDR OpenEXR and tone-mapped 8-bit PNG (stb_image_write).
#ifndef PBGI_TOOLS_IMAGE_IO_H_
#define PBGI_TOOLS_IMAGE_IO_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "glm/vec3.hpp"

namespace pbgi::tools {

// A linear RGB image, row-major from the top-left.
struct Image {
  int width = 0;
  int height = 0;
  std::vector<glm::vec3> pixels;

  Image() = default;
  Image(int w, int h) : width(w), height(h), pixels(size_t(w) * size_t(h), glm::vec3(0.0f)) {}
  glm::vec3& at(int x, int y) { return pixels[size_t(y) * size_t(width) + size_t(x)]; }
};

// Linear half-float RGB OpenEXR.
absl::Status WriteExr(const std::string& path, const Image& image);
// sRGB 8-bit PNG after multiplying by `exposure` and a Reinhard-style tone curve when
// `tonemap` (else clamped).
absl::Status WritePng(const std::string& path, const Image& image, float exposure = 1.0f,
                      bool tonemap = true);
// Writes by extension: .exr or .png.
absl::Status WriteImage(const std::string& path, const Image& image, float exposure = 1.0f);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_IMAGE_IO_H_
