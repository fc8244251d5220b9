// Cluster preparation, one at a time and four lanes at a time (see cluster_prep.h).
#include "raster/cluster_prep.h"

#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>

#include "base/math.h"
#include "glm/geometric.hpp"
#include "pbgi/sh.h"
#include "raster/cluster_model.h"
#include "raster/rasterizer.h"
#include "raster/simd.h"

#if PBGI_RASTER_HAS_AVX2
#include <immintrin.h>
#endif

namespace pbgi::internal {
namespace {

constexpr float kTwoPi = 2.0f * static_cast<float>(sh::kPi);

glm::vec3 ToFrame(const ClusterFrame& f, const glm::vec3& v) {
  return glm::vec3(glm::dot(f.t, v), glm::dot(f.b, v), glm::dot(f.n, v));
}

// A cluster that is not flat by its mean normal but whose normals, sides counted apart, lie
// near one axis (a two-sided card, whose pairs cancel in N; include/pbgi/surfel.h) is drawn
// by the plane through its box centre normal to that axis, turned towards the receiver. Both
// preparation paths call this one function, so they agree bit for bit. Such a cluster's band-2
// anisotropy is above kAxisAnisotropy, which the lanes test first.
constexpr float kAxisFlatness = kFlatness * kFlatness;
// (3 k - 1)^2 / 4 for k = kAxisFlatness, the least anisotropy of a dominant axis, less a margin.
constexpr float kAxisAnisotropy = 0.2f;
// A one-sided cluster whose surfels all face one way (|sum A_i n_i| >= kSheetFlatness * A) and
// whose plane the receiver lies behind, beyond the box's thickness, shows the receiver only
// backs: with hitsides front it is culled. Its moments' projected area there is a rounding
// residual, not 0, and drawn as a flat polygon with the normal turned towards the receiver it
// showed up to its whole area (bug: sheet_seen_from_behind_drawn: a receiver on cornell's
// ceiling 0.002 above the lamp's quad got the lamp's light in its glossy lobe).
constexpr float kSheetFlatness = 0.999f;
[[gnu::noinline]] void AxisPlane(const Cluster& c, const ClusterFrame& f, PreparedSplat* s) {
  if (!sh::AxisDominates(c.sh_area.data(), kAxisFlatness)) return;
  const glm::vec3 e = sh::PrincipalAxis(c.sh_area.data());
  if (!(glm::dot(e, e) > 0.0f)) return;
  const Bounds& box = c.bounds;
  const glm::vec3 ext = box.hi - box.lo;
  const glm::vec3 rel = 0.5f * (box.lo + box.hi) - f.origin;
  const float towards = glm::dot(e, rel);
  const glm::vec3 mw = towards > 0.0f ? -e : e;
  s->normal = ToFrame(f, mw);
  s->plane = -std::fabs(towards);
  s->thick = 0.5f * (std::fabs(mw.x) * ext.x + std::fabs(mw.y) * ext.y + std::fabs(mw.z) * ext.z);
  s->flat = s->plane < 0.0f ? 1 : 0;
}

// A flat cluster with something standing on it (StandingShift in base/math.h: the ground and a
// tree's trunk, the street and a building's wall) does not have its plane through the box
// centre: a ground plane drawn halfway up the trunk was seen from below by receivers under that
// height, and the ground vanished behind it. Its plane lies at the box's back along the
// dominant axis instead: what stands on a one-sided surface stands in front of it. Both
// preparation paths call this one function for every flat cluster that may need it.
// The lanes call StandingPlane() where their own estimate of the excess passes this share of
// the threshold (the function decides exactly).
constexpr float kStandingPrefilter = 0.9f;
[[gnu::noinline]] void StandingPlane(const Cluster& c, const ClusterFrame& f, PreparedSplat* s) {
  const glm::vec3 ns = sh::AreaAndNormalSum(c.sh_area.data()).normal_sum;
  const float nl = glm::length(ns);
  if (!(nl > 0.0f)) return;
  const glm::vec3 m = ns / nl;
  const glm::vec3 a(std::fabs(m.x), std::fabs(m.y), std::fabs(m.z));
  const Bounds& box = c.bounds;
  glm::vec3 ext = box.hi - box.lo;
  int k = 0;
  const float shift = StandingShift(ns, ext, &k);
  if (!(shift > 0.0f)) return;
  glm::vec3 rel = 0.5f * (box.lo + box.hi) - f.origin;
  rel[k] += m[k] > 0.0f ? -shift : shift;
  ext[k] -= 2.0f * shift;
  const float towards = glm::dot(m, rel);
  const glm::vec3 mw = towards > 0.0f ? -m : m;
  s->normal = ToFrame(f, mw);
  s->plane = -std::fabs(towards);
  s->thick = 0.5f * (a.x * ext.x + a.y * ext.y + a.z * ext.z);
  s->flat = s->plane < 0.0f ? 1 : 0;
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
      model(model) {}

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
  bool flat = false;
  if (nl2 > 0.0f) {
    const float nl = std::sqrt(nl2);
    const float towards = glm::dot(ns, rel);
    const float scale = (towards > 0.0f ? -1.0f : 1.0f) / nl;
    const glm::vec3 mw = ns * scale;
    s.normal = ToFrame(f, mw);
    if (nl > kFlatness * view.total) {
      flat = true;
      s.plane = towards * scale;
      s.thick =
          0.5f * (std::fabs(mw.x) * ext.x + std::fabs(mw.y) * ext.y + std::fabs(mw.z) * ext.z);
      if (f.sides == HitSides::kFront && towards > 0.0f && nl >= kSheetFlatness * view.total &&
          -s.plane > s.thick) {
        return false;
      }
      s.flat = s.plane < 0.0f ? 1 : 0;
      StandingPlane(c, f, &s);
    }
  }
  if (!flat) AxisPlane(c, f, &s);
  s.near = 0;
  s.flags = 0;
  return true;
}

// Lane-parallel preparation, one cluster per lane, L::kWidth lanes: the clusters are
// transposed in (blocks of four consecutive floats), every branch becomes a mask, and the
// splats are transposed back out; a culled lane's splat is written and then overwritten by the
// next one. The expressions are PrepareClusterOne's and ClusterView's, in the same order.
namespace {
namespace baseline {
#include "raster/cluster_lanes.inc"
}  // namespace baseline

#if PBGI_RASTER_HAS_AVX2
#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx2"))), apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx2")
#endif
namespace avx2 {
typedef float V8 __attribute__((vector_size(32)));
typedef int V8i __attribute__((vector_size(32)));

#include "raster/cluster_lanes.inc"

// Eight lanes.
struct Lanes8 {
  using V = V8;
  using Vi = V8i;
  static constexpr int kWidth = 8;
  [[gnu::always_inline]] static void Gather(const Cluster* c, size_t offset, V& x0, V& x1, V& x2,
                                            V& x3) {
    V4 l0, l1, l2, l3, h0, h1, h2, h3;
    Lanes4::Gather(c, offset, l0, l1, l2, l3);
    Lanes4::Gather(c + 4, offset, h0, h1, h2, h3);
    x0 = __builtin_shufflevector(l0, h0, 0, 1, 2, 3, 4, 5, 6, 7);
    x1 = __builtin_shufflevector(l1, h1, 0, 1, 2, 3, 4, 5, 6, 7);
    x2 = __builtin_shufflevector(l2, h2, 0, 1, 2, 3, 4, 5, 6, 7);
    x3 = __builtin_shufflevector(l3, h3, 0, 1, 2, 3, 4, 5, 6, 7);
  }
  template <class Rows>
  [[gnu::always_inline]] static void Scatter(V a, V b, V c, V d, Rows lane_rows) {
    Lanes4::Scatter(Low(a), Low(b), Low(c), Low(d), lane_rows);
    Lanes4::Scatter(High(a), High(b), High(c), High(d), [&](int i) { return lane_rows(i + 4); });
  }
  [[gnu::always_inline]] static V Sqrt(V v) { return _mm256_sqrt_ps(v); }
  [[gnu::always_inline]] static int Mask(Vi m) {
    return _mm256_movemask_ps(reinterpret_cast<__m256>(m));
  }
  [[gnu::always_inline]] static V4 Low(V v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3); }
  [[gnu::always_inline]] static V4 High(V v) { return __builtin_shufflevector(v, v, 4, 5, 6, 7); }
};
}  // namespace avx2
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif
#endif

#if PBGI_RASTER_HAS_AVX2
// Eight lanes, in VEX encoding (whose three-operand instructions also need none of the
// register copies of SSE's two-operand ones). No FMA: with -ffp-contract=off (ISO C++) the
// results are bit-identical to the baseline build.
template <bool kRad>
__attribute__((target("avx2"))) int PrepareAvx2(const Cluster* c, size_t count,
                                                const ClusterFrame& f, PreparedSplat* out) {
  return avx2::PrepareAll<avx2::Lanes8, kRad>(c, count, f, out);
}
#endif

template <bool kRad>
int PrepareBaseline(const Cluster* c, size_t count, const ClusterFrame& f, PreparedSplat* out) {
  return baseline::PrepareAll<baseline::Lanes4, kRad>(c, count, f, out);
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
int PrepareClusters(const Cluster* c, size_t count, const ClusterFrame& f, PreparedSplat* out,
                    bool avx2) {
  if (f.model != ClusterModel::kMoments) {
    int n = 0;
    for (size_t i = 0; i < count; ++i) {
      if (PrepareClusterOne<kRad>(c[i], f, out + n)) out[n++].source = static_cast<uint32_t>(i);
    }
    return n;
  }
#if PBGI_RASTER_HAS_AVX2
  if (avx2) return PrepareAvx2<kRad>(c, count, f, out);
#endif
  (void)avx2;
  return PrepareBaseline<kRad>(c, count, f, out);
}

template bool PrepareClusterOne<true>(const Cluster&, const ClusterFrame&, PreparedSplat*);
template bool PrepareClusterOne<false>(const Cluster&, const ClusterFrame&, PreparedSplat*);
template int PrepareClusters<true>(const Cluster*, size_t, const ClusterFrame&, PreparedSplat*,
                                   bool);
template int PrepareClusters<false>(const Cluster*, size_t, const ClusterFrame&, PreparedSplat*,
                                    bool);

}  // namespace pbgi::internal
