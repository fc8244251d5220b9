// The range of input a database can hold and shade exactly in float (docs/format.md, "Numeric
// range"): surfels outside it are an input error naming the surfel, at build time, instead of
// a database whose aggregates overflow to infinity (verify calls it corrupt) or whose shading
// loses its answer to overflowed or denormal products.
//
// The limits come from what the float pipeline computes: node areas and their squares (the
// rasterizer's cluster moments), cubes of distances (a surfel's solid angle), and positions
// that must place a disk to a small fraction of its radius:
//   - radius >= kMinRadius (2^-30, about 9.3e-10): smaller disks' squared areas underflow;
//   - |coordinate| <= kMaxCoordinate (2^40, about 1.1e12): cubed distances overflow;
//   - the total area of all surfels <= kMaxTotalArea (2^62, about 4.6e18), and their total
//     power (area x radiance) <= kMaxTotalPower (2^100): node aggregates and their squares
//     overflow beyond;
//   - radius >= 64 float steps of the surfel's largest coordinate: farther from the origin,
//     float cannot place a disk this small (a scene offset by 1e7 times its size).
// Within these, results do not depend on the scene's scale or position (tests/build:
// ScaleRegressionTest). Scale or translate a scene that falls outside.
#ifndef PBGI_BUILD_INPUT_RANGE_H_
#define PBGI_BUILD_INPUT_RANGE_H_

#include <cstdint>

#include "absl/status/status.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

inline constexpr double kMinRadius = 0x1p-30;
inline constexpr double kMaxCoordinate = 0x1p40;
inline constexpr double kMaxTotalArea = 0x1p62;
inline constexpr double kMaxTotalPower = 0x1p100;
inline constexpr float kMinRadiusInSteps = 64.0f;

// Checks surfels one by one (every valid input surfel, in input order). Not thread-safe.
class InputRangeCheck {
 public:
  // InvalidArgument naming surfel `index` (counting from 0) and the limit it breaks.
  absl::Status Add(const Surfel& s, uint64_t index, bool radiance);

 private:
  double area_ = 0;
  double power_ = 0;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_INPUT_RANGE_H_
