// kShared over a camera view's pixels (include/pbgi/shade.h, SharingOptions): adaptive
// refinement in screen space. Internal.
//
// The image is covered by square cells of `spacing` pixels whose corners are shaded. Level by
// level, each cell is either accepted (interpolated) or split into four, its five midpoints
// shaded; a cell of one pixel has no inside, so refinement ends with every pixel of an unsafe
// region shaded. A cell is accepted only if
//  - its four corners have receivers, and every pixel of the cell (edges included) has one, of
//    the corners' surface id, with a normal within max_normal_angle of every corner's and within
//    max_plane_distance * extent of the corners' tangent planes (bilinearly weighted), where
//    extent is the longer diagonal of the corners in space;
//  - extent <= radius_factor * the smallest harmonic distance of the corners (split sphere);
//  - the corners' values agree (shade/shared_value.h).
// Each pixel that is not shaded is interpolated by the smallest accepted cell that contains it,
// as a Coons patch of the cell's four edges, each edge piecewise linear through the shaded
// pixels on it: a cell next to finer ones passes through their shaded corners on the shared
// edge, so the image is continuous across cells of different sizes (no T-junction cracks).
// Every decision depends only on shaded values and the receivers' geometry, never on timing, so
// the result does not depend on the thread count.
#ifndef PBGI_SHADE_IMAGE_SHARING_H_
#define PBGI_SHADE_IMAGE_SHARING_H_

#include <cstdint>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "pbgi/shade.h"
#include "shade/engine.h"

namespace pbgi::internal {

// What a shared pass did beyond shading (the engine counts the shading).
struct SharingCounts {
  uint64_t interpolated = 0;
  double seconds = 0;  // thread time deciding cells and interpolating
};

// Shades the batch of `engine` with options.sharing.image (validated). shaded[i] (when not
// empty) = 1 for a receiver shaded on its own, 0 for an interpolated one.
absl::Status ShadeImageShared(ShadeEngine& engine, absl::Span<const ShadeReceiver> receivers,
                              const ShadeOptions& options, absl::Span<ShadeResult> out,
                              absl::Span<uint8_t> shaded, SharingCounts* counts);

}  // namespace pbgi::internal

#endif  // PBGI_SHADE_IMAGE_SHARING_H_
