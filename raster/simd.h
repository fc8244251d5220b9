// Four-float vectors for the rasterizer's hot loops, as GCC / Clang vector extensions: they
// compile to SSE2 (the x86-64 baseline) or NEON without intrinsics or run-time dispatch.
#ifndef PBGI_RASTER_SIMD_H_
#define PBGI_RASTER_SIMD_H_

#include <cmath>
#include <cstring>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace pbgi::internal {

typedef float V4 __attribute__((vector_size(16)));
typedef float V2 __attribute__((vector_size(8)));
typedef int V4i __attribute__((vector_size(16)));  // comparison masks: -1 true, 0 false

// Unaligned load and store through memcpy (no aliasing questions; one movups each).
inline V4 Load4(const float* p) {
  V4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void Store4(float* p, V4 v) { std::memcpy(p, &v, sizeof v); }

inline V4 Splat4(float x) { return V4{x, x, x, x}; }

// Bit i set where lane i of the mask is true.
inline int Movemask4(V4i m) {
#if defined(__SSE__)
  return _mm_movemask_ps(reinterpret_cast<__m128>(m));
#else
  return (m[0] & 1) | (m[1] & 2) | (m[2] & 4) | (m[3] & 8);
#endif
}

inline V4 Max4(V4 a, V4 b) { return a > b ? a : b; }
inline V4 Min4(V4 a, V4 b) { return a < b ? a : b; }

// The least (greatest) of the eight lanes of a and b: the value that std::min (std::max) finds
// one lane at a time, when no lane is NaN (a zero's sign aside).
inline float Least8(V4 a, V4 b) {
  V4 v = Min4(a, b);
  v = Min4(v, __builtin_shufflevector(v, v, 2, 3, 0, 1));
  return v[0] < v[1] ? v[0] : v[1];
}
inline float Greatest8(V4 a, V4 b) {
  V4 v = Max4(a, b);
  v = Max4(v, __builtin_shufflevector(v, v, 2, 3, 0, 1));
  return v[0] > v[1] ? v[0] : v[1];
}

inline V4 Sqrt4(V4 v) {
#if defined(__SSE__)
  return _mm_sqrt_ps(v);
#else
  for (int i = 0; i < 4; ++i) v[i] = std::sqrt(v[i]);
  return v;
#endif
}

// The product of the matrix with columns cx, cy, cz (lane i of each: row i) and (x, y, z): lane i
// is (cx[i] x + cy[i] y) + cz[i] z, glm::dot(row i, v) to the bit (its order of operations).
inline V4 MulColumns4(V4 cx, V4 cy, V4 cz, float x, float y, float z) {
  return cx * x + cy * y + cz * z;
}

// Rows a, b, c, d become columns.
inline void Transpose4(V4& a, V4& b, V4& c, V4& d) {
  const V4 t0 = __builtin_shufflevector(a, b, 0, 4, 1, 5),
           t1 = __builtin_shufflevector(a, b, 2, 6, 3, 7);
  const V4 t2 = __builtin_shufflevector(c, d, 0, 4, 1, 5),
           t3 = __builtin_shufflevector(c, d, 2, 6, 3, 7);
  a = __builtin_shufflevector(t0, t2, 0, 1, 4, 5);
  b = __builtin_shufflevector(t0, t2, 2, 3, 6, 7);
  c = __builtin_shufflevector(t1, t3, 0, 1, 4, 5);
  d = __builtin_shufflevector(t1, t3, 2, 3, 6, 7);
}

// {sum(a), sum(b), sum(c), sum(d)}: a 4 x 4 transpose folded into the additions.
inline V4 Hsum4(V4 a, V4 b, V4 c, V4 d) {
  const V4 ab =
      __builtin_shufflevector(a, b, 0, 4, 1, 5) + __builtin_shufflevector(a, b, 2, 6, 3, 7);
  const V4 cd =
      __builtin_shufflevector(c, d, 0, 4, 1, 5) + __builtin_shufflevector(c, d, 2, 6, 3, 7);
  return __builtin_shufflevector(ab, cd, 0, 1, 4, 5) + __builtin_shufflevector(ab, cd, 2, 3, 6, 7);
}

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_SIMD_H_
