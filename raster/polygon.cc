// Convex polygons on the micro-buffer (see polygon.h).
#include "raster/polygon.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "base/math.h"
#include "glm/geometric.hpp"
#include "raster/polygon_coverage.h"
#include "raster/simd.h"

namespace pbgi::internal {
namespace {

// Sutherland-Hodgman against {x : s(x) >= 0} for an affine s given by its values at the
// vertices.
template <class Side>
void Clip(Polygon* p, Side&& side) {
  if (p->n == 0) return;
  float s[kMaxPolygonVertices];
  bool all_in = true, all_out = true;
  for (int i = 0; i < p->n; ++i) {
    s[i] = side(p->v[i]);
    all_in &= s[i] >= 0.0f;
    all_out &= s[i] < 0.0f;
  }
  if (all_in) return;
  if (all_out) {
    p->n = 0;
    return;
  }
  Polygon q;
  for (int i = 0; i < p->n; ++i) {
    const int j = i + 1 == p->n ? 0 : i + 1;
    const bool in_i = s[i] >= 0.0f, in_j = s[j] >= 0.0f;
    if (in_i && q.n < kMaxPolygonVertices) q.v[q.n++] = p->v[i];
    if (in_i != in_j && q.n < kMaxPolygonVertices) {
      const float t = s[i] / (s[i] - s[j]);
      q.v[q.n++] = p->v[i] + t * (p->v[j] - p->v[i]);
    }
  }
  *p = q;
  if (p->n < 3) p->n = 0;
}

}  // namespace

void PlaneBoxPolygon(const glm::vec3& normal, float offset, const glm::vec3& lo,
                     const glm::vec3& hi, Polygon* out) {
  out->n = 0;
  glm::vec3 blo = lo, bhi = hi;
  const glm::vec3 ext = hi - lo;
  const float big = std::max(ext.x, std::max(ext.y, ext.z));
  if (!(big > 0.0f) || !std::isfinite(big)) return;
  for (int k = 0; k < 3; ++k) {
    const float pad = std::max(0.0f, 5e-5f * big - 0.5f * ext[k]);
    blo[k] -= pad, bhi[k] += pad;
  }
  // A plane along an axis (walls, floors): the box's cross-section is a rectangle.
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
    if (normal[k1] != 0.0f || normal[k2] != 0.0f || normal[k] == 0.0f) continue;
    const float at = offset / normal[k];
    if (!(at >= blo[k] && at <= bhi[k])) return;
    out->n = 4;
    for (int j = 0; j < 4; ++j) {
      out->v[j][k] = at;
      out->v[j][k1] = (j == 1 || j == 2) ? bhi[k1] : blo[k1];
      out->v[j][k2] = (j >= 2) ? bhi[k2] : blo[k2];
    }
    return;
  }
  // The plane's crossings of the box's 12 edges (corner i has bit k set where it is at bhi[k]),
  // then ordered by angle around their mean in the plane.
  // s[i] = dot(normal, corner i) - offset from six products (the same sums, in glm::dot's
  // order).
  const float px[2] = {normal.x * blo.x, normal.x * bhi.x};
  const float py[2] = {normal.y * blo.y, normal.y * bhi.y};
  const float pz[2] = {normal.z * blo.z, normal.z * bhi.z};
  float s[8];
  glm::vec3 c[8];
  for (int i = 0; i < 8; ++i) {
    c[i] = glm::vec3((i & 1) ? bhi.x : blo.x, (i & 2) ? bhi.y : blo.y, (i & 4) ? bhi.z : blo.z);
    s[i] = px[i & 1] + py[(i >> 1) & 1] + pz[i >> 2] - offset;
  }
  glm::vec3 pts[12];
  int n = 0;
  for (int k = 0; k < 3; ++k) {
    const int bit = 1 << k;
    for (int i = 0; i < 8; ++i) {
      if (i & bit) continue;
      const int j = i | bit;
      const bool in_i = s[i] >= 0.0f, in_j = s[j] >= 0.0f;
      if (in_i == in_j) continue;
      const float t = s[i] / (s[i] - s[j]);
      pts[n++] = c[i] + t * (c[j] - c[i]);
    }
  }
  if (n < 3) return;
  glm::vec3 mean(0.0f);
  for (int i = 0; i < n; ++i) mean += pts[i];
  mean /= static_cast<float>(n);
  glm::vec3 u, v;
  OrthonormalBasis(normal, &u, &v);
  float key[12];
  for (int i = 0; i < n; ++i) {
    // A pseudo-angle in [0, 4): monotonic in the angle, no trigonometry.
    const glm::vec3 d = pts[i] - mean;
    const float x = glm::dot(d, u), y = glm::dot(d, v);
    const float r = std::fabs(x) + std::fabs(y);
    const float a = r > 0.0f ? y / r : 0.0f;
    key[i] = x >= 0.0f ? (a < 0.0f ? 4.0f + a : a) : 2.0f - a;
  }
  for (int i = 1; i < n; ++i) {
    const float k = key[i];
    const glm::vec3 p = pts[i];
    int j = i - 1;
    for (; j >= 0 && key[j] > k; --j) key[j + 1] = key[j], pts[j + 1] = pts[j];
    key[j + 1] = k, pts[j + 1] = p;
  }
  // A corner on the plane is the crossing of several edges: keep it once.
  out->n = 0;
  for (int i = 0; i < n; ++i) {
    if (out->n > 0 && pts[i] == out->v[out->n - 1]) continue;
    out->v[out->n++] = pts[i];
  }
  if (out->n > 1 && out->v[0] == out->v[out->n - 1]) --out->n;
  if (out->n < 3) out->n = 0;
}

void ClipHalfSpace(const glm::vec3& m, Polygon* p) {
  Clip(p, [&](const glm::vec3& x) { return glm::dot(m, x); });
}

void ClipHalfSpace(const glm::vec3& m, float c, Polygon* p) {
  Clip(p, [&](const glm::vec3& x) { return glm::dot(m, x) - c; });
}

double PolygonArea(const Polygon& p) {
  // The sum of glm::cross(v[i], v[i + 1]) in doubles: two cross products at a time in lanes
  // (glm::cross's expressions lane by lane), added one at a time in order, so the same doubles
  // as one glm::cross at a time.
  typedef double V2d __attribute__((vector_size(16)));
  const int n = p.n;
  // The vertices by component; vertex n is vertex 0, and n + 1 (read by the last pair's second
  // lane when n is odd) is defined and not summed.
  constexpr int kPadded = kMaxPolygonVertices + 2;
  double x[kPadded], y[kPadded], z[kPadded];
  for (int i = 0; i < n; ++i) x[i] = p.v[i].x, y[i] = p.v[i].y, z[i] = p.v[i].z;
  if (n > 0) x[n] = x[0], y[n] = y[0], z[n] = z[0];
  x[n + 1] = 0.0, y[n + 1] = 0.0, z[n + 1] = 0.0;
  glm::dvec3 s(0.0);
  for (int i = 0; i < n; i += 2) {
    auto load = [](const double* a) {
      V2d v;
      std::memcpy(&v, a, sizeof v);
      return v;
    };
    const V2d ax = load(x + i), ay = load(y + i), az = load(z + i);
    const V2d bx = load(x + i + 1), by = load(y + i + 1), bz = load(z + i + 1);
    const V2d cx = ay * bz - by * az, cy = az * bx - bz * ax, cz = ax * by - bx * ay;
    s += glm::dvec3(cx[0], cy[0], cz[0]);
    if (i + 1 < n) s += glm::dvec3(cx[1], cy[1], cz[1]);
  }
  return 0.5 * glm::length(s);
}

// The outline's edges are the box's edges between a face in `faces` and one not in it, so its
// cone from the origin is the union of the faces' cones; consecutive equal vertices (a box flat
// along an axis) are dropped.
void BoxSilhouette(const glm::vec3& lo, const glm::vec3& hi, int faces, Polygon* out) {
  out->n = 0;
  int axes[3], count = 0, others[3], other_count = 0;
  for (int k = 0; k < 3; ++k) {
    if (faces & (1 << k)) {
      axes[count++] = k;
    } else {
      others[other_count++] = k;
    }
  }
  if (count == 0) return;
  // By axis in arrays: a glm::vec3 indexed by a variable is a switch.
  const float l[3] = {lo.x, lo.y, lo.z}, h[3] = {hi.x, hi.y, hi.z};
  // near_side[k]: the coordinate of the seen face across axis k; far_side[k]: the opposite side.
  float near_side[3], far_side[3];
  for (int k = 0; k < 3; ++k) {
    const bool at_lo = l[k] > 0.0f;
    near_side[k] = at_lo ? l[k] : h[k];
    far_side[k] = at_lo ? h[k] : l[k];
  }
  glm::vec3 v[6];
  int n = 0;
  auto put = [&](const float* p) { v[n++] = glm::vec3(p[0], p[1], p[2]); };
  if (count == 1) {
    // One face: its rectangle.
    const int k = axes[0], k1 = (k + 1) % 3, k2 = (k + 2) % 3;
    for (int j = 0; j < 4; ++j) {
      float p[3];
      p[k] = near_side[k];
      p[k1] = (j == 1 || j == 2) ? h[k1] : l[k1];
      p[k2] = (j >= 2) ? h[k2] : l[k2];
      put(p);
    }
  } else if (count == 2) {
    // Two faces a and b sharing the edge along c: each face's far edge, joined along c.
    const int a = axes[0], b = axes[1], c = others[0];
    float p[3];
    p[a] = near_side[a], p[b] = far_side[b], p[c] = l[c];
    put(p);
    p[b] = near_side[b];
    put(p);
    p[a] = far_side[a];
    put(p);
    p[c] = h[c];
    put(p);
    p[a] = near_side[a];
    put(p);
    p[b] = far_side[b];
    put(p);
  } else {
    // Three faces around the nearest corner: the six corners that differ from it along one or
    // two axes, alternately.
    for (int j = 0; j < 6; ++j) {
      const int k = j / 2;
      float p[3] = {near_side[0], near_side[1], near_side[2]};
      p[k] = far_side[k];
      if (j % 2 == 1) p[(k + 1) % 3] = far_side[(k + 1) % 3];
      put(p);
    }
  }
  for (int i = 0; i < n; ++i) {
    if (out->n > 0 && v[i] == out->v[out->n - 1]) continue;
    out->v[out->n++] = v[i];
  }
  if (out->n > 1 && out->v[0] == out->v[out->n - 1]) --out->n;
  if (out->n < 3) out->n = 0;
}

void BoxDotRange(const Bounds& b, const glm::vec3& n, const glm::vec3& o, float* lo, float* hi) {
  float tl[3], th[3];
  for (int k = 0; k < 3; ++k) {
    const float u = n[k] * (b.lo[k] - o[k]), v = n[k] * (b.hi[k] - o[k]);
    tl[k] = std::min(u, v);
    th[k] = std::max(u, v);
  }
  *lo = tl[0] + tl[1] + tl[2];
  *hi = th[0] + th[1] + th[2];
}

float ConeSolidAngle(const Polygon& p) {
  if (p.n < 3) return 0.0f;
  // A fan of triangles from vertex 0, each tan(omega / 2) = N / D (Van Oosterom and Strackee):
  // N = a . (b x c), from the edges b - a and c - a so that a small far polygon keeps its
  // digits, D = |a||b||c| + (a.b)|c| + (a.c)|b| + (b.c)|a|. The half angles add up, so the
  // product of the complex numbers D + iN has the total's half angle as its argument: one atan2
  // for the polygon. Each factor is scaled to a largest part of 1 (no overflow).
  // N and D of four triangles at a time (SSE2), each lane glm's expressions in glm's order
  // (glm::length, glm::cross, glm::dot): the same floats as one triangle at a time.
  const int n = p.n;
  // The vertices by component, zero past n (lanes past the last triangle read them).
  constexpr int kPadded = kMaxPolygonVertices + 4;
  float x[kPadded] = {}, y[kPadded] = {}, z[kPadded] = {}, len[kPadded] = {};
  for (int i = 0; i < n; ++i) x[i] = p.v[i].x, y[i] = p.v[i].y, z[i] = p.v[i].z;
  for (int i = 0; i < n; i += 4) {
    const V4 vx = Load4(x + i), vy = Load4(y + i), vz = Load4(z + i);
    Store4(len + i, Sqrt4(vx * vx + vy * vy + vz * vz));
  }
  const V4 ax = Splat4(x[0]), ay = Splat4(y[0]), az = Splat4(z[0]), la = Splat4(len[0]);
  float num[kMaxPolygonVertices], den[kMaxPolygonVertices];
  for (int j = 0; j < n - 2; j += 4) {
    // Triangles (a, b, c) = (v0, v[1 + j + lane], v[2 + j + lane]).
    const V4 bx = Load4(x + 1 + j), by = Load4(y + 1 + j), bz = Load4(z + 1 + j);
    const V4 cx = Load4(x + 2 + j), cy = Load4(y + 2 + j), cz = Load4(z + 2 + j);
    const V4 lb = Load4(len + 1 + j), lc = Load4(len + 2 + j);
    const V4 ux = bx - ax, uy = by - ay, uz = bz - az;
    const V4 wx = cx - ax, wy = cy - ay, wz = cz - az;
    const V4 crx = uy * wz - wy * uz, cry = uz * wx - wz * ux, crz = ux * wy - wx * uy;
    Store4(num + j, ax * crx + ay * cry + az * crz);
    const V4 dab = ax * bx + ay * by + az * bz;
    const V4 dac = ax * cx + ay * cy + az * cz;
    const V4 dbc = bx * cx + by * cy + bz * cz;
    Store4(den + j, la * lb * lc + dab * lc + dac * lb + dbc * la);
  }
  float re = 1.0f, im = 0.0f, orient = 0.0f;
  for (int i = 0; i < n - 2; ++i) {
    const float nu = num[i], de = den[i];
    const float big = std::max(std::fabs(nu), std::fabs(de));
    if (!(big > 0.0f)) continue;
    const float zr = de / big, zi = nu / big;
    const float r = re * zr - im * zi;
    im = re * zi + im * zr;
    re = r;
    orient += nu;
  }
  if (orient < 0.0f) im = -im;  // the vertices turn clockwise seen from the origin
  float half = std::atan2(im, re);
  // The total is below 2 pi (a convex cone): a negative argument is a half angle just below pi
  // that rounding took past it, or a rounding error around 0.
  if (half < 0.0f) half = re < 0.0f ? half + 2.0f * kPiFloat : 0.0f;
  return 2.0f * half;
}

void RasterizePolygon(const Polygon& p, int res, std::vector<float>* acc,
                      std::vector<PixelCoverage>* out) {
  RasterizePolygonTo(p, res, acc, [out](uint32_t pixel, float cov) {
    out->push_back({pixel, cov});
  });
}

}  // namespace pbgi::internal
