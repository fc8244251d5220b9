// ShadeBatch (include/pbgi/shade.h): validation, then the mode: kExact shades every receiver on
// the engine (shade/engine.h), kShared refines over an image (shade/image_sharing.h) or a point
// set (shade/point_sharing.h).
#include "pbgi/shade.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "pbgi/status.h"
#include "shade/engine.h"
#include "shade/image_sharing.h"
#include "shade/point_sharing.h"

namespace pbgi {
namespace {

absl::Status Validate(absl::Span<const ShadeReceiver> receivers, const ShadeOptions& options,
                      absl::Span<ShadeResult> out, absl::Span<uint8_t> shaded) {
  if (out.size() != receivers.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ShadeBatch: %d results for %d receivers", out.size(), receivers.size()));
  }
  if (!shaded.empty() && shaded.size() != receivers.size()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "ShadeBatch: %d shaded flags for %d receivers", shaded.size(), receivers.size()));
  }
  if (!(options.cut.max_solid_angle >= 0.0f)) {
    return absl::InvalidArgumentError("max_solid_angle must be >= 0");
  }
  if (!(options.cut.curved_scale > 0.0f && options.cut.curved_scale <= 1.0f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("Cut.curved_scale = %g: must be in (0, 1]", options.cut.curved_scale));
  }
  if (!(options.cut.curved_box_scale >= 0.0f && std::isfinite(options.cut.curved_box_scale))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "Cut.curved_box_scale = %g: must be finite and >= 0", options.cut.curved_box_scale));
  }
  PBGI_RETURN_IF_ERROR(ValidateCutLobe(options.cut.lobe));
  if (!(options.radiance_contrast >= 0.0f && std::isfinite(options.radiance_contrast))) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ShadeOptions::radiance_contrast = %g: must be finite and >= 0",
                        options.radiance_contrast));
  }
  PBGI_RETURN_IF_ERROR(ValidateRasterOptions(options.raster));
  for (size_t i = 0; i < receivers.size(); ++i) {
    const ShadeReceiver& r = receivers[i];
    const bool finite = std::isfinite(r.position.x) && std::isfinite(r.position.y) &&
                        std::isfinite(r.position.z) && std::isfinite(r.normal.x) &&
                        std::isfinite(r.normal.y) && std::isfinite(r.normal.z);
    if (!finite || glm::dot(r.normal, r.normal) == 0.0f) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "receiver %d has a %s", i, finite ? "zero normal" : "NaN or infinite coordinate"));
    }
  }
  PBGI_RETURN_IF_ERROR(ValidateFarSharingOptions(options));
  if (options.mode == ShadeMode::kShared) {
    PBGI_RETURN_IF_ERROR(ValidateSharingOptions(options.sharing, receivers.size()));
  } else if (options.mode != ShadeMode::kExact) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ShadeOptions::mode %d is not a ShadeMode", int(options.mode)));
  }
  return absl::OkStatus();
}

}  // namespace

void ShadeStats::Add(const ShadeStats& o) {
  receivers += o.receivers;
  seconds += o.seconds;
  cpu_seconds += o.cpu_seconds;
  query.Add(o.query);
  cache.Add(o.cache);
  gather_seconds += o.gather_seconds;
  raster_seconds += o.raster_seconds;
  shaded += o.shaded;
  interpolated += o.interpolated;
  sharing_seconds += o.sharing_seconds;
  far_groups += o.far_groups;
  far_members += o.far_members;
}

absl::Status ValidateFarSharingOptions(const ShadeOptions& options) {
  const FarSharingOptions& f = options.far_sharing;
  if (!f.enabled) return absl::OkStatus();
  if (f.max_members < 2 || f.max_members > 4096) {
    return absl::InvalidArgumentError(
        absl::StrFormat("FarSharingOptions::max_members %d: must be in [2, 4096]", f.max_members));
  }
  if (!(f.max_radius > 0.0f) || !std::isfinite(f.max_radius)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "FarSharingOptions::max_radius %g: must be finite and > 0 (world units)", f.max_radius));
  }
  if (!(f.distance_factor >= 1.0f) || !std::isfinite(f.distance_factor)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "FarSharingOptions::distance_factor %g: must be finite and >= 1", f.distance_factor));
  }
  if (!(f.max_normal_angle_degrees >= 0.0f && f.max_normal_angle_degrees < 90.0f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("FarSharingOptions::max_normal_angle_degrees %g: must be in [0, 90)",
                        f.max_normal_angle_degrees));
  }
  if (options.cut.lobe.kind != CutLobeKind::kNone ||
      (options.lobe_cut && options.raster.lobe != GlossyLobe::kNone)) {
    return absl::InvalidArgumentError(
        "FarSharingOptions::enabled with a lobe cut (Cut::lobe, or ShadeOptions::lobe_cut with "
        "a glossy lobe): a lobe belongs to one receiver; set lobe_cut = false");
  }
  if (std::isfinite(options.cut.max_distance)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("FarSharingOptions::enabled with Cut::max_distance %g: far sharing "
                        "needs an infinite max_distance",
                        options.cut.max_distance));
  }
  return absl::OkStatus();
}

int DefaultShadeThreads() { return std::max(1u, std::thread::hardware_concurrency()); }

absl::Status ValidateSharingOptions(const SharingOptions& s, size_t receivers) {
  if (s.spacing < 2 || s.spacing > 64 || (s.spacing & (s.spacing - 1)) != 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("SharingOptions::spacing %d: a power of two in [2, 64]", s.spacing));
  }
  if (!(s.tolerance >= 0.0f) || !std::isfinite(s.tolerance)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("SharingOptions::tolerance %g: must be finite and >= 0", s.tolerance));
  }
  if (!(s.radius_factor >= 0.0f) || !std::isfinite(s.radius_factor)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "SharingOptions::radius_factor %g: must be finite and >= 0", s.radius_factor));
  }
  if (!(s.max_normal_angle_degrees >= 0.0f && s.max_normal_angle_degrees <= 180.0f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("SharingOptions::max_normal_angle_degrees %g: must be in [0, 180]",
                        s.max_normal_angle_degrees));
  }
  if (!(s.max_plane_distance >= 0.0f) || !std::isfinite(s.max_plane_distance)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "SharingOptions::max_plane_distance %g: must be finite and >= 0", s.max_plane_distance));
  }
  const ImageLayout& im = s.image;
  if (im.width == 0 && im.height == 0 && im.pixel_of.empty()) {
    if (!im.surface_id.empty()) {
      return absl::InvalidArgumentError("ImageLayout: surface_id given without pixel_of");
    }
    return absl::OkStatus();  // a point set
  }
  if (im.width <= 0 || im.height <= 0 || uint64_t(im.width) * uint64_t(im.height) > (1ull << 32)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ImageLayout: %dx%d is not an image size", im.width, im.height));
  }
  if (im.pixel_of.size() != receivers) {
    return absl::InvalidArgumentError(
        absl::StrFormat("ImageLayout: %d pixels for %d receivers", im.pixel_of.size(), receivers));
  }
  if (!im.surface_id.empty() && im.surface_id.size() != receivers) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "ImageLayout: %d surface ids for %d receivers", im.surface_id.size(), receivers));
  }
  const uint64_t pixels = uint64_t(im.width) * uint64_t(im.height);
  std::vector<uint32_t> owner(pixels, std::numeric_limits<uint32_t>::max());
  for (size_t i = 0; i < receivers; ++i) {
    const uint32_t p = im.pixel_of[i];
    if (p >= pixels) {
      return absl::InvalidArgumentError(
          absl::StrFormat("ImageLayout: receiver %d is on pixel %d, outside the %dx%d image", i, p,
                          im.width, im.height));
    }
    if (owner[p] != std::numeric_limits<uint32_t>::max()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("ImageLayout: receivers %d and %d are both on pixel %d", owner[p], i, p));
    }
    owner[p] = static_cast<uint32_t>(i);
  }
  return absl::OkStatus();
}

absl::StatusOr<Cut> EffectiveCut(Database& db, const ShadeOptions& options) {
  Cut cut = options.cut;
  if (!(options.radiance_contrast > 0.0f) || cut.radiance_contrast > 0.0f ||
      !options.raster.compute_radiance || !HasRadiance(db.meta().channels)) {
    return cut;
  }
  absl::StatusOr<std::unique_ptr<Reader>> reader = db.NewReader();
  if (!reader.ok()) return reader.status();
  absl::StatusOr<float> mean = (*reader)->MeanRadiance();
  if (!mean.ok()) return mean.status();
  cut.radiance_contrast = options.radiance_contrast;
  cut.contrast_floor = kContrastFloorScale * *mean;
  return cut;
}

absl::Status ShadeBatch(Database& db, absl::Span<const ShadeReceiver> receivers,
                        const ShadeOptions& options, absl::Span<ShadeResult> out, ShadeStats* stats,
                        absl::Span<uint8_t> shaded) {
  PBGI_RETURN_IF_ERROR(Validate(receivers, options, out, shaded));
  absl::StatusOr<Cut> cut = EffectiveCut(db, options);
  if (!cut.ok()) return cut.status();
  std::fill(out.begin(), out.end(), ShadeResult{});
  internal::ShadeEngine engine(db, receivers, options, *cut, out);
  internal::SharingCounts sharing;
  if (options.mode == ShadeMode::kExact || receivers.empty()) {
    std::vector<uint32_t> all(receivers.size());
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<uint32_t>(i);
    PBGI_RETURN_IF_ERROR(engine.Shade(all));
    std::fill(shaded.begin(), shaded.end(), uint8_t{1});
  } else if (!options.sharing.image.pixel_of.empty()) {
    PBGI_RETURN_IF_ERROR(
        internal::ShadeImageShared(engine, receivers, options, out, shaded, &sharing));
  } else {
    PBGI_RETURN_IF_ERROR(
        internal::ShadePointsShared(engine, receivers, options, out, shaded, &sharing));
  }
  if (stats != nullptr) {
    *stats = engine.Stats();
    stats->interpolated = sharing.interpolated;
    stats->sharing_seconds = sharing.seconds;
  }
  engine.ReportEnd();
  return absl::OkStatus();
}

}  // namespace pbgi
