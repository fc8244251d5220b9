// The rasterizer's splatting, compositing and integration (see rasterizer.h, raster.h).
#include "raster/rasterizer.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include "base/math.h"
#include "glm/geometric.hpp"
#include "pbgi/sh.h"
#include "raster/cluster_model.h"
#include "raster/cluster_prep.h"
#include "raster/cube.h"
#include "raster/polygon.h"
#include "raster/polygon_coverage.h"

namespace pbgi::internal {
namespace {
// A cone's coverage ramps from 1 to 0 across its edge over 1 / kRampSlope pixel widths.
constexpr float kRampSlope = 1.0f;
// Splats up to this many pixels' solid angle are spread bilinearly (at most a full pixel each).
constexpr float kBilinearMax = 1.0f;
// Draw() looks for hidden clusters once this many layers have closed behind a nearer one: in a
// scene with little behind what is seen first (a room), the test would cost ~80 instructions
// per cluster and find almost nothing (cornell: 4% hidden, city 45%).
constexpr uint32_t kMinClosesToTest = 64;
}  // namespace

// LSD radix sort of (depth, index) on the top 20 bits of the depth (positive floats sort as
// integers; 20 bits keep 11 mantissa bits, a relative depth step of 5e-4), two 10-bit passes.
// The high digit (exponent and two mantissa bits) of a receiver's splats spans a few dozen of
// its 1024 buckets: its prefix sum runs over that span only.
inline void Rasterizer::SortByDepth() {
  const PreparedSplat* splats = mb_.splats_.data();
  auto& order = mb_.order_;
  auto& tmp = mb_.order_tmp_;
  const size_t n = count_;
  order.resize(n);
  tmp.resize(n);
  constexpr int kBits = 10, kBuckets = 1 << kBits;
  uint32_t count[2][kBuckets] = {};
  uint32_t high_lo = kBuckets - 1, high_hi = 0;
  for (size_t i = 0; i < n; ++i) {
    uint32_t key;
    std::memcpy(&key, &splats[i].depth, sizeof key);
    key >>= 12;
    order[i] = (static_cast<uint64_t>(key) << 32) | i;
    ++count[0][key & (kBuckets - 1)];
    const uint32_t high = (key >> kBits) & (kBuckets - 1);
    ++count[1][high];
    high_lo = std::min(high_lo, high);
    high_hi = std::max(high_hi, high);
  }
  for (int pass = 0; pass < 2; ++pass) {
    uint32_t sum = 0;
    const uint32_t b0 = pass == 0 ? 0 : high_lo, b1 = pass == 0 ? kBuckets - 1 : high_hi;
    for (uint32_t b = b0; b <= b1; ++b) {
      const uint32_t c = count[pass][b];
      count[pass][b] = sum;
      sum += c;
    }
    const int shift = 32 + pass * kBits;
    for (size_t i = 0; i < n; ++i) {
      const uint64_t o = order[i];
      tmp[count[pass][(o >> shift) & (kBuckets - 1)]++] = o;
    }
    order.swap(tmp);
  }
}

inline void Rasterizer::Reset() {
  PixelState empty{};
  empty.depth = std::numeric_limits<float>::infinity();
  std::fill(mb_.pixels_.begin(), mb_.pixels_.end(), empty);
  std::fill(mb_.shut_.begin(), mb_.shut_.end(), std::numeric_limits<float>::quiet_NaN());
}

void Rasterizer::SetFrame(const ShadeReceiver& r) {
  n_ = glm::normalize(r.normal);
  sheet_ = r.sheet;
  OrthonormalBasis(n_, &t_, &b_);
  origin_ = r.position + o_.bias * n_;
  world_x_ = ToLocal(glm::vec3(1.0f, 0.0f, 0.0f));
  world_y_ = ToLocal(glm::vec3(0.0f, 1.0f, 0.0f));
  world_z_ = ToLocal(glm::vec3(0.0f, 0.0f, 1.0f));
  col_x_ = V4{t_.x, b_.x, n_.x, 0.0f};
  col_y_ = V4{t_.y, b_.y, n_.y, 0.0f};
  col_z_ = V4{t_.z, b_.z, n_.z, 0.0f};
}

template <bool kRad>
void Rasterizer::PrepareClusters(const std::vector<Cluster>& clusters) {
  const ClusterFrame frame(origin_, t_, b_, n_, o_.max_distance, o_.hitsides, o_.cluster_model);
  count_ += static_cast<uint32_t>(internal::PrepareClusters<kRad>(
      clusters.data(), clusters.size(), frame, mb_.splats_.data(), avx2_));
}

void Rasterizer::PrepareSurfel(const Surfel& sf, ShadeResult* out) {
  glm::vec3 rel = sf.position - origin_;
  const float r = sf.radius;
  const float nn = glm::dot(sf.normal, sf.normal);
  if (!(r > 0.0f) || !(nn > 0.0f)) {
    ++out->culled;
    return;
  }
  const glm::vec3 normal = sf.normal / std::sqrt(nn);
  // side > 0: the receiver is in front of the surfel.
  float side = -glm::dot(normal, rel);
  if (const float shift = CreaseShift(sf.two_sided, normal, side); shift != 0.0f) {
    rel -= shift * normal;
    side += shift;
  }
  // The disk's highest point along the receiver's normal.
  const float cn = glm::dot(normal, n_);
  const float top = glm::dot(n_, rel) + r * std::sqrt(std::max(0.0f, 1.0f - cn * cn));
  const float d2 = glm::dot(rel, rel);
  const float d = std::sqrt(d2);
  // A two-sided surfel shows both sides whatever hitsides says.
  const HitSides sides = sf.two_sided ? HitSides::kBoth : o_.hitsides;
  const bool visible = (sides == HitSides::kFront && side > 0.0f) ||
                       (sides == HitSides::kBack && side < 0.0f) ||
                       (sides == HitSides::kBoth && side != 0.0f);
  if (!(top > 0.0f) || !visible || OwnSurfaceFromBehind(sf.two_sided, sf.sheet, normal, rel, r) ||
      !std::isfinite(d2) || d > o_.max_distance) {
    ++out->culled;
    return;
  }
  PreparedSplat& s = mb_.splats_[count_];  // counted only once complete
  s.depth = d;
  s.extent = r;
  if (radiance_) {
    // A two-sided surfel seen from behind shows its back radiance.
    const glm::vec3& l = sf.two_sided && side < 0.0f ? sf.back_radiance : sf.radiance;
    Store4(s.rgb1, V4{1.0f, l.x, l.y, l.z});
  } else {
    Store4(s.rgb1, V4{1.0f, 0.0f, 0.0f, 0.0f});
  }
  // The disk's plane, its normal turned towards the receiver (side != 0 here).
  const float facing = side > 0.0f ? 1.0f : -1.0f;
  s.normal = ToLocal(normal) * facing;
  s.plane = -std::fabs(side);
  s.thick = 0.0f;
  s.flat = 1;
  s.flags = SurfelFlags(sf.two_sided, side);
  if (d < o_.near_field_factor * r) {
    s.dir = ToLocal(rel);
    s.omega = r;
    s.near = 1;
    ++count_;
    ++out->near_disks_drawn;
    return;
  }
  const float omega =
      std::min(sf.Area() * std::fabs(side) / (d2 * d), 2.0f * static_cast<float>(sh::kPi));
  if (!(omega > 0.0f) || !(d2 > 0.0f)) {
    ++out->culled;
    return;
  }
  s.dir = ToLocal(rel) * (1.0f / d);
  s.omega = omega;
  s.near = 0;
  ++count_;
  ++out->surfels_drawn;
}

template <bool kClamp, bool kRad, bool kLanes>
void Rasterizer::SplatPolygons(const PreparedSplat& s) {
  const Frag fr = FragOf(s);
  const Polygon* polys = mb_.polygons_.data() + s.poly_first;
  const float alpha = s.alpha;
  auto emit = [&](uint32_t pixel, float cov) { Emit<kClamp, kRad>(pixel, alpha * cov, fr); };
  if constexpr (kClamp) {
    // Fragments arrive front to back: where every pixel of the polygon's rectangle is closed
    // and already as near, Emit() would change nothing (bit for bit the same result).
    auto skip = [&](uint32_t first, int col0, int col1, int row0, int row1) {
      return RectClosed(first, col0, col1, row0, row1, fr.depth);
    };
    // An opaque polygon's fragments carry their coverage masks (see Layer()). One of lower
    // opacity covers an unknown part of its pixels' samples: its fragments stay scalar. Both
    // pass the samples whose cells their footprint overlaps (PixelState::touched).
    if (alpha >= kMaskOpacity) {
      auto masked = [&](uint32_t pixel, float cov, const polygon_coverage::PixelSamples& t) {
        Emit<kClamp, kRad>(pixel, alpha * cov, fr, PolygonSamples<true>{t});
      };
      for (uint32_t k = 0; k < s.poly_count; ++k) {
        RasterizePolygonIn<kLanes>(polys[k], res_, &mb_.accumulation_, masked, skip);
      }
    } else {
      auto scalar = [&](uint32_t pixel, float cov, const polygon_coverage::PixelSamples& t) {
        Emit<kClamp, kRad>(pixel, alpha * cov, fr, PolygonSamples<false>{t});
      };
      for (uint32_t k = 0; k < s.poly_count; ++k) {
        RasterizePolygonIn<kLanes>(polys[k], res_, &mb_.accumulation_, scalar, skip);
      }
    }
  } else {
    for (uint32_t k = 0; k < s.poly_count; ++k) {
      RasterizePolygonIn<kLanes>(polys[k], res_, &mb_.accumulation_, emit,
                                 [](uint32_t, int, int, int, int) { return false; });
    }
  }
}

template <bool kClamp, bool kRad>
void Rasterizer::SplatCone(const PreparedSplat& s) {
  const Frag fr = FragOf(s);
  const glm::vec3& d = s.dir;
  // The face and pixel that contain the cone's axis.
  const glm::vec3 ad(std::fabs(d.x), std::fabs(d.y), std::fabs(d.z));  // glm::abs branches
  const int k = ad.x >= ad.y ? (ad.x >= ad.z ? 0 : 2) : (ad.y >= ad.z ? 1 : 2);
  const int f = 2 * k + (d[k] < 0.0f ? 1 : 0);
  const FaceAxes face = Face(f);
  const float inv = 1.0f / ad[k];
  const float half = 0.5f * static_cast<float>(res_);
  const float x = (d[face.k1] * inv + 1.0f) * half - 0.5f;
  const float y = (d[face.k2] * inv + 1.0f) * half - 0.5f;
  const int base = f * res_ * res_;
  auto pixel = [&](int col, int row) {
    col = std::clamp(col, 0, res_ - 1);
    row = std::clamp(row, 0, res_ - 1);
    return static_cast<uint32_t>(base + row * res_ + col);
  };
  // x, y >= -0.5, so int(x + 1.5) - 1 is floor(x + 0.5): the nearest pixel centre.
  const int cx = static_cast<int>(x + 1.5f) - 1, cy = static_cast<int>(y + 1.5f) - 1;
  const uint32_t q = pixel(cx, cy);
  if (s.omega <= kBilinearMax * omega_[q]) {
    // At most a pixel: bilinear weights over the four nearest pixel centres. Their
    // sums over a surface's many small splats beat with the pixel grid by a few percent, which
    // the depth layers absorb (a layer's coverage is not clamped per pixel).
    // x, y in [-0.5, res - 0.5], so int(x + 1) - 1 is floor(x), in [-1, res - 1] (std::floor
    // is a library call without SSE4.1).
    const int ix = static_cast<int>(x + 1.0f) - 1, iy = static_cast<int>(y + 1.0f) - 1;
    const float tx = x - static_cast<float>(ix), ty = y - static_cast<float>(iy);
    const int c0 = std::max(ix, 0);
    const int c1 = std::min(ix + 1, res_ - 1);
    const int r0 = base + std::max(iy, 0) * res_;
    const int r1 = base + std::min(iy + 1, res_ - 1) * res_;
    const float w[4] = {(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty};
    const uint32_t p[4] = {static_cast<uint32_t>(r0 + c0), static_cast<uint32_t>(r0 + c1),
                           static_cast<uint32_t>(r1 + c0), static_cast<uint32_t>(r1 + c1)};
    float cov[4];
    for (int i = 0; i < 4; ++i) cov[i] = s.omega * w[i] * inv_omega_[p[i]];
    // ix, iy in [0, res - 2] (one unsigned comparison each).
    const uint32_t last = static_cast<uint32_t>(res_ - 1);
    if (static_cast<uint32_t>(ix) < last && static_cast<uint32_t>(iy) < last) {
      Emit2x2<kClamp, kRad>(p[0], cov, fr);  // no pixel clamped to the face: a 2 x 2 block
    } else {
      for (int i = 0; i < 4; ++i) Emit<kClamp, kRad>(p[i], cov[i], fr);
    }
    return;
  }
  // Up to two pixels wide: a square footprint of the cone's solid angle on the home face, each
  // pixel's coverage its overlap with the square (separable: no per-pixel direction or square
  // root). On the face plane at distance 1, a solid angle omega around the axis spans an area
  // omega / z^3 (z = the axis's component along the face normal). Larger squares lose more
  // where the depth layers clamp (docs/raster.md, "Square splats"), so larger cones take the
  // ramp below.
  const float side = std::sqrt(s.omega * inv * inv * inv) * half;  // in pixels
  if (side <= 2.0f * kBoxMaxHalf) {
    SplatBox<kClamp, kRad>(s, base, x + 0.5f, y + 0.5f, 0.5f * side, q);
    return;
  }
  // A cone of solid angle omega has chord radius sqrt(omega / pi) (2 - 2 cos = omega / pi).
  const float chord = std::sqrt(s.omega / static_cast<float>(sh::kPi));
  const float reach = chord + 0.5f / kRampSlope * max_width_;
  const float reach2 = reach * reach;
  // At most one fragment per pixel: the buffer holds pixel_count() of them.
  std::pair<uint32_t, float>* frags = mb_.fragments_.data();
  uint32_t nf = 0;
  float sum = 0.0f;
  // The home face first; the others only when the cone crosses the home face's border.
  bool contained = false;
  for (int step = 0; step < 6; ++step) {
    const int fi = step == 0 ? f : (step <= f ? step - 1 : step);
    int col0, col1, row0, row1;
    if (!FaceRange(Face(fi), d, reach, res_, &col0, &col1, &row0, &row1,
                   step == 0 ? &contained : nullptr)) {
      continue;
    }
    for (int row = row0; row <= row1; ++row) {
      const uint32_t rbase = static_cast<uint32_t>((fi * res_ + row) * res_);
      for (int col = col0; col <= col1; ++col) {
        const uint32_t p = rbase + static_cast<uint32_t>(col);
        const PixelDir& u = dirs_[p];
        const float dot = u.x * d.x + u.y * d.y + u.z * d.z;
        // Squared chord first: most pixels of the bounding range lie beyond the ramp's reach
        // (where coverage would be <= 0), and rejecting them needs no square root.
        const float dist2 = 2.0f - 2.0f * dot;
        if (dist2 >= reach2) continue;
        const float dist = std::sqrt(std::max(0.0f, dist2));
        const float cov = std::min(1.0f, 0.5f + kRampSlope * (chord - dist) * u.inv_width);
        if (cov > 0.0f) {
          frags[nf++] = {p, cov};
          sum += cov * omega_[p];
        }
      }
    }
    if (contained) break;
  }
  if (!(sum > 0.0f)) {
    Emit<kClamp, kRad>(q, s.omega / omega_[q], fr);
    return;
  }
  // Rescale so that the footprint's solid angle is the element's exactly (a covered pixel may
  // then hold slightly more than 1; the depth layers take it as they take overlaps).
  const float scale = s.omega / sum;
  for (uint32_t i = 0; i < nf; ++i) Emit<kClamp, kRad>(frags[i].first, frags[i].second * scale, fr);
}

template <bool kClamp, bool kRad>
void Rasterizer::SplatBox(const PreparedSplat& s, int base, float u, float v, float h, uint32_t q) {
  const Frag fr = FragOf(s);
  // The square [u - h, u + h] x [v - h, v + h] in pixel-edge coordinates (pixel i spans
  // [i, i + 1]), moved back onto the face where it crosses a border: a shift of at most
  // kBoxMaxHalf pixels, and the total stays exact.
  const float size = static_cast<float>(res_);
  auto span = [&](float c, float* w, int* first) {
    float lo = c - h, hi = c + h;
    if (lo < 0.0f) {
      hi = std::min(size, hi - lo);
      lo = 0.0f;
    } else if (hi > size) {
      lo = std::max(0.0f, lo - (hi - size));
      hi = size;
    }
    const int i0 = std::min(static_cast<int>(lo), res_ - 1);
    // The last pixel that [lo, hi] enters: ceil(hi) - 1, hi >= 0 (std::ceil is a library call).
    const int top = static_cast<int>(hi);
    const int i1 = std::min(static_cast<float>(top) == hi ? top - 1 : top, i0 + kBoxMaxSpan - 1);
    for (int i = i0; i <= i1; ++i) {
      w[i - i0] = std::max(
          0.0f, std::min(hi, static_cast<float>(i + 1)) - std::max(lo, static_cast<float>(i)));
    }
    *first = i0;
    return std::max(0, i1 - i0 + 1);
  };
  float wx[kBoxMaxSpan], wy[kBoxMaxSpan];
  int c0, r0;
  const int nc = span(u, wx, &c0);
  const int nr = span(v, wy, &r0);
  float sum = 0.0f;
  for (int j = 0; j < nr; ++j) {
    const float* om = omega_ + base + (r0 + j) * res_ + c0;
    float row = 0.0f;
    for (int i = 0; i < nc; ++i) row += wx[i] * om[i];
    sum += wy[j] * row;
  }
  if (!(sum > 0.0f)) {
    Emit<kClamp, kRad>(q, s.omega * inv_omega_[q], fr);
    return;
  }
  // Coverage = overlap fraction, rescaled so that the footprint's solid angle is exact.
  const float scale = s.omega / sum;
  for (int j = 0; j < nr; ++j) {
    const uint32_t rbase = static_cast<uint32_t>(base + (r0 + j) * res_ + c0);
    const float wr = wy[j] * scale;
    for (int i = 0; i < nc; ++i) {
      if (wx[i] > 0.0f) Emit<kClamp, kRad>(rbase + static_cast<uint32_t>(i), wx[i] * wr, fr);
    }
  }
}

template <bool kClamp, bool kRad>
void Rasterizer::SplatDisk(const PreparedSplat& s) {
  const Frag fr = FragOf(s);
  const glm::vec3& c = s.dir;  // centre, local frame
  const glm::vec3& nrm = s.normal;
  const float r = s.omega;
  const float dist = s.depth;
  // Bounding cone of the disk's bounding sphere, widened by a pixel (a pixel whose centre is
  // outside may still overlap); everything when the receiver is inside the sphere.
  glm::vec3 axis(0.0f, 0.0f, 1.0f);
  float chord = 2.0f;
  if (dist > r) {
    axis = c / dist;
    const float sin_t = r / dist;
    const float cos_t = std::sqrt(std::max(0.0f, 1.0f - sin_t * sin_t));
    chord = std::min(2.0f, std::sqrt(std::max(0.0f, 2.0f - 2.0f * cos_t)) + max_width_);
  }
  const int k = o_.near_field_samples;
  const float step = 2.0f / static_cast<float>(res_);
  const float sub = step / static_cast<float>(k);
  const float plane = glm::dot(nrm, c);
  const float r2 = r * r;
  // Hits closer than this are the receiver's own surface (self-intersection epsilon).
  const float min_t2 = (1e-4f * r) * (1e-4f * r);
  // The disk's own frame, for its exact image on each face.
  glm::vec3 e1, e2;
  OrthonormalBasis(nrm, &e1, &e2);
  // Faces -x, +x, -y, +y, +z; -z lies wholly below the horizon, and so do the lower rows of the
  // side faces: pixels there count for nothing, so they are not sampled.
  for (int fi = 0; fi < 5; ++fi) {
    const FaceAxes face = Face(fi);
    int col0 = 0, col1 = res_ - 1, row0 = 0, row1 = res_ - 1;
    const DiskRange range = DiskFaceRange(face, c, e1, e2, r, res_, &col0, &col1, &row0, &row1);
    if (range == DiskRange::kNone) continue;
    if (range == DiskRange::kUnknown) {
      col0 = 0, col1 = res_ - 1, row0 = 0, row1 = res_ - 1;
      if (chord < 2.0f && !FaceRange(face, axis, chord, res_, &col0, &col1, &row0, &row1)) {
        continue;
      }
    }
    if (face.k != 2) row0 = std::max(row0, res_ / 2);
    for (int row = row0; row <= row1; ++row) {
      for (int col = col0; col <= col1; ++col) {
        float hit = 0.0f, all = 0.0f;
        for (int sj = 0; sj < k; ++sj) {
          const float bcoord = -1.0f + static_cast<float>(row) * step + (sj + 0.5f) * sub;
          for (int si = 0; si < k; ++si) {
            const float acoord = -1.0f + static_cast<float>(col) * step + (si + 0.5f) * sub;
            glm::vec3 v;
            v[face.k] = face.sign;
            v[face.k1] = acoord;
            v[face.k2] = bcoord;
            // Each ray stands for the solid angle of its sub-pixel, dA / |v|^3.
            const float v2 = glm::dot(v, v);
            const float dw = 1.0f / (v2 * std::sqrt(v2));
            all += dw;
            const float den = glm::dot(nrm, v);
            if (den == 0.0f) continue;
            const float t = plane / den;
            if (!(t > 0.0f)) continue;
            const glm::vec3 h = t * v - c;
            if (glm::dot(h, h) <= r2 && t * t * v2 > min_t2) hit += dw;
          }
        }
        if (hit > 0.0f) {
          Emit<kClamp, kRad>(static_cast<uint32_t>((fi * res_ + row) * res_ + col), hit / all, fr);
        }
      }
    }
  }
}

inline void Rasterizer::Integrate(const ShadeReceiver& r, ShadeResult* out) {
  const size_t n = mb_.hemisphere_.size();
  const uint32_t* hp = mb_.hemisphere_.data();
  const float* om = mb_.hemi_omega_.data();
  const float* w = mb_.hemi_weight_.data();
  const float* gx = mb_.hemi_slope_x_.data();
  const float* gy = mb_.hemi_slope_y_.data();
  // Each hemisphere pixel's open layer is closed as it is summed; the pixels below the horizon
  // count for nothing and stay open (MicroBuffer's accessors close them on reading).
  // Coverage and radiance in four double lanes: the same products and sums, in the same order,
  // as one scalar accumulator each.
  typedef double V4d __attribute__((vector_size(32)));
  V4d sum = {0.0, 0.0, 0.0, 0.0};
  double cover = 0.0;
  if (radiance_) {
    for (size_t i = 0; i < n; ++i) {
      PixelState& px = px_[hp[i]];
      Close<true>(px, /*behind=*/false, free_layer_);
      if (bound_) CapByTouched<true>(px);
      sum += __builtin_convertvector(Load4(&px.closed), V4d) *
             static_cast<double>(w[i] * SampleWeight(px, gx[i], gy[i]));
      cover += static_cast<double>(std::min(1.0f, px.closed)) * om[i];
    }
  } else {
    double occ = 0.0;
    for (size_t i = 0; i < n; ++i) {
      PixelState& px = px_[hp[i]];
      Close<false>(px, /*behind=*/false, free_layer_);
      if (bound_) CapByTouched<false>(px);
      occ += static_cast<double>(px.closed) * (w[i] * SampleWeight(px, gx[i], gy[i]));
      cover += static_cast<double>(std::min(1.0f, px.closed)) * om[i];
    }
    sum[0] = occ;
  }
  const double occ = sum[0];
  const glm::dvec3 e(sum[1], sum[2], sum[3]);
  out->occlusion = static_cast<float>(occ / sh::kPi);
  out->coverage = static_cast<float>(cover / (2.0 * sh::kPi));
  out->irradiance = glm::vec3(e);
  out->glossy = glm::vec3(0.0f);
  if (radiance_ && o_.lobe != GlossyLobe::kNone) {
    const float rl = glm::length(r.reflection);
    if (rl > 0.0f && std::isfinite(rl)) {
      const glm::vec3 refl = ToLocal(r.reflection / rl);
      const float alpha2 = o_.ggx_roughness * o_.ggx_roughness;
      double wsum = 0.0;
      glm::dvec3 g(0.0);
      for (size_t i = 0; i < n; ++i) {
        const uint32_t p = hp[i];
        const PixelDir& u = dirs_[p];
        const float cosa = u.x * refl.x + u.y * refl.y + u.z * refl.z;
        if (!(cosa > 0.0f)) continue;
        float lobe;
        if (o_.lobe == GlossyLobe::kPhong) {
          lobe = std::pow(cosa, o_.phong_exponent);
        } else {
          const float q = (alpha2 - 1.0f) * cosa * cosa + 1.0f;
          lobe = alpha2 / (static_cast<float>(sh::kPi) * q * q);
        }
        const double wt = static_cast<double>(lobe) * om[i];
        wsum += wt;
        const PixelState& px = px_[p];
        g += glm::dvec3(px.closed_rgb[0], px.closed_rgb[1], px.closed_rgb[2]) * wt;
      }
      if (wsum > 0.0) out->glossy = glm::vec3(g / wsum);
    }
  }
  if (clamp_) {
    out->occlusion = std::clamp(out->occlusion, 0.0f, 1.0f);
    out->coverage = std::clamp(out->coverage, 0.0f, 1.0f);
    out->irradiance = glm::max(out->irradiance, glm::vec3(0.0f));
    out->glossy = glm::max(out->glossy, glm::vec3(0.0f));
  }
}

inline bool Rasterizer::BilinearConeClosed(const PreparedSplat& s) const {
  // SplatCone's face, pixel and bilinear weights' pixels, the same expressions.
  const glm::vec3& d = s.dir;
  const glm::vec3 ad(std::fabs(d.x), std::fabs(d.y), std::fabs(d.z));
  const int k = ad.x >= ad.y ? (ad.x >= ad.z ? 0 : 2) : (ad.y >= ad.z ? 1 : 2);
  const int f = 2 * k + (d[k] < 0.0f ? 1 : 0);
  const FaceAxes face = Face(f);
  const float inv = 1.0f / ad[k];
  const float half = 0.5f * static_cast<float>(res_);
  const float x = (d[face.k1] * inv + 1.0f) * half - 0.5f;
  const float y = (d[face.k2] * inv + 1.0f) * half - 0.5f;
  const int base = f * res_ * res_;
  const int cx = std::clamp(static_cast<int>(x + 1.5f) - 1, 0, res_ - 1);
  const int cy = std::clamp(static_cast<int>(y + 1.5f) - 1, 0, res_ - 1);
  if (!(s.omega <= kBilinearMax * omega_[base + cy * res_ + cx])) return false;
  const int ix = static_cast<int>(x + 1.0f) - 1, iy = static_cast<int>(y + 1.0f) - 1;
  return RectClosed(static_cast<uint32_t>(base), std::max(ix, 0), std::min(ix + 1, res_ - 1),
                    std::max(iy, 0), std::min(iy + 1, res_ - 1), s.depth);
}

template <bool kClamp, bool kRad, bool kLanes>
void Rasterizer::Draw(const Gathered& g, uint32_t count) {
  PreparedSplat* splats = mb_.splats_.data();
  auto draw = [&](uint32_t i) {
    PreparedSplat& s = splats[i];
    if (polygons_ && i < cluster_count_) {
      const Cluster& c = g.clusters[s.source];
      // With clamp, fragments arrive front to back: a cluster wholly behind closed pixels is
      // skipped before its footprint is built (Emit() would only have lowered depth: the same
      // result bit for bit).
      if constexpr (kClamp) {
        if (closes_ >= kMinClosesToTest && BilinearConeClosed(s) && ClusterHidden(c, s)) return;
      }
      if (!BuildClusterFootprint(c, s)) return;
    }
    if (s.near == 2) {
      SplatPolygons<kClamp, kRad, kLanes>(s);
    } else if (s.near) {
      SplatDisk<kClamp, kRad>(s);
    } else {
      SplatCone<kClamp, kRad>(s);
    }
  };
  if constexpr (kClamp) {
    // Front to back, for the depth layers of Emit().
    SortByDepth();
    for (uint64_t o : mb_.order_) draw(static_cast<uint32_t>(o & 0xffffffffu));
  } else {
    for (uint32_t i = 0; i < count; ++i) draw(i);
  }
}

template <bool kClamp, bool kRad, bool kLanes>
void Rasterizer::Finish(const Gathered& g, const ShadeReceiver& r, ShadeResult* out) {
  Reset();
  if (polygons_) {
    PrepareSurfelGroups(g, out);
  } else {
    for (const Surfel& s : g.surfels) PrepareSurfel(s, out);
  }
  Draw<kClamp, kRad, kLanes>(g, count_);
  if (far_ != nullptr) CompositeFar<kClamp, kRad>();
  Integrate(r, out);
}

template <bool kClamp, bool kRad>
void Rasterizer::CompositeFar() {
  const float* state = far_->state_.data();
  const float* depth = far_->depth_.data();
  for (const uint32_t p : mb_.hemisphere_) {
    const float* f = state + 4 * size_t(p);
    const float cov = f[0];
    if (!(cov > 0.0f)) continue;
    PixelState& px = px_[p];
    px.depth = std::min(px.depth, depth[p]);
    const V4 far = Load4(f);
    if constexpr (!kClamp) {
      if constexpr (kRad) {
        Store4(&px.closed, Load4(&px.closed) + far);
      } else {
        px.closed += cov;
      }
      continue;
    } else {
      // The near layers lie in front: close the open one as a layer with something behind it
      // (clamped, as Shade() clamps a first layer once a fragment lies behind it). The far
      // field then fills what is left as a solid layer behind does in Close(): only its
      // samples that the near layers leave uncovered, where both have masks.
      Close<kRad>(px, /*behind=*/true, free_layer_);
      float c = std::min(cov, 1.0f);
      const uint64_t mask = far_->mask_[p];
      if (mask != 0 && px.closed_mask != 0) {
        c *= static_cast<float>(std::popcount(mask & ~px.closed_mask)) /
             static_cast<float>(std::popcount(mask));
      }
      const float e = std::min(c, std::max(0.0f, 1.0f - px.closed));
      if (!(e > 0.0f)) continue;
      // Where the far field's samples lie was bounded in its own buffer; here they are unknown
      // (RasterOptions::bound_by_footprints).
      px.touched = ~uint64_t{0};
      const float closed = px.closed + e;
      if constexpr (kRad) Store4(&px.closed, Load4(&px.closed) + (e / cov) * far);
      px.closed = closed;  // exactly closed + e, as Close() keeps it
    }
  }
}

void Rasterizer::ExportFar(const ShadeReceiver& r, FarBuffer* out) const {
  const size_t n = mb_.pixels_.size();
  out->res_ = res_;
  out->normal_ = glm::normalize(r.normal);
  out->state_.assign(4 * n, 0.0f);
  out->depth_.assign(n, std::numeric_limits<float>::infinity());
  out->mask_.assign(n, 0);
  // Integrate() closed the hemisphere's pixels; the others count for nothing.
  for (const uint32_t p : mb_.hemisphere_) {
    const PixelState& px = px_[p];
    float* f = &out->state_[4 * size_t(p)];
    f[0] = px.closed;
    if (radiance_) f[1] = px.closed_rgb[0], f[2] = px.closed_rgb[1], f[3] = px.closed_rgb[2];
    out->depth_[p] = px.depth;
    out->mask_[p] = px.closed_mask;
  }
}

template <bool kClamp, bool kRad>
void Rasterizer::FinishOn(const Gathered& g, const ShadeReceiver& r, ShadeResult* out) {
#if PBGI_RASTER_HAS_AVX2
  if (avx2_) {
    FinishAvx2<kClamp, kRad>(g, r, out);
    return;
  }
#endif
  Finish<kClamp, kRad, /*kLanes=*/false>(g, r, out);
}

absl::Status Rasterizer::Run(const Gathered& g, const ShadeReceiver& r, ShadeResult* out) {
  *out = ShadeResult{};
  SetFrame(r);
  crease_tol_ =
      std::max(g.position_tolerance,
               8.0f * std::numeric_limits<float>::epsilon() *
                   std::max({std::fabs(origin_.x), std::fabs(origin_.y), std::fabs(origin_.z)}));
  auto& splats = mb_.splats_;
  // Written by index: a vector's push_back costs more than the rest of a small splat's setup.
  // A group of surfels draws at most two splats a member (its pieces and their cores).
  const size_t most = g.clusters.size() + 2 * g.surfels.size();
  if (splats.size() < most) splats.resize(most);
  count_ = 0;
  if (radiance_) {
    PrepareClusters<true>(g.clusters);
  } else {
    PrepareClusters<false>(g.clusters);
  }
  out->clusters_drawn = count_;
  cluster_count_ = count_;
  poly_count_ = 0;
  closes_ = 0;
  out->culled = static_cast<uint32_t>(g.clusters.size()) - count_;
  if (clamp_) {
    if (radiance_) {
      FinishOn<true, true>(g, r, out);
    } else {
      FinishOn<true, false>(g, r, out);
    }
  } else {
    if (radiance_) {
      FinishOn<false, true>(g, r, out);
    } else {
      FinishOn<false, false>(g, r, out);
    }
  }
  mb_.prepared_ = count_;
  mb_.prepared_clusters_ = cluster_count_;
  return absl::OkStatus();
}

void Rasterizer::FootprintsOver(const MicroBuffer& mb, int pixel, std::vector<FootprintOver>* out) {
  out->clear();
  if (pixel < 0 || pixel >= mb.pixel_count()) return;
  const glm::vec3 d = glm::normalize(mb.PixelDirection(pixel));
  std::vector<float> acc;
  std::vector<PixelCoverage> cov;
  for (uint32_t i = 0; i < mb.prepared_ && i < mb.splats_.size(); ++i) {
    const PreparedSplat& s = mb.splats_[i];
    FootprintOver f;
    f.depth = s.depth;
    f.flags = s.flags;
    f.cluster = i < mb.prepared_clusters_ ? static_cast<int32_t>(s.source) : -1;
    f.normal = s.normal;
    f.alpha = 1.0f;
    f.coverage = -1.0f;
    if (s.near == 1) {  // an exact disk, centre s.dir, radius s.omega: does the centre ray cross it
      const float dn = glm::dot(d, s.normal);
      if (!(std::fabs(dn) > 0.0f)) continue;
      const float t = glm::dot(s.dir, s.normal) / dn;
      const glm::vec3 q = t * d - s.dir;
      if (!(t > 0.0f) || !(glm::dot(q, q) <= s.omega * s.omega)) continue;
      f.kind = FootprintOver::kDisk;
      out->push_back(f);
    } else if (s.near == 0) {  // a cone of solid angle s.omega about s.dir: the same
      // With polygon footprints a cluster still a cone was never drawn (hidden behind closed
      // pixels, or no footprint: Draw()); a far surfel's cone was.
      if (!mb.free_layer_ && f.cluster >= 0) continue;
      if (!(glm::dot(d, s.dir) >= 1.0f - s.omega / (2.0f * kPiFloat))) continue;
      f.kind = FootprintOver::kCone;
      out->push_back(f);
    } else if (s.near == 2) {  // polygons: their exact share of the pixel
      float share = 0.0f;
      glm::vec3 n(0.0f);
      for (uint32_t k = 0; k < s.poly_count; ++k) {
        const Polygon& p = mb.polygons_[s.poly_first + k];
        cov.clear();
        RasterizePolygon(p, mb.resolution(), &acc, &cov);
        for (const PixelCoverage& c : cov) {
          if (static_cast<int>(c.pixel) != pixel) continue;
          share += c.coverage;
          for (int j = 1; j + 1 < p.n; ++j) n += glm::cross(p.v[j] - p.v[0], p.v[j + 1] - p.v[0]);
        }
      }
      if (!(share > 0.0f)) continue;
      f.kind = FootprintOver::kPolygon;
      f.alpha = s.alpha;
      f.coverage = std::min(share, 1.0f);
      if (glm::dot(n, n) > 0.0f) f.normal = glm::normalize(n);
      out->push_back(f);
    }
  }
  std::sort(out->begin(), out->end(),
            [](const FootprintOver& a, const FootprintOver& b) { return a.depth < b.depth; });
}

}  // namespace pbgi::internal
