// Four-float vectors for the rasterizer's hot loops, as GCC / Clang vector extensions: they
// compile to SSE2 (the x86-64 baseline) or NEON without intrinsics or run-time dispatch.
#ifndef PBGI_RASTER_SIMD_H_
#define PBGI_RASTER_SIMD_H_

#include <cstring>

namespace pbgi::internal {

typedef float V4 __attribute__((vector_size(16)));

// Unaligned load and store through memcpy (no aliasing questions; one movups each).
inline V4 Load4(const float* p) {
  V4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void Store4(float* p, V4 v) { std::memcpy(p, &v, sizeof v); }

inline V4 Max4(V4 a, V4 b) { return a > b ? a : b; }

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
