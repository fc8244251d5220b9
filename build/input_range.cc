#include "build/input_range.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <string>

#include "absl/strings/str_format.h"
#include "pbgi/sh.h"

namespace pbgi::internal {

absl::Status InputRangeCheck::Add(const Surfel& s, uint64_t index, bool radiance) {
  return Check(s, index, radiance, /*position_only=*/false, "counting from 0");
}

absl::Status InputRangeCheck::AddPosition(const Surfel& s, uint64_t index) {
  return Check(s, index, /*radiance=*/false, /*position_only=*/true, "counting from 0");
}

absl::Status InputRangeCheck::AddEstimated(const Surfel& s, uint64_t index, bool radiance) {
  return Check(s, index, radiance, /*position_only=*/false,
               "in Morton order, with its estimated radius");
}

absl::Status InputRangeCheck::Check(const Surfel& s, uint64_t index, bool radiance,
                                    bool position_only, const char* order) {
  auto refuse = [&](const std::string& what, const char* fix) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "input surfel %d (%s) at (%g, %g, %g), radius %g: %s; %s (docs/format.md, "
        "\"Numeric range\")",
        index, order, s.position.x, s.position.y, s.position.z, s.radius, what, fix));
  };
  const float c =
      std::max({std::abs(s.position.x), std::abs(s.position.y), std::abs(s.position.z)});
  if (double(c) > kMaxCoordinate) {
    return refuse(
        absl::StrFormat("a coordinate beyond +-%g, the largest supported", kMaxCoordinate),
        "scale the scene down (positions and radii by one factor)");
  }
  if (position_only) return absl::OkStatus();
  if (double(s.radius) < kMinRadius) {
    return refuse(absl::StrFormat("the radius is below %g, the smallest supported", kMinRadius),
                  "scale the scene up (positions and radii by one factor)");
  }
  // The spacing of floats at this surfel's largest coordinate: the next float up is the next
  // bit pattern for a finite c >= 0, as std::nextafter(c, inf) gives it, without its libm call
  // (about 30 instructions a surfel; docs/format.md, "Session 15").
  const float step = std::bit_cast<float>(std::bit_cast<uint32_t>(c) + 1u) - c;
  if (s.radius < kMinRadiusInSteps * step) {
    return refuse(absl::StrFormat("floats are %g apart this far from the origin, too coarse to "
                                  "place a disk of this radius (at least %g steps are needed)",
                                  step, kMinRadiusInSteps),
                  "translate the scene near the origin before writing it");
  }
  const double a = sh::kPi * double(s.radius) * double(s.radius);
  area_ += a;
  if (area_ > kMaxTotalArea) {
    return refuse(absl::StrFormat("the surfels' total area reaches %g here, beyond %g (node "
                                  "aggregates would overflow float)",
                                  area_, kMaxTotalArea),
                  "scale the scene down (positions and radii by one factor)");
  }
  if (radiance) {
    power_ += a * std::max({double(s.radiance.x), double(s.radiance.y), double(s.radiance.z)});
    if (power_ > kMaxTotalPower) {
      return refuse(absl::StrFormat("the surfels' total power (area x radiance) reaches %g here, "
                                    "beyond %g",
                                    power_, kMaxTotalPower),
                    "scale the radiance or the scene down");
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
