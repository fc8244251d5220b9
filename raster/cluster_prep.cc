// Cluster preparation, one at a time and four lanes at a time (see cluster_prep.h).
#include "raster/cluster_prep.h"

#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>

#include "glm/geometric.hpp"
#include "pbgi/sh.h"
#include "raster/cluster_model.h"
#include "raster/rasterizer.h"
#include "raster/simd.h"

namespace pbgi::internal {
namespace {

constexpr float kTwoPi = 2.0f * static_cast<float>(sh::kPi);

glm::vec3 ToFrame(const ClusterFrame& f, const glm::vec3& v) {
  return glm::vec3(glm::dot(f.t, v), glm::dot(f.b, v), glm::dot(f.n, v));
}

// The four-lane path reads a cluster as consecutive floats: bounds, area, then the area SH and
// the three power SH back to back.
constexpr size_t kLoOffset = offsetof(Cluster, bounds) + offsetof(Bounds, lo);
static_assert(offsetof(Bounds, hi) == offsetof(Bounds, lo) + 12);
static_assert(offsetof(Cluster, area) == kLoOffset + 24);
static_assert(offsetof(Cluster, sh_area) == kLoOffset + 28);
static_assert(offsetof(Cluster, sh_power) == offsetof(Cluster, sh_area) + 36);
static_assert(sizeof(Cluster) >= offsetof(Cluster, sh_power) + 28 * 4);
// And writes a splat as four blocks of four floats (the last one's fourth is near and flat).
static_assert(offsetof(PreparedSplat, dir) == 16 && offsetof(PreparedSplat, omega) == 28);
static_assert(offsetof(PreparedSplat, normal) == 32 && offsetof(PreparedSplat, depth) == 44);
static_assert(offsetof(PreparedSplat, extent) == 48 && offsetof(PreparedSplat, plane) == 52);
static_assert(offsetof(PreparedSplat, thick) == 56 && offsetof(PreparedSplat, near) == 60);

V4 LoadAt(const Cluster& c, size_t offset) {
  return Load4(reinterpret_cast<const float*>(reinterpret_cast<const char*>(&c) + offset));
}

inline V4 Abs4(V4 v) { return reinterpret_cast<V4>(reinterpret_cast<V4i>(v) & 0x7fffffff); }
inline V4 Select(V4i mask, V4 a, V4 b) { return mask ? a : b; }

}  // namespace

ClusterFrame::ClusterFrame(const glm::vec3& origin, const glm::vec3& t, const glm::vec3& b,
                           const glm::vec3& n, float max_distance, HitSides sides,
                           ClusterModel model)
    : origin(origin),
      t(t),
      b(b),
      n(n),
      half_abs_n(0.5f * glm::vec3(std::fabs(n.x), std::fabs(n.y), std::fabs(n.z))),
      max_distance(max_distance),
      sides(sides),
      model(model) {
  for (int k = 0; k < 3; ++k) {
    origin4[k] = Splat4(origin[k]);
    t4[k] = Splat4(t[k]);
    b4[k] = Splat4(b[k]);
    n4[k] = Splat4(n[k]);
    half_abs_n4[k] = Splat4(half_abs_n[k]);
  }
  max_distance4 = Splat4(max_distance);
}

template <bool kRad>
bool PrepareClusterOne(const Cluster& c, const ClusterFrame& f, PreparedSplat* out) {
  const Bounds& box = c.bounds;
  if (box.Empty()) return false;
  const glm::vec3 ext = box.hi - box.lo;
  const glm::vec3 rel = 0.5f * (box.lo + box.hi) - f.origin;
  const glm::vec3 local = ToFrame(f, rel);
  // Entirely behind (or in) the tangent plane: the box's highest corner along n.
  const float top = local.z + glm::dot(f.half_abs_n, ext);
  const float d2 = glm::dot(local, local);
  if (!(top > 0.0f) || !(d2 > 0.0f) || !std::isfinite(d2)) return false;
  const float d = std::sqrt(d2);
  if (d > f.max_distance) return false;
  const float inv_d = 1.0f / d;
  const glm::vec3 to_receiver = rel * -inv_d;
  const ClusterSight view = ClusterView<kRad>(c, to_receiver, f.sides, f.model);
  const float omega = std::min(view.area * (inv_d * inv_d), kTwoPi);
  if (!(omega > 0.0f)) return false;
  PreparedSplat& s = *out;
  Store4(s.rgb1, view.rgb1);
  s.dir = local * inv_d;
  s.omega = omega;
  s.depth = d;
  s.extent = 0.5f * glm::length(ext);
  // The mean normal, turned towards the receiver; a nearly flat cluster also gets its plane
  // through the box centre and its thickness along the normal (the box's half extent).
  const glm::vec3& ns = view.normal_sum;
  const float nl2 = glm::dot(ns, ns);
  s.normal = glm::vec3(0.0f);
  s.plane = 0.0f;
  s.thick = 0.0f;
  s.flat = 0;
  if (nl2 > 0.0f) {
    const float nl = std::sqrt(nl2);
    const float towards = glm::dot(ns, rel);
    const float scale = (towards > 0.0f ? -1.0f : 1.0f) / nl;
    const glm::vec3 mw = ns * scale;
    s.normal = ToFrame(f, mw);
    if (nl > kFlatness * view.total) {
      s.plane = towards * scale;
      s.thick =
          0.5f * (std::fabs(mw.x) * ext.x + std::fabs(mw.y) * ext.y + std::fabs(mw.z) * ext.z);
      s.flat = s.plane < 0.0f ? 1 : 0;
    }
  }
  s.near = 0;
  return true;
}

// PrepareClusterOne and ClusterView (moment model) in four lanes, one cluster per lane: the
// clusters are transposed in (4 x 4 blocks of consecutive floats), every branch becomes a mask,
// and the splats are transposed back out; a culled lane's splat is written and then
// overwritten by the next one.
namespace {

template <bool kRad>
[[gnu::always_inline]] inline int Prepare4(const Cluster* c, const ClusterFrame& f,
                                           PreparedSplat* out) {
  using namespace cluster_model_internal;
  // Block 0: lo.x lo.y lo.z hi.x; 1: hi.y hi.z area c0; 2: c1..c4; 3: c5..c8 (c: area SH).
  V4 lox = LoadAt(c[0], kLoOffset), loy = LoadAt(c[1], kLoOffset), loz = LoadAt(c[2], kLoOffset),
     hix = LoadAt(c[3], kLoOffset);
  Transpose4(lox, loy, loz, hix);
  V4 hiy = LoadAt(c[0], kLoOffset + 16), hiz = LoadAt(c[1], kLoOffset + 16),
     unused = LoadAt(c[2], kLoOffset + 16), a0 = LoadAt(c[3], kLoOffset + 16);
  Transpose4(hiy, hiz, unused, a0);
  V4 a1 = LoadAt(c[0], kLoOffset + 32), a2 = LoadAt(c[1], kLoOffset + 32),
     a3 = LoadAt(c[2], kLoOffset + 32), a4 = LoadAt(c[3], kLoOffset + 32);
  Transpose4(a1, a2, a3, a4);
  V4 a5 = LoadAt(c[0], kLoOffset + 48), a6 = LoadAt(c[1], kLoOffset + 48),
     a7 = LoadAt(c[2], kLoOffset + 48), a8 = LoadAt(c[3], kLoOffset + 48);
  Transpose4(a5, a6, a7, a8);

  const V4 zero = Splat4(0.0f), one = Splat4(1.0f);
  const V4i empty = (lox > hix) | (loy > hiy) | (loz > hiz);
  const V4 ex = hix - lox, ey = hiy - loy, ez = hiz - loz;
  const V4* o = f.origin4;
  const V4 rx = 0.5f * (lox + hix) - o[0], ry = 0.5f * (loy + hiy) - o[1],
           rz = 0.5f * (loz + hiz) - o[2];
  auto to_frame = [](const V4* axis, V4 x, V4 y, V4 z) {
    return axis[0] * x + axis[1] * y + axis[2] * z;
  };
  const V4 lx = to_frame(f.t4, rx, ry, rz);
  const V4 ly = to_frame(f.b4, rx, ry, rz);
  const V4 lz = to_frame(f.n4, rx, ry, rz);
  const V4 top = lz + to_frame(f.half_abs_n4, ex, ey, ez);
  const V4 d2 = lx * lx + ly * ly + lz * lz;
  const V4 d = Sqrt4(d2);
  constexpr float kInf = std::numeric_limits<float>::infinity();
  // d2 < inf also rejects NaN; !(d > max_distance) as in the scalar path.
  V4i ok = ~empty & (top > 0.0f) & (d2 > 0.0f) & (d2 < kInf) & ~(d > f.max_distance4);
  const V4 inv_d = one / d;
  const V4 wx = rx * -inv_d, wy = ry * -inv_d, wz = rz * -inv_d;

  // The area SH at w (ClusterView): band 2 and band 1.
  const V4 y1 = kY1 * wy, y2 = kY1 * wz, y3 = kY1 * wx;
  const V4 y4 = kY2 * wx * wy, y5 = kY2 * wy * wz, y6 = kY6 * (3.0f * wz * wz - 1.0f),
           y7 = kY2 * wx * wz, y8 = kY8 * (wx * wx - wy * wy);
  const V4 even2 = ((a4 * y4 + a6 * y6) + (a5 * y5 + a7 * y7)) + a8 * y8;
  const V4 odd = a2 * y2 + (a1 * y1 + a3 * y3);
  const V4 total = a0 * static_cast<float>(1.0 / kBand0);
  const V4 m2 = (total + 6.4f * even2) * (1.0f / 3.0f);
  const V4 q = ((a4 * a4 + a6 * a6) + (a5 * a5 + a7 * a7)) + a8 * a8;
  V4 t = 3.2f * q / (a0 * a0);
  t = Select(t < 0.0f, zero, Select(1.0f < t, one, t));
  constexpr float kIso = 0.8660254037844386f;
  const V4 even_factor = kIso + (1.0f - kIso) * t;
  const V4 n_dot_w = odd * static_cast<float>(1.0 / (kBand1 * kY1));
  const V4 root = Sqrt4(Max4(zero, total * m2)) * even_factor;
  const V4 abs_ndw = Abs4(n_dot_w);
  const V4 even = Select(root < abs_ndw, abs_ndw, root);
  V4 area = f.sides == HitSides::kFront  ? 0.5f * (even + n_dot_w)
            : f.sides == HitSides::kBack ? 0.5f * (even - n_dot_w)
                                         : even;
  area = Select(total > 0.0f, area, zero);
  V4 omega = area * (inv_d * inv_d);
  omega = Select(kTwoPi < omega, Splat4(kTwoPi), omega);
  ok &= omega > 0.0f;
  const int mask = Movemask4(ok);
  if (mask == 0) return 0;

  // Radiance: the three power SH at the same basis, regularised as in ClusterRadiance.
  V4 red = zero, green = zero, blue = zero;
  if constexpr (kRad) {
    constexpr size_t kP = offsetof(Cluster, sh_power);
    V4 p[28];
    for (int j = 0; j < 7; ++j) {
      p[4 * j] = LoadAt(c[0], kP + 16 * j);
      p[4 * j + 1] = LoadAt(c[1], kP + 16 * j);
      p[4 * j + 2] = LoadAt(c[2], kP + 16 * j);
      p[4 * j + 3] = LoadAt(c[3], kP + 16 * j);
      Transpose4(p[4 * j], p[4 * j + 1], p[4 * j + 2], p[4 * j + 3]);
    }
    auto side = [&](V4 e, V4 o) {
      const V4 front = Max4(zero, e + o), back = Max4(zero, e - o);
      return f.sides == HitSides::kFront ? front : f.sides == HitSides::kBack ? back : front + back;
    };
    const V4 den = side(a0 * kY0 + even2, odd) + kRadianceBlend * (kY0 * a0);
    const V4i lit = den > 0.0f;
    V4 rgb[3];
    for (int ch = 0; ch < 3; ++ch) {
      const V4* s = p + 9 * ch;
      const V4 e = s[0] * kY0 + (((s[4] * y4 + s[6] * y6) + (s[5] * y5 + s[7] * y7)) + s[8] * y8);
      const V4 o = s[2] * y2 + (s[1] * y1 + s[3] * y3);
      const V4 num = side(e, o) + kRadianceBlend * Max4(zero, kY0 * s[0]);
      rgb[ch] = Select(lit, num / den, zero);
    }
    red = rgb[0], green = rgb[1], blue = rgb[2];
  }

  // The mean normal, turned towards the receiver, and a flat cluster's plane.
  constexpr float kInv1 = static_cast<float>(1.0 / kBand1);
  const V4 nx = a3 * kInv1, ny = a1 * kInv1, nz = a2 * kInv1;
  const V4 nl2 = nx * nx + ny * ny + nz * nz;
  const V4i has_normal = nl2 > 0.0f;
  const V4 nl = Sqrt4(nl2);
  const V4 towards = nx * rx + ny * ry + nz * rz;
  const V4 scale = Select(towards > 0.0f, Splat4(-1.0f), one) / nl;
  const V4 mx = nx * scale, my = ny * scale, mz = nz * scale;
  const V4 snx = Select(has_normal, to_frame(f.t4, mx, my, mz), zero);
  const V4 sny = Select(has_normal, to_frame(f.b4, mx, my, mz), zero);
  const V4 snz = Select(has_normal, to_frame(f.n4, mx, my, mz), zero);
  const V4i flat = has_normal & (nl > kFlatness * total);
  const V4 plane = Select(flat, towards * scale, zero);
  const V4 thick = Select(flat, 0.5f * (Abs4(mx) * ex + Abs4(my) * ey + Abs4(mz) * ez), zero);
  const V4i flat_flag = flat & (plane < 0.0f);

  // Out, one splat per block of four: {1, rgb}, {dir, omega}, {normal, depth},
  // {extent, plane, thick, -}.
  V4 g0 = one, g1 = red, g2 = green, g3 = blue;
  Transpose4(g0, g1, g2, g3);
  V4 h0 = lx * inv_d, h1 = ly * inv_d, h2 = lz * inv_d, h3 = omega;
  Transpose4(h0, h1, h2, h3);
  V4 k0 = snx, k1 = sny, k2 = snz, k3 = d;
  Transpose4(k0, k1, k2, k3);
  V4 m0 = 0.5f * Sqrt4(ex * ex + ey * ey + ez * ez), m1 = plane, m2b = thick, m3 = zero;
  Transpose4(m0, m1, m2b, m3);
  const int flat_bits = Movemask4(flat_flag);
  int n = 0;
  auto put = [&](int i, V4 rgb1, V4 dir, V4 normal, V4 rest) {
    PreparedSplat& s = out[n];
    Store4(s.rgb1, rgb1);
    Store4(&s.dir.x, dir);
    Store4(&s.normal.x, normal);
    Store4(&s.extent, rest);
    s.near = 0;
    s.flat = static_cast<uint8_t>((flat_bits >> i) & 1);
    n += (mask >> i) & 1;
  };
  put(0, g0, h0, k0, m0);
  put(1, g1, h1, k1, m1);
  put(2, g2, h2, k2, m2b);
  put(3, g3, h3, k3, m3);
  return n;
}

#if PBGI_RASTER_HAS_AVX2
// The same code in VEX encoding: three-operand instructions need none of the register copies
// that SSE's two-operand ones do (about a quarter of the SSE2 instructions). No FMA: with
// -ffp-contract=off (ISO C++) the results are bit-identical to the SSE2 build.
template <bool kRad>
__attribute__((target("avx2"))) int Prepare4Avx2(const Cluster* c, const ClusterFrame& f,
                                                 PreparedSplat* out) {
  return Prepare4<kRad>(c, f, out);
}
#endif

template <bool kRad>
int Prepare4Baseline(const Cluster* c, const ClusterFrame& f, PreparedSplat* out) {
  return Prepare4<kRad>(c, f, out);
}

}  // namespace

bool CpuHasAvx2() {
#if PBGI_RASTER_HAS_AVX2
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
#else
  return false;
#endif
}

namespace {
std::atomic<bool> force_baseline{false};
}  // namespace

bool UseAvx2() { return CpuHasAvx2() && !force_baseline.load(std::memory_order_relaxed); }

void ForceBaselineIsaForTesting(bool force) { force_baseline.store(force); }

template <bool kRad>
int PrepareClusters4(const Cluster* c, const ClusterFrame& f, PreparedSplat* out, bool avx2) {
#if PBGI_RASTER_HAS_AVX2
  if (avx2) return Prepare4Avx2<kRad>(c, f, out);
#endif
  (void)avx2;
  return Prepare4Baseline<kRad>(c, f, out);
}

template bool PrepareClusterOne<true>(const Cluster&, const ClusterFrame&, PreparedSplat*);
template bool PrepareClusterOne<false>(const Cluster&, const ClusterFrame&, PreparedSplat*);
template int PrepareClusters4<true>(const Cluster*, const ClusterFrame&, PreparedSplat*, bool);
template int PrepareClusters4<false>(const Cluster*, const ClusterFrame&, PreparedSplat*, bool);

}  // namespace pbgi::internal
