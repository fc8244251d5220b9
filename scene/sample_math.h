// Small sampling helpers shared by the sampler, the lighting function and the reference
// integrator: counter-based random numbers (so any sample can be computed on its own, on any
// thread), a rotated Hammersley set, area-preserving square-to-triangle and cosine-weighted
// hemisphere maps.
#ifndef PBGI_SCENE_SAMPLE_MATH_H_
#define PBGI_SCENE_SAMPLE_MATH_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "base/math.h"
#include "glm/geometric.hpp"
#include "glm/mat4x4.hpp"
#include "glm/vec2.hpp"
#include "glm/vec3.hpp"

namespace pbgi::internal {

// SplitMix64's finalizer: a bijective 64-bit mix.
inline uint64_t Mix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

inline uint64_t HashCombine(uint64_t a, uint64_t b) { return Mix64(a ^ Mix64(b)); }

// A uniform float in [0, 1) from the top 24 bits.
inline float ToUnitFloat(uint64_t bits) {
  return static_cast<float>(bits >> 40) * (1.0f / 16777216.0f);
}

// Counter-based stream: the i-th number of stream `key`.
inline float Random(uint64_t key, uint64_t i) { return ToUnitFloat(HashCombine(key, i)); }

// Van der Corput radical inverse in base 2, in [0, 1).
inline float RadicalInverse2(uint32_t i) {
  i = (i << 16) | (i >> 16);
  i = ((i & 0x00ff00ffu) << 8) | ((i & 0xff00ff00u) >> 8);
  i = ((i & 0x0f0f0f0fu) << 4) | ((i & 0xf0f0f0f0u) >> 4);
  i = ((i & 0x33333333u) << 2) | ((i & 0xccccccccu) >> 2);
  i = ((i & 0x55555555u) << 1) | ((i & 0xaaaaaaaau) >> 1);
  return static_cast<float>(i >> 8) * (1.0f / 16777216.0f);
}

inline float Wrap01(float x) {
  x -= std::floor(x);
  return x < 1.0f ? x : 0.0f;
}

// Point j of an n-point Hammersley set, toroidally shifted by (r0, r1) (Cranley-Patterson
// rotation keeps the set stratified and makes it unbiased).
inline glm::vec2 RotatedHammersley(uint64_t j, uint64_t n, float r0, float r1) {
  double u = (static_cast<double>(j) + 0.5) / static_cast<double>(n);
  return {Wrap01(static_cast<float>(u) + r0),
          Wrap01(RadicalInverse2(static_cast<uint32_t>(j)) + r1)};
}

// Barycentrics (b0, b1) of a uniform point in a triangle from a point of the unit square,
// area-preserving and with low distortion (Heitz, "A Low-Distortion Map Between Triangle and
// Square", 2019), so stratification in the square survives in the triangle.
inline glm::vec2 SquareToTriangle(glm::vec2 u) {
  if (u.y > u.x) {
    float b0 = 0.5f * u.x;
    return {b0, u.y - b0};
  }
  float b1 = 0.5f * u.y;
  return {u.x - b1, b1};
}

inline glm::vec3 TrianglePoint(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c,
                               glm::vec2 u) {
  glm::vec2 bc = SquareToTriangle(u);
  return a * (1.0f - bc.x - bc.y) + b * bc.x + c * bc.y;
}

// The triangle's longest edge: (p[e], p[(e + 1) % 3]), its opposite vertex p[(e + 2) % 3].
inline int LongestEdge(const glm::dvec3 p[3]) {
  const double l0 = glm::dot(p[1] - p[0], p[1] - p[0]);
  const double l1 = glm::dot(p[2] - p[1], p[2] - p[1]);
  const double l2 = glm::dot(p[0] - p[2], p[0] - p[2]);
  return l0 >= l1 && l0 >= l2 ? 0 : (l1 >= l2 ? 1 : 2);
}

// The centroid of piece j of a partition of triangle (a, b, c) into k pieces of equal area:
// the longest edge is cut where it splits the area k/2 : k - k/2, a line from the opposite
// vertex, and each side is cut again for its share. The pieces are as compact as the triangle
// allows, so a small triangle (a forest's leaf holds one to three surfels) gets its disks where
// they cover it best; a rotated Hammersley set of so few points puts two in one corner, or a
// disk far over an edge, as often as not (tests/scene/sampler_test.cc measures both).
inline glm::vec3 EqualAreaPiecePoint(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c,
                                     uint64_t j, uint64_t k) {
  glm::dvec3 p[3] = {glm::dvec3(a), glm::dvec3(b), glm::dvec3(c)};
  while (k > 1) {
    const int e = LongestEdge(p);
    const glm::dvec3 u = p[e], v = p[(e + 1) % 3], o = p[(e + 2) % 3];
    const uint64_t k1 = k / 2;
    const glm::dvec3 m = u + (v - u) * (static_cast<double>(k1) / static_cast<double>(k));
    if (j < k1) {  // the piece (u, m, o): k1 / k of the area
      p[0] = u;
      p[1] = m;
      p[2] = o;
      k = k1;
    } else {
      p[0] = m;
      p[1] = v;
      p[2] = o;
      j -= k1;
      k -= k1;
    }
  }
  return glm::vec3((p[0] + p[1] + p[2]) * (1.0 / 3.0));
}

// Point j of k along a narrow triangle (one narrower than the surfel spacing across its longest
// edge): at (j + 1/4) / k of that edge's length from the end where the triangle is wider, in the
// middle of its section there. A narrow quad's two triangles are wide at opposite ends, so
// their points interleave evenly along the quad, a spacing of length / (2k) apart (at area
// quantiles each triangle's points crowd its wide end, and the quad's union left gaps of 1.6
// disk diameters along a trunk's face); the pair's density along it is uniform, as its area is.
inline glm::vec3 StripPoint(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c, uint64_t j,
                            uint64_t k) {
  glm::dvec3 p[3] = {glm::dvec3(a), glm::dvec3(b), glm::dvec3(c)};
  const int e = LongestEdge(p);
  glm::dvec3 u = p[e], v = p[(e + 1) % 3];
  const glm::dvec3 o = p[(e + 2) % 3];
  if (!(glm::dot(v - u, v - u) > 0.0)) return a;
  // The opposite vertex's foot nearer v: the triangle is wider toward v; measure from there.
  if (glm::dot(o - u, v - u) > 0.5 * glm::dot(v - u, v - u)) std::swap(u, v);
  const glm::dvec3 d = v - u;
  const double to = std::clamp(glm::dot(o - u, d) / glm::dot(d, d), 0.0, 1.0);
  const glm::dvec3 up = o - (u + d * to);  // from the foot of o to o
  const double t = (static_cast<double>(j) + 0.25) / static_cast<double>(k);
  const double h = t <= to ? (to > 0.0 ? t / to : 1.0) : (to < 1.0 ? (1.0 - t) / (1.0 - to) : 1.0);
  return glm::vec3(u + d * t + up * (0.5 * h));
}

// A cosine-weighted direction around n (Malley's method: uniform on the disk, lifted).
inline glm::vec3 CosineDirection(const glm::vec3& n, const glm::vec3& t, const glm::vec3& b,
                                 glm::vec2 u) {
  float r = std::sqrt(u.x);
  float phi = 2.0f * kPiFloat * u.y;
  float z = std::sqrt(std::max(0.0f, 1.0f - u.x));
  return glm::normalize(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * z);
}

// The glossy lobes of pbgi/raster.h as distributions of x = cos(a), a the angle to the lobe's
// axis, over the axis's hemisphere (x in [0, 1], phi uniform). Solid angle is dx dphi, so the
// density of x is D(x) / integral_0^1 D: no cos factor, unlike a microfacet half-vector pdf.
// Phong, D = x^e: the CDF is x^(e + 1), so x = u^(1 / (e + 1)).
inline double PhongLobeCosine(double u, double exponent) {
  return std::pow(std::clamp(u, 0.0, 1.0), 1.0 / (exponent + 1.0));
}

// The inverse of GgxLobeIntegral(x) / GgxLobeIntegral(1) (base/math.h): Newton's method on the
// monotone CDF, kept inside a shrinking bracket (a bisection step whenever Newton would leave it).
inline double GgxLobeCosine(double u, double alpha) {
  const double k = alpha * alpha - 1.0;
  const double target = std::clamp(u, 0.0, 1.0) * GgxLobeIntegral(1.0, alpha);
  double lo = 0.0, hi = 1.0, x = std::clamp(u, 0.0, 1.0);
  for (int i = 0; i < 100; ++i) {
    const double f = GgxLobeIntegral(x, alpha) - target;
    if (f > 0.0) {
      hi = x;
    } else {
      lo = x;
    }
    const double q = 1.0 + k * x * x;
    double next = x - f * q * q;  // d/dx of the integral is 1 / q^2
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::abs(next - x) <= 1e-15 || hi - lo <= 1e-15) return next;
    x = next;
  }
  return x;
}

inline glm::vec3 TransformPoint(const glm::mat4& m, const glm::vec3& p) {
  return glm::vec3(m[0]) * p.x + glm::vec3(m[1]) * p.y + glm::vec3(m[2]) * p.z + glm::vec3(m[3]);
}

// A world-space triangle of an instance.
struct WorldTriangle {
  glm::vec3 a, b, c;
  glm::vec3 Cross() const { return glm::cross(b - a, c - a); }
  double Area() const {
    glm::dvec3 e1 = glm::dvec3(b) - glm::dvec3(a);
    glm::dvec3 e2 = glm::dvec3(c) - glm::dvec3(a);
    return 0.5 * glm::length(glm::cross(e1, e2));
  }
};

}  // namespace pbgi::internal

#endif  // PBGI_SCENE_SAMPLE_MATH_H_
