// The micro-buffer's pixel tables: directions, exact solid angles and cosine weights.
#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "glm/geometric.hpp"
#include "pbgi/raster.h"
#include "raster/cube.h"
#include "raster/rasterizer.h"

namespace pbgi {
namespace internal {

double RectSolidAngle(double a0, double a1, double b0, double b1) {
  auto f = [](double x, double y) { return std::atan2(x * y, std::sqrt(1.0 + x * x + y * y)); };
  return f(a1, b1) - f(a0, b1) - f(a1, b0) + f(a0, b0);
}

double PolygonCosineWeight(const glm::dvec3* v, int n) {
  double sum = 0.0;
  for (int i = 0; i < n; ++i) {
    const glm::dvec3& a = v[i];
    const glm::dvec3& b = v[(i + 1) % n];
    const glm::dvec3 g = glm::cross(a, b);
    const double len = glm::length(g);
    if (len <= 0.0) continue;
    const double angle = std::atan2(len, glm::dot(a, b));
    sum += angle * g.z / len;
  }
  return 0.5 * std::fabs(sum);
}

bool FaceRange(const FaceAxes& face, const glm::vec3& d, float chord, int res, int* col0, int* col1,
               int* row0, int* row1, bool* contained) {
  const float zc = face.sign * d[face.k];
  const float zhi = std::min(1.0f, zc + chord);
  if (zhi <= 0.0f) return false;
  const float zlo = zc - chord;
  constexpr float kInf = std::numeric_limits<float>::infinity();
  // Bounds of u / z for u in [lo, hi] and z in (max(zlo, 0), zhi].
  auto range = [&](float lo, float hi, float* mn, float* mx) {
    *mn = lo >= 0.0f ? lo / zhi : (zlo > 0.0f ? lo / zlo : -kInf);
    *mx = hi <= 0.0f ? hi / zhi : (zlo > 0.0f ? hi / zlo : kInf);
  };
  float amin, amax, bmin, bmax;
  range(d[face.k1] - chord, d[face.k1] + chord, &amin, &amax);
  range(d[face.k2] - chord, d[face.k2] + chord, &bmin, &bmax);
  if (amin > 1.0f || amax < -1.0f || bmin > 1.0f || bmax < -1.0f) return false;
  if (contained != nullptr) {
    *contained = zlo > 0.0f && amin > -1.0f && amax < 1.0f && bmin > -1.0f && bmax < 1.0f;
  }
  const float half = 0.5f * static_cast<float>(res);
  auto to_pixel = [&](float x) {
    x = std::clamp(x, -1.0f, 1.0f);
    return std::clamp(static_cast<int>((x + 1.0f) * half), 0, res - 1);
  };
  *col0 = to_pixel(amin);
  *col1 = to_pixel(amax);
  *row0 = to_pixel(bmin);
  *row1 = to_pixel(bmax);
  return true;
}

DiskRange DiskFaceRange(const FaceAxes& face, const glm::vec3& c, const glm::vec3& e1,
                        const glm::vec3& e2, float r, int res, int* col0, int* col1, int* row0,
                        int* row1) {
  // Rim point p(phi) = c + r (cos phi e1 + sin phi e2); its depth along the face axis is
  // b0 + b1 cos phi + b2 sin phi.
  const double b0 = face.sign * c[face.k];
  const double b1 = face.sign * r * e1[face.k], b2 = face.sign * r * e2[face.k];
  const double amp = std::sqrt(b1 * b1 + b2 * b2);
  if (b0 + amp <= 0.0) return DiskRange::kNone;              // wholly behind the face plane
  if (b0 <= amp * (1.0 + 1e-6)) return DiskRange::kUnknown;  // the rim crosses it
  const double half = 0.5 * res;
  // Coordinate t = (a0 + a1 cos + a2 sin) / (b0 + b1 cos + b2 sin) is reachable iff
  // (a0 - t b0)^2 <= (a1 - t b1)^2 + (a2 - t b2)^2: t between the roots of a quadratic.
  auto range = [&](int j, int* lo, int* hi) {
    const double a0 = c[j], a1 = r * e1[j], a2 = r * e2[j];
    const double qa = b0 * b0 - b1 * b1 - b2 * b2;
    const double qb = a0 * b0 - a1 * b1 - a2 * b2;
    const double qc = a0 * a0 - a1 * a1 - a2 * a2;
    const double root = std::sqrt(std::max(0.0, qb * qb - qa * qc));
    const double tmin = (qb - root) / qa - 1e-6, tmax = (qb + root) / qa + 1e-6;
    if (tmax < -1.0 || tmin > 1.0) return false;
    *lo = std::clamp(static_cast<int>((std::max(tmin, -1.0) + 1.0) * half), 0, res - 1);
    *hi = std::clamp(static_cast<int>((std::min(tmax, 1.0) + 1.0) * half), 0, res - 1);
    return true;
  };
  if (!range(face.k1, col0, col1) || !range(face.k2, row0, row1)) return DiskRange::kNone;
  return DiskRange::kExact;
}

}  // namespace internal

absl::Status MicroBuffer::Prepare(int resolution) {
  if (resolution < 4 || resolution > 64) {
    return absl::InvalidArgumentError(
        absl::StrCat("MicroBuffer resolution ", resolution, " is outside [4, 64]"));
  }
  if (resolution == res_) return absl::OkStatus();
  res_ = resolution;
  max_width_ = 0.0f;
  const int n = pixel_count();
  dirs_.assign(n, internal::PixelDir{});
  omega_.assign(n, 0.0);
  omega_above_.assign(n, 0.0);
  cos_weight_.assign(n, 0.0);
  omega_f_.assign(n, 0.0f);
  inv_omega_f_.assign(n, 0.0f);
  hemisphere_.clear();
  hemi_weight_.clear();
  hemi_omega_.clear();
  hemi_slope_x_.clear();
  hemi_slope_y_.clear();
  pixels_.assign(n, internal::PixelState{});
  for (internal::PixelState& px : pixels_) px.depth = std::numeric_limits<float>::infinity();
  shut_.assign(n, std::numeric_limits<float>::quiet_NaN());
  fragments_.resize(n);
  for (auto* v : {&dir_x_, &dir_y_, &dir_z_, &half_width_}) v->assign(n, 0.0f);

  const double step = 2.0 / res_;
  for (int f = 0; f < 6; ++f) {
    const internal::FaceAxes face = internal::Face(f);
    for (int row = 0; row < res_; ++row) {
      for (int col = 0; col < res_; ++col) {
        const int p = (f * res_ + row) * res_ + col;
        const double a0 = -1.0 + col * step, a1 = a0 + step;
        const double b0 = -1.0 + row * step, b1 = b0 + step;
        auto point = [&](double a, double b) {
          glm::dvec3 v(0.0);
          v[face.k] = face.sign;
          v[face.k1] = a;
          v[face.k2] = b;
          return v;
        };
        const glm::dvec3 centre = glm::normalize(point(0.5 * (a0 + a1), 0.5 * (b0 + b1)));
        omega_[p] = internal::RectSolidAngle(a0, a1, b0, b1);
        omega_f_[p] = static_cast<float>(omega_[p]);
        inv_omega_f_[p] = static_cast<float>(1.0 / omega_[p]);
        max_width_ = std::max(max_width_, static_cast<float>(std::sqrt(omega_[p])));
        dirs_[p] = internal::PixelDir{static_cast<float>(centre.x), static_cast<float>(centre.y),
                                      static_cast<float>(centre.z),
                                      static_cast<float>(1.0 / std::sqrt(omega_[p])),
                                      static_cast<float>(0.5 * std::sqrt(omega_[p]))};
        dir_x_[p] = dirs_[p].x, dir_y_[p] = dirs_[p].y, dir_z_[p] = dirs_[p].z;
        half_width_[p] = dirs_[p].half_width;
        // The part above the horizon z >= 0. On the side faces z is the row coordinate b
        // (k2 == 2), so clipping keeps a rectangle; +z is all above, -z all below.
        double c0 = b0;
        if (face.k == 2) {
          if (face.sign < 0) continue;
        } else {
          if (b1 <= 0.0) continue;
          c0 = std::max(b0, 0.0);
        }
        omega_above_[p] = internal::RectSolidAngle(a0, a1, c0, b1);
        const glm::dvec3 corners[4] = {point(a0, c0), point(a1, c0), point(a1, b1), point(a0, b1)};
        cos_weight_[p] = internal::PolygonCosineWeight(corners, 4);
        hemisphere_.push_back(static_cast<uint32_t>(p));
        hemi_weight_.push_back(static_cast<float>(cos_weight_[p]));
        hemi_omega_.push_back(static_cast<float>(omega_above_[p]));
        // The weight's slope across the pixel's coverage samples: with a sample's weight
        // w / 64 * (1 + gx (i - 3.5) + gy (j - 3.5)) (column i, row j of kMaskSide = 8), the
        // halves' weights differ by 2 w gx and 2 w gy. Exact where the weight is linear across
        // the pixel (the row above the horizon: cos ~ b), and the samples' weights sum to w.
        double gx = 0.0, gy = 0.0;
        if (c0 == b0 && cos_weight_[p] > 0.0) {
          auto weight = [&](double x0, double x1, double y0, double y1) {
            const glm::dvec3 q[4] = {point(x0, y0), point(x1, y0), point(x1, y1), point(x0, y1)};
            return internal::PolygonCosineWeight(q, 4);
          };
          const double am = 0.5 * (a0 + a1), bm = 0.5 * (b0 + b1);
          const double w = cos_weight_[p];
          gx = (weight(am, a1, b0, b1) - weight(a0, am, b0, b1)) / (2.0 * w);
          gy = (weight(a0, a1, bm, b1) - weight(a0, a1, b0, bm)) / (2.0 * w);
          // Every sample keeps a positive weight.
          const double worst = 3.5 * (std::fabs(gx) + std::fabs(gy));
          if (worst > 0.95) gx *= 0.95 / worst, gy *= 0.95 / worst;
        }
        hemi_slope_x_.push_back(static_cast<float>(gx));
        hemi_slope_y_.push_back(static_cast<float>(gy));
      }
    }
  }
  return absl::OkStatus();
}

glm::vec3 MicroBuffer::PixelDirection(int p) const {
  return glm::vec3(dirs_[p].x, dirs_[p].y, dirs_[p].z);
}

// Shade() closes the open layers of the pixels above the horizon only; these close a copy, which
// is a no-op for those.
float MicroBuffer::PixelCoverage(int p) const {
  internal::PixelState px = pixels_[p];
  internal::Rasterizer::Close<false>(px, /*behind=*/false, free_layer_);
  return px.closed;
}

glm::vec3 MicroBuffer::PixelRadiance(int p) const {
  internal::PixelState px = pixels_[p];
  internal::Rasterizer::Close<true>(px, /*behind=*/false, free_layer_);
  return glm::vec3(px.closed_rgb[0], px.closed_rgb[1], px.closed_rgb[2]);
}

}  // namespace pbgi
