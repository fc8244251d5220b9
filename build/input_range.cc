#include "build/input_range.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "absl/strings/str_format.h"
#include "pbgi/sh.h"

namespace pbgi::internal {

absl::Status InputRangeCheck::Add(const Surfel& s, uint64_t index, bool radiance) {
  auto refuse = [&](const std::string& what, const char* fix) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "input surfel %d (counting from 0) at (%g, %g, %g), radius %g: %s; %s (docs/format.md, "
        "\"Numeric range\")",
        index, s.position.x, s.position.y, s.position.z, s.radius, what, fix));
  };
  const float c = std::max({std::abs(s.position.x), std::abs(s.position.y),
                            std::abs(s.position.z)});
  if (double(c) > kMaxCoordinate) {
    return refuse(absl::StrFormat("a coordinate beyond +-%g, the largest supported", kMaxCoordinate),
                  "scale the scene down (positions and radii by one factor)");
  }
  if (double(s.radius) < kMinRadius) {
    return refuse(absl::StrFormat("the radius is below %g, the smallest supported", kMinRadius),
                  "scale the scene up (positions and radii by one factor)");
  }
  // The spacing of floats at this surfel's largest coordinate.
  const float step = std::nextafter(c, std::numeric_limits<float>::infinity()) - c;
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
