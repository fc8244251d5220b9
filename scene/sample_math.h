// Small sampling helpers shared by the sampler, the lighting function and the reference
// integrator: counter-based random numbers (so any sample can be computed on its own, on any
// thread), a rotated Hammersley set, area-preserving square-to-triangle and cosine-weighted
// hemisphere maps.
#ifndef PBGI_SCENE_SAMPLE_MATH_H_
#define PBGI_SCENE_SAMPLE_MATH_H_

#include <algorithm>
#include <cmath>
#include <cstdint>

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
