// Shade(): validates the options and the receiver, then runs the rasterizer.
#include <cmath>

#include "absl/strings/str_cat.h"
#include "glm/geometric.hpp"
#include "pbgi/raster.h"
#include "pbgi/status.h"
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

namespace {
// The checks of Shade(), ShadeFar() and ShadeWithFar(), whose name `what` is.
absl::Status CheckShade(absl::string_view what, const ShadeReceiver& receiver,
                        const RasterOptions& options, const MicroBuffer* scratch, const void* out) {
  if (scratch == nullptr || out == nullptr) {
    return absl::InvalidArgumentError(absl::StrCat(what, ": scratch and out must not be null"));
  }
  absl::Status valid = ValidateRasterOptions(options);
  if (!valid.ok()) return valid;
  const float nn = glm::dot(receiver.normal, receiver.normal);
  if (!(nn > 0.0f) || !std::isfinite(nn) || !std::isfinite(receiver.position.x) ||
      !std::isfinite(receiver.position.y) || !std::isfinite(receiver.position.z)) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, ": receiver at (", receiver.position.x, ", ", receiver.position.y, ", ",
                     receiver.position.z, ") has a zero or non-finite normal or position"));
  }
  return absl::OkStatus();
}
}  // namespace

absl::Status Shade(const Gathered& gathered, const ShadeReceiver& receiver,
                   const RasterOptions& options, MicroBuffer* scratch, ShadeResult* out) {
  PBGI_RETURN_IF_ERROR(CheckShade("Shade", receiver, options, scratch, out));
  absl::Status s = scratch->Prepare(options.resolution);
  if (!s.ok()) return s;
  internal::Rasterizer raster(scratch, options);
  return raster.Run(gathered, receiver, out);
}

absl::Status ShadeFar(const Gathered& far, const ShadeReceiver& centre,
                      const RasterOptions& options, MicroBuffer* scratch, FarBuffer* out) {
  PBGI_RETURN_IF_ERROR(CheckShade("ShadeFar", centre, options, scratch, out));
  PBGI_RETURN_IF_ERROR(scratch->Prepare(options.resolution));
  internal::Rasterizer raster(scratch, options);
  ShadeResult result;
  PBGI_RETURN_IF_ERROR(raster.Run(far, centre, &result));
  raster.ExportFar(centre, out);
  return absl::OkStatus();
}

absl::Status ShadeWithFar(const Gathered& near, const ShadeReceiver& receiver, const FarBuffer& far,
                          const RasterOptions& options, MicroBuffer* scratch, ShadeResult* out) {
  PBGI_RETURN_IF_ERROR(CheckShade("ShadeWithFar", receiver, options, scratch, out));
  if (far.resolution() != options.resolution) {
    return absl::InvalidArgumentError(
        absl::StrCat("ShadeWithFar: the far buffer's resolution is ", far.resolution(),
                     ", the options' ", options.resolution, " (ShadeFar with the same options)"));
  }
  PBGI_RETURN_IF_ERROR(scratch->Prepare(options.resolution));
  internal::Rasterizer raster(scratch, options);
  raster.set_far(&far);
  ShadeReceiver r = receiver;
  r.normal = far.normal();  // the far buffer's frame
  return raster.Run(near, r, out);
}

}  // namespace pbgi
