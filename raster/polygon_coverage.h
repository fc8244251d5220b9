// Exact area coverage of a polygon on the micro-buffer's cube faces (see raster/polygon.h),
// as a template over what receives each covered pixel: the rasterizer hands each pixel straight
// to its compositing (no list of pixels to write and read back), the tests collect them.
#ifndef PBGI_RASTER_POLYGON_COVERAGE_H_
#define PBGI_RASTER_POLYGON_COVERAGE_H_

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

#include "pbgi/raster.h"
#include "raster/simd.h"

namespace pbgi::internal {
namespace polygon_coverage {

// floor and ceil of pixel coordinates, which are >= 0 (std::floor is a library call without
// SSE4.1).
inline int FloorPos(float x) { return static_cast<int>(x); }
inline int CeilPos(float x) {
  const int i = static_cast<int>(x);
  return static_cast<float>(i) < x ? i + 1 : i;
}

// Adds the polygon's edges to the signed-area accumulation buffer of the cells
// [x0, x0 + w) x [y0, y0 + h) (w includes one column past the last, which an edge's right
// neighbour may reach). Each piece of an edge inside one cell (column m, row r) with vertical
// extent d (signed by the edge's direction) and mean x xm adds d * (1 - (xm - m)) to cell m and
// d * (xm - m) to cell m + 1: the running sum of a row is then the exact area covered in each
// cell (the integral over the row of clamp(m + 1 - x_edge(y), 0, 1), summed over edges).
inline void Accumulate(const float* xs, const float* ys, int n, int x0, int y0, int w, int h,
                       float* acc) {
  for (int i = 0; i < n; ++i) {
    const int j = i + 1 == n ? 0 : i + 1;
    float ax = xs[i], ay = ys[i], bx = xs[j], by = ys[j];
    if (ay == by) continue;
    float dir = 1.0f;
    if (ay > by) {
      std::swap(ax, bx);
      std::swap(ay, by);
      dir = -1.0f;
    }
    const float slope = (bx - ax) / (by - ay);  // dx per dy
    const int r0 = std::max(y0, FloorPos(ay));
    const int r1 = std::min(y0 + h - 1, CeilPos(by) - 1);
    for (int r = r0; r <= r1; ++r) {
      const float ya = std::max(ay, static_cast<float>(r));
      const float yb = std::min(by, static_cast<float>(r + 1));
      if (!(yb > ya)) continue;
      const float xa = ax + (ya - ay) * slope, xb = ax + (yb - ay) * slope;
      float* row = acc + size_t(r - y0) * size_t(w);
      const float d = dir * (yb - ya);
      const float lo = std::min(xa, xb), hi = std::max(xa, xb);
      const int mlo = FloorPos(lo);
      // The last cell the piece enters (an end exactly on a cell's left edge does not enter it).
      const int mhi = std::max(mlo, CeilPos(hi) - 1);
      if (mhi == mlo) {
        const int m = std::clamp(mlo, x0, x0 + w - 2);
        const float f = 0.5f * (lo + hi) - static_cast<float>(m);
        row[m - x0] += d * (1.0f - f);
        row[m - x0 + 1] += d * f;
        continue;
      }
      // Split at the integer crossings; each piece's share of d is its share of the x span.
      const float inv = d / (hi - lo);
      float s = lo;
      for (int m = mlo; m <= mhi; ++m) {
        const float e = std::min(hi, static_cast<float>(m + 1));
        if (e > s) {
          const int mc = std::clamp(m, x0, x0 + w - 2);
          const float piece = (e - s) * inv;
          const float f = 0.5f * (s + e) - static_cast<float>(mc);
          row[mc - x0] += piece * (1.0f - f);
          row[mc - x0 + 1] += piece * f;
        }
        s = e;
      }
    }
  }
}

// Sample rows of a coverage mask on a face: the largest resolution (64) times kMaskSide (8).
inline constexpr int kMaxMaskRows = 64 * 8;

// A polygon in a face's pixel coordinates.
// Room for two splits (the 2x2-block path) of a polygon of kMaxPolygonVertices: Split() adds
// one vertex per edge that crosses the line, so a part of an n-gon has at most 2n. A convex
// one's has at most n + 1, but Project() clamps vertices to the face, which can leave a polygon
// that is not quite convex; with n + 2 slots such a polygon's second split wrote past the end
// (UBSan in PolygonTest.RasterizePolygonInLanesMatchesOneVertexAtATime).
struct Poly2 {
  int n = 0;
  float x[4 * kMaxPolygonVertices], y[4 * kMaxPolygonVertices];
};

// Twice the signed area (shoelace).
inline float Area2(const Poly2& p) {
  float a = 0.0f;
  for (int i = 0, j = p.n - 1; i < p.n; j = i++) a += (p.x[j] + p.x[i]) * (p.y[j] - p.y[i]);
  return a;
}

// Splits p by the line {coord = at} (coord 0: x, 1: y) into its parts below and above (neither
// may be p). Each vertex is loaded once and carried to the next edge, the counts kept in
// locals: through the pointers, every store to a part reloaded p's vertices.
inline void Split(const Poly2& p, int coord, float at, Poly2* below, Poly2* above) {
  const int n = p.n;
  int nb = 0, na = 0;
  if (n > 0) {
    const float* c = coord == 0 ? p.x : p.y;
    float xi = p.x[0], yi = p.y[0], si = c[0] - at;
    for (int i = 0; i < n; ++i) {
      const int j = i + 1 == n ? 0 : i + 1;
      const float xj = p.x[j], yj = p.y[j], sj = c[j] - at;
      if (si <= 0.0f) below->x[nb] = xi, below->y[nb++] = yi;
      if (si >= 0.0f) above->x[na] = xi, above->y[na++] = yi;
      if ((si < 0.0f && sj > 0.0f) || (si > 0.0f && sj < 0.0f)) {
        const float t = si / (si - sj);
        const float x = xi + t * (xj - xi), y = yi + t * (yj - yi);
        below->x[nb] = x, below->y[nb++] = y;
        above->x[na] = x, above->y[na++] = y;
      }
      xi = xj, yi = yj, si = sj;
    }
  }
  below->n = nb;
  above->n = na;
}

// Eight sample rows, or eight vertices, at a time.
typedef float SpanV8f __attribute__((vector_size(32)));
typedef int32_t SpanV8i __attribute__((vector_size(32)));
inline constexpr SpanV8i kSpanLane = {0, 1, 2, 3, 4, 5, 6, 7};

// Whether every lane of a comparison's mask is true.
inline bool MaskAll(const SpanV8i& m) {
  return Movemask4(__builtin_shufflevector(m, m, 0, 1, 2, 3) &
                   __builtin_shufflevector(m, m, 4, 5, 6, 7)) == 0xf;
}

// Split() and Area2() in eight lanes, for a polygon of at most eight vertices (lane i: vertex
// i; the lanes from n on may hold anything). The 2 x 2-block path splits most far footprints
// twice, one vertex at a time with three branches per vertex, and sums each part's area.

// For each 8-bit mask, the indices of its set bits in order, three bits each (the lanes that a
// compaction keeps; the indices past the count are 0).
inline constexpr struct CompactTable {
  uint32_t lanes[256];
  constexpr CompactTable() : lanes() {
    for (int m = 0; m < 256; ++m) {
      int k = 0;
      for (int i = 0; i < 8; ++i) {
        if (m & (1 << i)) lanes[m] |= static_cast<uint32_t>(i) << (3 * k++);
      }
    }
  }
} kCompact;
// Bits 0-3 of a mask spread to bits 0, 2, 4 and 6.
inline constexpr uint8_t kSpreadBits[16] = {0x00, 0x01, 0x04, 0x05, 0x10, 0x11, 0x14, 0x15,
                                            0x40, 0x41, 0x44, 0x45, 0x50, 0x51, 0x54, 0x55};

// The compaction mask of lanes 0-3 (high: 4-7) of vertices and crossings interleaved (vertex i,
// then the crossing on its edge): bit 2 i where keep, bit 2 i + 1 where cross.
inline int InterleavedMask(const SpanV8i& keep, const SpanV8i& cross, bool high) {
  const V4i k = high ? __builtin_shufflevector(keep, keep, 4, 5, 6, 7)
                     : __builtin_shufflevector(keep, keep, 0, 1, 2, 3);
  const V4i c = high ? __builtin_shufflevector(cross, cross, 4, 5, 6, 7)
                     : __builtin_shufflevector(cross, cross, 0, 1, 2, 3);
  return kSpreadBits[Movemask4(k)] | (kSpreadBits[Movemask4(c)] << 1);
}

// *out = v's lanes permuted by `index` (each 0 to 7): GCC's variable-index __builtin_shuffle;
// clang has none (its __builtin_shufflevector takes constant indices), so there lane by lane,
// which it lowers to one permute with AVX2. Written through a pointer: an eight-lane vector
// returned by value changes the ABI without AVX.
inline void Permute8(const SpanV8f& v, const SpanV8i& index, SpanV8f* out) {
#if defined(__clang__)
  for (int i = 0; i < 8; ++i) (*out)[i] = v[index[i] & 7];
#else
  *out = __builtin_shuffle(v, index);
#endif
}

// Stores the lanes of v whose bits are set in `mask`, in order, at to[0 ..), and stale values
// after them up to to[7]. The indices are unpacked by per-lane shifts (one instruction with
// AVX2; unpacked from bytes, GCC moved them one at a time). An eight-lane vector is not
// returned: without AVX that changes the ABI.
inline void StoreCompact(float* to, const SpanV8f& v, int mask) {
  constexpr SpanV8i kShift = {0, 3, 6, 9, 12, 15, 18, 21};
  const SpanV8i index = ((SpanV8i{} + static_cast<int32_t>(kCompact.lanes[mask])) >> kShift) & 7;
  SpanV8f c;
  Permute8(v, index, &c);
  std::memcpy(to, &c, sizeof c);
}

// Split() of a polygon of at most eight vertices: the same parts, vertex for vertex. Each
// vertex's side and the crossing on the edge to the next vertex are found in lanes with the same
// expressions; a part takes vertex i where its side says so, then the crossing after it (Split's
// order), by compacting the vertices and crossings interleaved. The parts' lanes past their
// counts are written with stale values.
inline void SplitLanes(const Poly2& p, int coord, float at, Poly2* below, Poly2* above) {
  const int n = p.n;
  SpanV8f x, y;
  std::memcpy(&x, p.x, sizeof x);
  std::memcpy(&y, p.y, sizeof y);
  // Vertex j = i + 1, and 0 after the last.
  const SpanV8i succ = kSpanLane + 1;
  const SpanV8i next = succ & (succ != n);
  const SpanV8f s = (coord == 0 ? x : y) - at;
  SpanV8f xj, yj, sj;
  Permute8(x, next, &xj), Permute8(y, next, &yj), Permute8(s, next, &sj);
  const SpanV8i live = kSpanLane < n;
  const SpanV8i cross = live & (((s < 0.0f) & (sj > 0.0f)) | ((s > 0.0f) & (sj < 0.0f)));
  const SpanV8f t = s / (s - sj);
  const SpanV8f cx = x + t * (xj - x), cy = y + t * (yj - y);
  // Vertex i, then its edge's crossing: lanes 0-3 of the vertices and crossings interleaved,
  // then lanes 4-7.
  const SpanV8f x_lo = __builtin_shufflevector(x, cx, 0, 8, 1, 9, 2, 10, 3, 11);
  const SpanV8f y_lo = __builtin_shufflevector(y, cy, 0, 8, 1, 9, 2, 10, 3, 11);
  const SpanV8i keep_below = live & (s <= 0.0f), keep_above = live & (s >= 0.0f);
  const int below_lo = InterleavedMask(keep_below, cross, false);
  const int above_lo = InterleavedMask(keep_above, cross, false);
  StoreCompact(below->x, x_lo, below_lo);
  StoreCompact(below->y, y_lo, below_lo);
  StoreCompact(above->x, x_lo, above_lo);
  StoreCompact(above->y, y_lo, above_lo);
  int nb = std::popcount(static_cast<unsigned>(below_lo));
  int na = std::popcount(static_cast<unsigned>(above_lo));
  if (n > 4) {
    const SpanV8f x_hi = __builtin_shufflevector(x, cx, 4, 12, 5, 13, 6, 14, 7, 15);
    const SpanV8f y_hi = __builtin_shufflevector(y, cy, 4, 12, 5, 13, 6, 14, 7, 15);
    const int below_hi = InterleavedMask(keep_below, cross, true);
    const int above_hi = InterleavedMask(keep_above, cross, true);
    static_assert(sizeof below->x >= 16 * sizeof(float));  // nb <= 8 here, then eight lanes
    StoreCompact(below->x + nb, x_hi, below_hi);
    StoreCompact(below->y + nb, y_hi, below_hi);
    StoreCompact(above->x + na, x_hi, above_hi);
    StoreCompact(above->y + na, y_hi, above_hi);
    nb += std::popcount(static_cast<unsigned>(below_hi));
    na += std::popcount(static_cast<unsigned>(above_hi));
  }
  below->n = nb;
  above->n = na;
}

// |Area2(p)| of a polygon of at most eight vertices: each edge's term in lanes (lane i the edge
// from vertex i - 1, lane 0 the one from vertex n - 1), summed in Area2's order. The lanes past n
// add +0, which can change only the sign of a zero sum.
inline float AbsArea2Lanes(const Poly2& p) {
  const int n = p.n;
  SpanV8f x, y;
  std::memcpy(&x, p.x, sizeof x);
  std::memcpy(&y, p.y, sizeof y);
  const SpanV8i prev = (kSpanLane - 1) + ((kSpanLane == 0) & n);
  SpanV8f xp, yp;
  Permute8(x, prev, &xp), Permute8(y, prev, &yp);
  SpanV8f t = (xp + x) * (yp - y);
  t = (SpanV8f)((SpanV8i)t & (kSpanLane < n));
  float a = 0.0f;
  a += t[0];
  a += t[1];
  a += t[2];
  a += t[3];
  if (n > 4) {
    a += t[4];
    a += t[5];
    a += t[6];
    a += t[7];
  }
  return std::fabs(a);
}

// ClipToPyramid()'s clip of a polygon of at most eight vertices (lanes la, lb, lw) by the plane
// whose sides are ls, in lanes: the vertices inside and the crossings on the edges that leave or
// enter, in the one-vertex loop's order and with its expressions, compacted as SplitLanes()
// compacts a part. Writes the clipped polygon to a, b and w (room for kClipRoom floats each,
// stale values past its count) and returns its vertex count; -1, with nothing written, when it
// has more than kMaxPolygonVertices (the one-vertex loop drops the excess).
inline constexpr int kClipRoom = 16;
inline int ClipLanes(const SpanV8f& la, const SpanV8f& lb, const SpanV8f& lw, const SpanV8f& ls,
                     int n, float* a, float* b, float* w) {
  const SpanV8i succ = kSpanLane + 1;
  const SpanV8i next = succ & (succ != n);
  SpanV8f sj, aj, bj, wj;
  Permute8(ls, next, &sj), Permute8(la, next, &aj), Permute8(lb, next, &bj);
  Permute8(lw, next, &wj);
  const SpanV8i live = kSpanLane < n;
  const SpanV8i in = ls >= 0.0f;
  const SpanV8i cross = live & (in ^ (sj >= 0.0f));
  const SpanV8f t = ls / (ls - sj);
  const SpanV8f ca = la + t * (aj - la), cb = lb + t * (bj - lb), cw = lw + t * (wj - lw);
  const SpanV8i keep = live & in;
  const int lo = InterleavedMask(keep, cross, false);
  const int hi = n > 4 ? InterleavedMask(keep, cross, true) : 0;
  const int m_lo = std::popcount(static_cast<unsigned>(lo));
  const int m = m_lo + std::popcount(static_cast<unsigned>(hi));
  if (m > kMaxPolygonVertices) return -1;
  static_assert(kClipRoom >= 16 && kClipRoom >= kMaxPolygonVertices);  // m_lo <= 8, then eight
  StoreCompact(a, __builtin_shufflevector(la, ca, 0, 8, 1, 9, 2, 10, 3, 11), lo);
  StoreCompact(b, __builtin_shufflevector(lb, cb, 0, 8, 1, 9, 2, 10, 3, 11), lo);
  StoreCompact(w, __builtin_shufflevector(lw, cw, 0, 8, 1, 9, 2, 10, 3, 11), lo);
  if (n > 4) {
    StoreCompact(a + m_lo, __builtin_shufflevector(la, ca, 4, 12, 5, 13, 6, 14, 7, 15), hi);
    StoreCompact(b + m_lo, __builtin_shufflevector(lb, cb, 4, 12, 5, 13, 6, 14, 7, 15), hi);
    StoreCompact(w + m_lo, __builtin_shufflevector(lw, cw, 4, 12, 5, 13, 6, 14, 7, 15), hi);
  }
  return m;
}

// Clips the homogeneous polygon (a, b, w) of a face to |a| <= w, |b| <= w (its pyramid),
// through the buffers ta, tb, tw; returns the vertex count (0 when nothing is left). Each of
// the six holds kMaxPolygonVertices floats; ta, tb and tw are copied back whole, so all of
// theirs must be defined.
// kLanes: a, b and w hold eight lanes of defined values (RasterizePolygonTo's lanes) and room
// for kClipRoom floats, and a polygon of at most eight vertices has its planes' sides found
// and is clipped in lanes (ClipLanes), the same expressions.
template <bool kLanes>
inline int ClipToPyramid(float* a, float* b, float* w, int n, float* ta, float* tb, float* tw) {
  static_assert(kMaxPolygonVertices >= 8);
  // Plane i: s = w + sa * a (i = 0, 1) or w + sb * b (i = 2, 3).
  for (int plane = 0; plane < 4 && n >= 3; ++plane) {
    const float sa = plane == 0 ? 1.0f : plane == 1 ? -1.0f : 0.0f;
    const float sb = plane == 2 ? 1.0f : plane == 3 ? -1.0f : 0.0f;
    float s[kMaxPolygonVertices + 2];
    bool all_in = true;
    if (kLanes && n <= 8) {
      SpanV8f la, lb, lw;
      std::memcpy(&la, a, sizeof la);
      std::memcpy(&lb, b, sizeof lb);
      std::memcpy(&lw, w, sizeof lw);
      const SpanV8f ls = lw + sa * la + sb * lb;
      if (MaskAll((ls >= 0.0f) | (kSpanLane >= n))) continue;
      if (const int m = ClipLanes(la, lb, lw, ls, n, a, b, w); m >= 0) {
        n = m;
        continue;
      }
      std::memcpy(s, &ls, sizeof ls);
      all_in = false;
    } else {
      for (int i = 0; i < n; ++i) {
        s[i] = w[i] + sa * a[i] + sb * b[i];
        all_in &= s[i] >= 0.0f;
      }
    }
    if (all_in) continue;
    int m = 0;
    for (int i = 0; i < n; ++i) {
      const int j = i + 1 == n ? 0 : i + 1;
      const bool in_i = s[i] >= 0.0f, in_j = s[j] >= 0.0f;
      if (in_i && m < kMaxPolygonVertices) ta[m] = a[i], tb[m] = b[i], tw[m++] = w[i];
      if (in_i != in_j && m < kMaxPolygonVertices) {
        const float t = s[i] / (s[i] - s[j]);
        ta[m] = a[i] + t * (a[j] - a[i]);
        tb[m] = b[i] + t * (b[j] - b[i]);
        tw[m++] = w[i] + t * (w[j] - w[i]);
      }
    }
    // The whole buffers, in a few moves: a copy of m floats was three calls of memcpy.
    constexpr size_t kBuffer = sizeof(float) * kMaxPolygonVertices;
    std::memcpy(a, ta, kBuffer);
    std::memcpy(b, tb, kBuffer);
    std::memcpy(w, tw, kBuffer);
    n = m;
  }
  return n >= 3 ? n : 0;
}

// Coverage masks: each pixel holds kMaskSide x kMaskSide sample points at the centres of its
// sub-cells; bit j * kMaskSide + i is sample column i of sample row j. A convex polygon covers
// a sample when the sample lies between the polygon's left and right crossings of the
// sample's row. The crossings of every sample row that the polygon spans on a face are found
// once (Spans), then each covered pixel's mask is read off them (Mask).
inline constexpr int kMaskSide = 8;
struct MaskSpans {
  int row0 = 0, rows = 0;  // sample rows [row0, row0 + rows) in face-sample coordinates
  // Per sample row, the polygon's left and right crossings in face-pixel coordinates
  // (xl > xr: none).
  float xl[kMaxMaskRows], xr[kMaxMaskRows];
};

// The first row of the block of kMaskSide rows from row0 that holds row j >= row0:
// j - (j - row0) % kMaskSide, without a signed division.
inline int BlockStart(int j, int row0) { return row0 + ((j - row0) & -kMaskSide); }

// Sets every row's crossings to none.
inline void ClearSpans(int y0, int y1, MaskSpans* s) {
  const int rows = std::min((y1 - y0 + 1) * kMaskSide, kMaxMaskRows);
  s->row0 = y0 * kMaskSide;
  s->rows = rows;
  const SpanV8f none_l = {1e30f, 1e30f, 1e30f, 1e30f, 1e30f, 1e30f, 1e30f, 1e30f};
  const SpanV8f none_r = -none_l;
  for (int j = 0; j < rows; j += kMaskSide) {
    std::memcpy(s->xl + j, &none_l, sizeof none_l);
    std::memcpy(s->xr + j, &none_r, sizeof none_r);
  }
}

// The crossings of a convex polygon in face-pixel coordinates with the sample rows of pixel
// rows [y0, y1]: each edge is walked over the sample rows it crosses (two edges per row), one
// division per edge, eight rows at a time.
inline void Spans(const Poly2& p, int y0, int y1, MaskSpans* s) {
  static_assert(kMaskSide == 8);
  ClearSpans(y0, y1, s);
  // In locals: the stores to the spans would reload them through s.
  const int row0 = s->row0, rows = s->rows;
  float* xl = s->xl;
  float* xr = s->xr;
  constexpr float kSide = kMaskSide;
  for (int i = 0; i < p.n; ++i) {
    const int k = i + 1 == p.n ? 0 : i + 1;
    float ax = p.x[i], ay = p.y[i], bx = p.x[k], by = p.y[k];
    if (ay == by) continue;
    if (ay > by) std::swap(ax, bx), std::swap(ay, by);
    // Sample row j (face-sample coordinates) lies at y = (j + 0.5) / kMaskSide; the edge
    // crosses the rows with ay <= y < by.
    const int j0 = std::max(row0, CeilPos(std::max(0.0f, ay * kSide - 0.5f)));
    const int j1 = std::min(row0 + rows, CeilPos(std::max(0.0f, by * kSide - 0.5f)));
    if (j0 >= j1) continue;
    const float slope = (bx - ax) / (by - ay);
    // Rows [jb, jb + 8) from the block that holds j0; the lanes outside [j0, j1) keep theirs.
    for (int jb = BlockStart(j0, row0); jb < j1; jb += kMaskSide) {
      const SpanV8i j = jb + kSpanLane;
      const SpanV8i in = (j >= j0) & (j < j1);
      const SpanV8f y = (__builtin_convertvector(j, SpanV8f) + 0.5f) / kSide;
      const SpanV8f x = ax + (y - ay) * slope;
      SpanV8f l, r;
      std::memcpy(&l, xl + (jb - row0), sizeof l);
      std::memcpy(&r, xr + (jb - row0), sizeof r);
      // std::min(l, x) and std::max(r, x), lane by lane.
      l = (in & (x < l)) ? x : l;
      r = (in & (r < x)) ? x : r;
      std::memcpy(xl + (jb - row0), &l, sizeof l);
      std::memcpy(xr + (jb - row0), &r, sizeof r);
    }
  }
}

// The samples whose cells a convex polygon overlaps, for an upper bound of what it covers
// (PixelState::touched): per sample row's band [j, j + 1) / kMaskSide of face-pixel rows
// [y0, y1], the polygon's x-extent within the band (BandSpans, eight bands at a time), then per
// pixel the columns whose cells that extent overlaps (Touched).
inline void BandSpans(const Poly2& p, int y0, int y1, MaskSpans* s) {
  static_assert(kMaskSide == 8);
  ClearSpans(y0, y1, s);
  // In locals: the stores to the spans would reload them through s.
  const int row0 = s->row0, rows = s->rows;
  float* xl = s->xl;
  float* xr = s->xr;
  constexpr float kSide = kMaskSide;
  for (int i = 0; i < p.n; ++i) {
    const int k = i + 1 == p.n ? 0 : i + 1;
    float ax = p.x[i], ay = p.y[i], bx = p.x[k], by = p.y[k];
    if (ay > by) std::swap(ax, bx), std::swap(ay, by);
    const int j0 = std::max(row0, FloorPos(ay * kSide));
    const int j1 = std::min(row0 + rows - 1, FloorPos(by * kSide));
    if (j0 > j1) continue;
    const bool slanted = by > ay;
    const float slope = slanted ? (bx - ax) / (by - ay) : 0.0f;
    const float flat_a = std::min(ax, bx), flat_b = std::max(ax, bx);
    for (int jb = BlockStart(j0, row0); jb <= j1; jb += kMaskSide) {
      const SpanV8i j = jb + kSpanLane;
      const SpanV8i in = (j >= j0) & (j <= j1);
      const SpanV8f fj = __builtin_convertvector(j, SpanV8f);
      SpanV8f lo = fj / kSide, hi = (fj + 1.0f) / kSide;
      lo = ay < lo ? lo : ay;  // std::max(ay, lo)
      hi = hi < by ? hi : by;  // std::min(by, hi)
      SpanV8f xa, xb;
      if (slanted) {
        xa = ax + (lo - ay) * slope;
        xb = ax + (hi - ay) * slope;
      } else {
        xa = SpanV8f{flat_a, flat_a, flat_a, flat_a, flat_a, flat_a, flat_a, flat_a};
        xb = SpanV8f{flat_b, flat_b, flat_b, flat_b, flat_b, flat_b, flat_b, flat_b};
      }
      SpanV8f l, r;
      std::memcpy(&l, xl + (jb - row0), sizeof l);
      std::memcpy(&r, xr + (jb - row0), sizeof r);
      // std::min({l, xa, xb}) and std::max({r, xa, xb}): the first extreme, lane by lane.
      SpanV8f nl = xa < l ? xa : l, nr = r < xa ? xa : r;
      nl = xb < nl ? xb : nl;
      nr = nr < xb ? xb : nr;
      l = in ? nl : l;
      r = in ? nr : r;
      std::memcpy(xl + (jb - row0), &l, sizeof l);
      std::memcpy(xr + (jb - row0), &r, sizeof r);
    }
  }
}
// The columns of pixel (col, row) that each of its eight sample rows holds, in eight lanes (the
// row must lie in the spans'). kCells false: the sample points, columns i with
// xl <= col + (i + 0.5) / kMaskSide <= xr (Mask). kCells true: the sample cells
// [i, i + 1) / kMaskSide that [xl, xr] overlaps (Touched).
template <bool kCells>
inline uint64_t RowColumns(const MaskSpans& s, int col, int row) {
  typedef float V8f __attribute__((vector_size(32)));
  typedef int32_t V8i __attribute__((vector_size(32)));
  typedef uint8_t V32b __attribute__((vector_size(32)));
  typedef uint8_t V8b __attribute__((vector_size(8)));
  static_assert(kMaskSide == 8);
  V8f xl, xr;
  std::memcpy(&xl, s.xl + (row * kMaskSide - s.row0), sizeof xl);
  std::memcpy(&xr, s.xr + (row * kMaskSide - s.row0), sizeof xr);
  const float c0 = static_cast<float>(col);
  // In the pixel's sample units. Points: the first column l = ceil(a), the last h = floor(b),
  // a and b taken at the samples' centres. Cells: l = floor(a), h = ceil(b) - 1. l is clamped
  // to [0, 8], h to [-1, 7] (l = 8 or h = -1: none). The values are shifted by 2, so that
  // truncation is floor, and clamped before they are rounded, to the bounds that give those
  // columns: the same columns as clamping after rounding (rounding is monotonic and keeps
  // integers), in fewer instructions, and the conversions stay exact.
  constexpr float kShift = kCells ? 0.0f : 0.5f;
  V8f a = ((xl - c0) * 8.0f - kShift) + 2.0f, b = ((xr - c0) * 8.0f - kShift) + 2.0f;
  constexpr float kLowB = kCells ? 2.0f : 1.0f, kHighB = kCells ? 10.0f : 9.0f;
  a = a < 2.0f ? 2.0f : a;
  a = a > 10.0f ? 10.0f : a;
  b = b < kLowB ? kLowB : b;
  b = b > kHighB ? kHighB : b;
  // Truncation, and ceil from it (a true comparison is -1).
  const V8i ai = __builtin_convertvector(a, V8i), bi = __builtin_convertvector(b, V8i);
  V8i l, h;
  if constexpr (kCells) {
    l = ai - 2;
    h = bi - (__builtin_convertvector(bi, V8f) < b) - 3;
  } else {
    l = ai - (__builtin_convertvector(ai, V8f) < a) - 2;
    h = bi - 2;
  }
  // (ff << l) keeps bits past the eighth; (ff >> (7 - h)) has none.
  const V8i ff = {0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff};
  const V8i bits = (ff << l) & (ff >> (7 - h));
  const V8b bytes =
      __builtin_shufflevector(reinterpret_cast<const V32b&>(bits),
                              reinterpret_cast<const V32b&>(bits), 0, 4, 8, 12, 16, 20, 24, 28);
  uint64_t m;
  std::memcpy(&m, &bytes, sizeof m);
  return m;
}

// The coverage mask of pixel (col, row), which must lie in the spans' rows: sample column i of
// the pixel lies at x = col + (i + 0.5) / kMaskSide; a row holds the columns with
// xl <= x <= xr.
inline uint64_t Mask(const MaskSpans& s, int col, int row) {
  return RowColumns<false>(s, col, row);
}

// The samples whose cells the polygon of BandSpans() overlaps in pixel (col, row); all when none
// (a polygon whose coverage passed the sink's floor without reaching a cell: not placed).
inline uint64_t Touched(const MaskSpans& s, int col, int row) {
  const uint64_t m = RowColumns<true>(s, col, row);
  return m == 0 ? ~uint64_t{0} : m;
}

// A polygon's coverage masks and touched samples on one face, their spans found on first use:
// the rasterizer asks only in pixels that are still open (Rasterizer::Layer()), so a polygon
// whose partly covered pixels are all closed finds none.
class FaceSamples {
 public:
  FaceSamples(const Poly2& p, int y0, int y1) : p_(p), y0_(y0), y1_(y1) {}
  FaceSamples(const FaceSamples&) = delete;
  FaceSamples& operator=(const FaceSamples&) = delete;

  uint64_t Mask(int col, int row) {
    if (!have_spans_) {
      Spans(p_, y0_, y1_, &spans_);
      have_spans_ = true;
    }
    return polygon_coverage::Mask(spans_, col, row);
  }
  uint64_t Touched(int col, int row) {
    if (!have_bands_) {
      BandSpans(p_, y0_, y1_, &bands_);
      have_bands_ = true;
    }
    return polygon_coverage::Touched(bands_, col, row);
  }

 private:
  const Poly2& p_;
  const int y0_, y1_;
  bool have_spans_ = false, have_bands_ = false;
  MaskSpans spans_;  // Spans()
  MaskSpans bands_;  // BandSpans()
};

// One covered pixel's coverage mask and touched samples, computed when asked; a pixel that the
// polygon covers whole holds every sample (most of a large polygon's pixels).
class PixelSamples {
 public:
  PixelSamples(FaceSamples* face, int col, int row, bool full)
      : face_(face), col_(col), row_(row), full_(full) {}
  uint64_t mask() const { return full_ ? ~uint64_t{0} : face_->Mask(col_, row_); }
  uint64_t touched() const { return full_ ? ~uint64_t{0} : face_->Touched(col_, row_); }

 private:
  FaceSamples* face_;
  int col_, row_;
  bool full_;
};

}  // namespace polygon_coverage

namespace polygon_coverage {

// A polygon of at most eight vertices with its coordinates in lanes (lane i: vertex i), the
// lanes from n on repeating vertex 0: they change neither the polygon's faces nor its extremes.
struct VertexLanes {
  SpanV8f x, y, z;
};
// Polygon's vertices (x, y, z of vertex i at floats 3 i .. 3 i + 2) as three loads of eight
// floats (within Polygon's twelve vertices), each coordinate gathered from its lanes of the
// three loads by two blends and a permutation.
inline void LoadVertexLanes(const Polygon& p, VertexLanes* out) {
  static_assert(sizeof(glm::vec3) == 3 * sizeof(float) && kMaxPolygonVertices * 3 >= 24);
  const float* f = &p.v[0].x;
  SpanV8f l0, l1, l2;
  std::memcpy(&l0, f, sizeof l0);
  std::memcpy(&l1, f + 8, sizeof l1);
  std::memcpy(&l2, f + 16, sizeof l2);
  // Lane i of load q holds coordinate (8 q + i) % 3 of vertex (8 q + i) / 3.
  const SpanV8f tx = __builtin_shufflevector(
      __builtin_shufflevector(l0, l1, 0, 9, 2, 3, 12, 5, 6, 15), l2, 0, 1, 10, 3, 4, 13, 6, 7);
  const SpanV8f ty = __builtin_shufflevector(
      __builtin_shufflevector(l0, l1, 0, 1, 10, 3, 4, 13, 6, 7), l2, 8, 1, 2, 11, 4, 5, 14, 7);
  const SpanV8f tz = __builtin_shufflevector(
      __builtin_shufflevector(l0, l1, 8, 1, 2, 11, 4, 5, 14, 7), l2, 0, 9, 2, 3, 12, 5, 6, 15);
  VertexLanes& v = *out;
  v.x = __builtin_shufflevector(tx, tx, 0, 3, 6, 1, 4, 7, 2, 5);
  v.y = __builtin_shufflevector(ty, ty, 1, 4, 7, 2, 5, 0, 3, 6);
  v.z = __builtin_shufflevector(tz, tz, 2, 5, 0, 3, 6, 1, 4, 7);
  const SpanV8i keep = kSpanLane < p.n;
  v.x = keep ? v.x : __builtin_shufflevector(v.x, v.x, 0, 0, 0, 0, 0, 0, 0, 0);
  v.y = keep ? v.y : __builtin_shufflevector(v.y, v.y, 0, 0, 0, 0, 0, 0, 0, 0);
  v.z = keep ? v.z : __builtin_shufflevector(v.z, v.z, 0, 0, 0, 0, 0, 0, 0, 0);
}

// The cube face of each vertex, as RasterizePolygonTo's one-vertex form: its largest |coordinate|
// (x before y before z on ties) and that coordinate's sign.
inline void VertexFaces(const VertexLanes& v, SpanV8i* faces) {
  // |x| by clearing the sign bit.
  const SpanV8i abs_bits = SpanV8i{} + 0x7fffffff;
  const SpanV8f ax = (SpanV8f)((SpanV8i)v.x & abs_bits), ay = (SpanV8f)((SpanV8i)v.y & abs_bits),
                az = (SpanV8f)((SpanV8i)v.z & abs_bits);
  const SpanV8i face = SpanV8i{};
  const SpanV8i fx = v.x < 0.0f ? face + 1 : face;
  const SpanV8i fy = v.y < 0.0f ? face + 3 : face + 2;
  const SpanV8i fz = v.z < 0.0f ? face + 5 : face + 4;
  *faces = ax >= ay ? (ax >= az ? fx : fz) : (ay >= az ? fy : fz);
}

// Whether any lane of a comparison's mask is true.
inline bool MaskAny(const SpanV8i& m) {
  return Movemask4(__builtin_shufflevector(m, m, 0, 1, 2, 3) |
                   __builtin_shufflevector(m, m, 4, 5, 6, 7)) != 0;
}

// The least and greatest of the eight lanes of x and of y (no lane NaN, none -0: then any order
// of comparisons finds std::min's and std::max's values), x's and y's halves side by side.
inline void LaneExtremes(const SpanV8f& x, const SpanV8f& y, float* minx, float* maxx, float* miny,
                         float* maxy) {
  const SpanV8f a = __builtin_shufflevector(x, y, 0, 1, 2, 3, 8, 9, 10, 11);
  const SpanV8f b = __builtin_shufflevector(x, y, 4, 5, 6, 7, 12, 13, 14, 15);
  SpanV8f lo = a < b ? a : b, hi = a > b ? a : b;
  SpanV8f t = __builtin_shufflevector(lo, lo, 2, 3, 0, 1, 6, 7, 4, 5);
  lo = lo < t ? lo : t;
  t = __builtin_shufflevector(hi, hi, 2, 3, 0, 1, 6, 7, 4, 5);
  hi = hi > t ? hi : t;
  t = __builtin_shufflevector(lo, lo, 1, 0, 3, 2, 5, 4, 7, 6);
  lo = lo < t ? lo : t;
  t = __builtin_shufflevector(hi, hi, 1, 0, 3, 2, 5, 4, 7, 6);
  hi = hi > t ? hi : t;
  *minx = lo[0], *miny = lo[4], *maxx = hi[0], *maxy = hi[4];
}

// A face's polygon in face-pixel coordinates and its extent there.
struct FacePoly {
  Poly2 whole;
  float minx, maxx, miny, maxy;
};

// The face-pixel coordinates of the homogeneous polygon (a, b, w) of a face: (a / w + 1) * half,
// clamped to [0, res]. False when a vertex lies at the apex (w <= 0: the polygon passes through
// the receiver).
inline bool Project(const float* a, const float* b, const float* w, int n, int res, FacePoly* out) {
  const float half = 0.5f * static_cast<float>(res);
  Poly2& whole = out->whole;
  whole.n = n;
  float* xs = whole.x;
  float* ys = whole.y;
  float minx = 1e30f, maxx = -1e30f, miny = 1e30f, maxy = -1e30f;
  const float top = static_cast<float>(res);
  for (int i = 0; i < n; ++i) {
    if (!(w[i] > 0.0f)) return false;
    const float inv = 1.0f / w[i];
    xs[i] = std::min(top, std::max(0.0f, (a[i] * inv + 1.0f) * half));
    ys[i] = std::min(top, std::max(0.0f, (b[i] * inv + 1.0f) * half));
    minx = std::min(minx, xs[i]), maxx = std::max(maxx, xs[i]);
    miny = std::min(miny, ys[i]), maxy = std::max(maxy, ys[i]);
  }
  out->minx = minx, out->maxx = maxx, out->miny = miny, out->maxy = maxy;
  return true;
}
// Project() in lanes, for a polygon of at most eight vertices (VertexLanes): the same
// expressions lane by lane (std::min and std::max as their selects). The extremes are the
// same values: no lane is NaN (a NaN coordinate projects to 0, as std::max(0.0f, NaN) does)
// nor -0.
inline bool ProjectLanes(const SpanV8f& a, const SpanV8f& b, const SpanV8f& w, int n, int res,
                         FacePoly* out) {
  if (MaskAny(!(w > 0.0f))) return false;
  const float half = 0.5f * static_cast<float>(res);
  const float top = static_cast<float>(res);
  const SpanV8f inv = 1.0f / w;
  SpanV8f xs = (a * inv + 1.0f) * half, ys = (b * inv + 1.0f) * half;
  xs = 0.0f < xs ? xs : 0.0f;  // std::max(0.0f, x)
  ys = 0.0f < ys ? ys : 0.0f;
  xs = xs < top ? xs : top;  // std::min(top, x)
  ys = ys < top ? ys : top;
  Poly2& whole = out->whole;
  whole.n = n;
  static_assert(sizeof whole.x >= sizeof xs);
  std::memcpy(whole.x, &xs, sizeof xs);
  std::memcpy(whole.y, &ys, sizeof ys);
  LaneExtremes(xs, ys, &out->minx, &out->maxx, &out->miny, &out->maxy);
  return true;
}

}  // namespace polygon_coverage

// RasterizePolygonTo() below. kLanes: a polygon of up to eight vertices has its faces found,
// its faces rejected and clipped and its projection made in eight lanes (the rasterizer's AVX2
// build, Rasterizer::Finish); false: one vertex at a time (the baseline ISA's form, where eight
// lanes are two SSE2 vectors and their shuffles cost more; the form that the lanes' must match,
// tests/raster/polygon_test.cc), as it is for a polygon of more than eight vertices.
template <bool kLanes, class Sink, class Skip>
inline void RasterizePolygonIn(const Polygon& p, int res, std::vector<float>* acc, Sink&& sink,
                               Skip&& skip) {
  using namespace polygon_coverage;  // NOLINT(build/namespaces): this file's own helpers

  if (p.n < 3) return;
  // Whether the sink takes a pixel's samples (PixelSamples) as a third argument.
  constexpr bool kSamples = std::is_invocable_v<Sink, uint32_t, float, const PixelSamples&>;
  // Up to eight vertices (almost every footprint) in lanes, one coordinate per vector.
  const bool lanes = kLanes && p.n <= 8;
  VertexLanes v;
  // The face of each vertex; a polygon whose vertices all lie in one face's pyramid lies in it
  // (the pyramid is convex) and needs no clipping.
  int home = -1;
  bool one_face = true;
  if (lanes) {
    LoadVertexLanes(p, &v);
    SpanV8i faces;
    VertexFaces(v, &faces);
    home = faces[0];
    one_face = MaskAll(faces == home);
  } else {
    for (int i = 0; i < p.n && one_face; ++i) {
      const glm::vec3& x = p.v[i];
      const float ax = std::fabs(x.x), ay = std::fabs(x.y), az = std::fabs(x.z);
      const int f = ax >= ay ? (ax >= az ? (x.x < 0.0f ? 1 : 0) : (x.z < 0.0f ? 5 : 4))
                             : (ay >= az ? (x.y < 0.0f ? 3 : 2) : (x.z < 0.0f ? 5 : 4));
      if (home < 0) home = f;
      one_face = f == home;
    }
  }
  const float* coords = &p.v[0].x;  // x, y, z of vertex i at 3 i .. 3 i + 2
  static_assert(sizeof(glm::vec3) == 3 * sizeof(float));
  // The -z face lies below the horizon, which the caller clipped away.
  const int f_first = one_face ? home : 0, f_last = one_face ? home : 4;
  for (int f = f_first; f <= f_last; ++f) {
    const int k = f / 2;
    const float sign = (f % 2) ? -1.0f : 1.0f;
    // The face's homogeneous coordinates: (a, b) / w is the point on the face's plane (with
    // room for ClipToPyramid's lanes).
    float a[kClipRoom], b[kClipRoom], w[kClipRoom];
    int n = p.n;
    // The polygon in the face's pixel coordinates.
    FacePoly face;
    if (lanes) {
      const SpanV8f la = k == 0 ? v.y : v.x, lb = k == 2 ? v.y : v.z;
      const SpanV8f lw = sign * (k == 0 ? v.x : k == 1 ? v.y : v.z);
      if (one_face) {
        if (!ProjectLanes(la, lb, lw, n, res, &face)) continue;
      } else {
        // Rejected at once when every vertex lies outside one side of the face's pyramid.
        if (MaskAll(lw + la < 0.0f) || MaskAll(lw - la < 0.0f) || MaskAll(lw + lb < 0.0f) ||
            MaskAll(lw - lb < 0.0f)) {
          continue;
        }
        static_assert(sizeof a >= sizeof la);
        std::memcpy(a, &la, sizeof la);
        std::memcpy(b, &lb, sizeof lb);
        std::memcpy(w, &lw, sizeof lw);
        float ta[kMaxPolygonVertices] = {}, tb[kMaxPolygonVertices] = {},
              tw[kMaxPolygonVertices] = {};
        n = ClipToPyramid<true>(a, b, w, n, ta, tb, tw);
        if (n < 3) continue;
        if (n <= 8) {
          // Projected in lanes too, the lanes past n repeating vertex 0 as LoadVertexLanes'
          // do (ClipLanes leaves other values there).
          SpanV8f ca, cb, cw;
          std::memcpy(&ca, a, sizeof ca);
          std::memcpy(&cb, b, sizeof cb);
          std::memcpy(&cw, w, sizeof cw);
          const SpanV8i keep = kSpanLane < n;
          ca = keep ? ca : __builtin_shufflevector(ca, ca, 0, 0, 0, 0, 0, 0, 0, 0);
          cb = keep ? cb : __builtin_shufflevector(cb, cb, 0, 0, 0, 0, 0, 0, 0, 0);
          cw = keep ? cw : __builtin_shufflevector(cw, cw, 0, 0, 0, 0, 0, 0, 0, 0);
          if (!ProjectLanes(ca, cb, cw, n, res, &face)) continue;
        } else if (!Project(a, b, w, n, res, &face)) {
          continue;
        }
      }
    } else {
      // One loop per axis: with constant offsets the copy is a third of the instructions.
      auto copy = [&](int o1, int o2, int o) [[gnu::always_inline]] {
        for (int i = 0; i < n; ++i) {
          a[i] = coords[3 * i + o1], b[i] = coords[3 * i + o2], w[i] = sign * coords[3 * i + o];
        }
      };
      if (k == 0) {
        copy(1, 2, 0);
      } else if (k == 1) {
        copy(0, 2, 1);
      } else {
        copy(0, 1, 2);
      }
      if (!one_face) {
        // Rejected at once when every vertex lies outside one side of the face's pyramid.
        bool out_lo1 = true, out_hi1 = true, out_lo2 = true, out_hi2 = true;
        for (int i = 0; i < n; ++i) {
          out_lo1 &= w[i] + a[i] < 0.0f, out_hi1 &= w[i] - a[i] < 0.0f;
          out_lo2 &= w[i] + b[i] < 0.0f, out_hi2 &= w[i] - b[i] < 0.0f;
        }
        if (out_lo1 || out_hi1 || out_lo2 || out_hi2) continue;
        float ta[kMaxPolygonVertices] = {}, tb[kMaxPolygonVertices] = {},
              tw[kMaxPolygonVertices] = {};
        n = ClipToPyramid<false>(a, b, w, n, ta, tb, tw);
        if (n < 3) continue;
      }
      if (!Project(a, b, w, n, res, &face)) continue;
    }
    // The face-pixel coordinates, in the layout Split() and Area2() take.
    const Poly2& whole = face.whole;
    const float* xs = whole.x;
    const float* ys = whole.y;
    const float minx = face.minx, maxx = face.maxx, miny = face.miny, maxy = face.maxy;
    const int x0 = std::min(res - 1, static_cast<int>(minx));
    const int x1 = std::min(res - 1, static_cast<int>(maxx));
    const int y0 = std::min(res - 1, static_cast<int>(miny));
    const int y1 = std::min(res - 1, std::max(y0, CeilPos(maxy) - 1));
    const uint32_t base = static_cast<uint32_t>(f * res * res);
    if (skip(base, x0, x1, y0, y1)) continue;
    // A sink that takes a third argument gets each pixel's samples, their spans on the face
    // found when first needed.
    FaceSamples samples(whole, y0, y1);
    auto emit = [&](int col, int row, float area2) {
      const float cov = std::min(1.0f, 0.5f * std::fabs(area2));
      if (!(cov > 1e-6f)) return;
      const uint32_t pixel = base + static_cast<uint32_t>(row * res + col);
      if constexpr (kSamples) {
        sink(pixel, cov, PixelSamples(&samples, col, row, /*full=*/!(cov < 1.0f)));
      } else {
        sink(pixel, cov);
      }
    };
    if (x1 - x0 <= 1 && y1 - y0 <= 1) {
      // Within a 2 x 2 block of pixels (most far footprints): the exact areas of the polygon's
      // parts on either side of the block's middle lines.
      // With kLanes, a part of at most eight vertices is split and measured in lanes (the
      // same parts and |areas|, which is all that emit() takes).
      auto area2 = [](const Poly2& q) {
        if constexpr (kLanes) {
          if (q.n <= 8) return AbsArea2Lanes(q);
        }
        return Area2(q);
      };
      auto split = [](const Poly2& q, int coord, float at, Poly2* below, Poly2* above) {
        if constexpr (kLanes) {
          if (q.n <= 8) return SplitLanes(q, coord, at, below, above);
        }
        Split(q, coord, at, below, above);
      };
      if (x1 == x0 && y1 == y0) {
        emit(x0, y0, area2(whole));  // inside one pixel
        continue;
      }
      Poly2 parts[2];
      const Poly2* cols[2] = {&whole, nullptr};
      int nc = 1;
      if (x1 > x0) {
        split(whole, 0, static_cast<float>(x1), &parts[0], &parts[1]);
        cols[0] = &parts[0], cols[1] = &parts[1];
        nc = 2;
      }
      for (int ci = 0; ci < nc; ++ci) {
        const Poly2& col = *cols[ci];
        if (col.n < 3) continue;
        if (y1 > y0) {
          Poly2 lo, hi;
          split(col, 1, static_cast<float>(y1), &lo, &hi);
          if (lo.n >= 3) emit(x0 + ci, y0, area2(lo));
          if (hi.n >= 3) emit(x0 + ci, y1, area2(hi));
        } else {
          emit(x0 + ci, y0, area2(col));
        }
      }
      continue;
    }
    const int cw = x1 - x0 + 2, h = y1 - y0 + 1;
    // Most footprints span a few pixels: their buffer lives on the stack.
    constexpr int kSmall = 64;
    float small[kSmall];
    float* buf = small;
    const size_t cells = size_t(cw) * size_t(h);
    if (cells <= size_t(kSmall)) {
      std::fill(small, small + cells, 0.0f);
    } else {
      acc->assign(cells, 0.0f);
      buf = acc->data();
    }
    Accumulate(xs, ys, n, x0, y0, cw, h, buf);
    for (int r = 0; r < h; ++r) {
      const float* row = buf + size_t(r) * size_t(cw);
      float sum = 0.0f;
      for (int c = 0; c < cw - 1; ++c) {
        sum += row[c];
        emit(x0 + c, y0 + r, 2.0f * sum);
      }
    }
  }
}

// RasterizePolygon() (raster/polygon.h) with each covered pixel passed to sink(pixel, coverage)
// in the same order as RasterizePolygon() appends them. A sink may take a third argument, a
// PixelSamples that computes the pixel's coverage mask or the samples whose cells the polygon
// overlaps when asked. Except on a face where
// skip(first, col0, col1, row0, row1) says that the pixels first + row * res + col of the
// polygon's bounding rectangle there need none (the caller's pixels that a fragment cannot
// change): its coverage is not computed.
template <class Sink, class Skip>
inline void RasterizePolygonTo(const Polygon& p, int res, std::vector<float>* acc, Sink&& sink,
                               Skip&& skip) {
  RasterizePolygonIn</*kLanes=*/false>(p, res, acc, sink, skip);
}

template <class Sink>
inline void RasterizePolygonTo(const Polygon& p, int res, std::vector<float>* acc, Sink&& sink) {
  RasterizePolygonTo(p, res, acc, sink, [](uint32_t, int, int, int, int) { return false; });
}

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_POLYGON_COVERAGE_H_
