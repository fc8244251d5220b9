// Shade(): validates the options and the receiver, then runs the rasterizer.
#include <cmath>

#include "absl/strings/str_cat.h"
#include "glm/geometric.hpp"
#include "pbgi/raster.h"
#include "raster/rasterizer.h"

namespace pbgi {

absl::Status ValidateRasterOptions(const RasterOptions& o) {
  auto bad = [](absl::string_view field, auto value, absl::string_view want) {
    return absl::InvalidArgumentError(
        absl::StrCat("RasterOptions.", field, " = ", value, ": ", want));
  };
  if (o.resolution < 4 || o.resolution > 64) {
    return bad("resolution", o.resolution, "must be in [4, 64]");
  }
  if (!std::isfinite(o.bias) || o.bias < 0.0f) return bad("bias", o.bias, "must be >= 0");
  if (!(o.max_distance > 0.0f)) {
    return bad("max_distance", o.max_distance, "must be > 0 (may be infinite)");
  }
  if (!std::isfinite(o.near_field_factor) || o.near_field_factor < 0.0f) {
    return bad("near_field_factor", o.near_field_factor, "must be finite and >= 0");
  }
  if (o.near_field_samples < 1 || o.near_field_samples > 16) {
    return bad("near_field_samples", o.near_field_samples, "must be in [1, 16]");
  }
  if (o.footprint != Footprint::kSplats && o.footprint != Footprint::kPolygons) {
    return bad("footprint", static_cast<int>(o.footprint), "must be kSplats or kPolygons");
  }
  if (!std::isfinite(o.phong_exponent) || o.phong_exponent < 0.0f) {
    return bad("phong_exponent", o.phong_exponent, "must be finite and >= 0");
  }
  if (!(o.ggx_roughness > 0.0f && o.ggx_roughness <= 1.0f)) {
    return bad("ggx_roughness", o.ggx_roughness, "must be in (0, 1]");
  }
  return absl::OkStatus();
}

absl::Status Shade(const Gathered& gathered, const ShadeReceiver& receiver,
                   const RasterOptions& options, MicroBuffer* scratch, ShadeResult* out) {
  if (scratch == nullptr || out == nullptr) {
    return absl::InvalidArgumentError("Shade: scratch and out must not be null");
  }
  absl::Status valid = ValidateRasterOptions(options);
  if (!valid.ok()) return valid;
  const float nn = glm::dot(receiver.normal, receiver.normal);
  if (!(nn > 0.0f) || !std::isfinite(nn) || !std::isfinite(receiver.position.x) ||
      !std::isfinite(receiver.position.y) || !std::isfinite(receiver.position.z)) {
    return absl::InvalidArgumentError(
        absl::StrCat("Shade: receiver at (", receiver.position.x, ", ", receiver.position.y, ", ",
                     receiver.position.z, ") has a zero or non-finite normal or position"));
  }
  absl::Status s = scratch->Prepare(options.resolution);
  if (!s.ok()) return s;
  internal::Rasterizer raster(scratch, options);
  return raster.Run(gathered, receiver, out);
}

}  // namespace pbgi
