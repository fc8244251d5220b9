// kShared over a point set without an image layout (include/pbgi/shade.h, SharingOptions):
// the same idea as shade/image_sharing.h, on the octree of the receivers' Morton keys. Internal.
//
// Level by level, from the first at which the occupied cells hold about spacing^2 receivers on
// average down to the finest: every cell with undecided receivers and no shaded one gets one
// shaded, the one nearest its centre. Then each undecided receiver looks at the shaded receivers
// in its own and the 26 neighbouring cells of the level and keeps those that are of its surface
// (a normal within max_normal_angle both ways, each within max_plane_distance * distance of the
// other's tangent plane) and within radius_factor * their harmonic distance (split sphere).
// They must be at least three and surround it (no gap of half a turn between their directions
// in its tangent plane: never extrapolated). It is then interpolated from the weighted
// least-squares plane through their values over its tangent plane (weights 1 / d^2, tapered to
// 0 at the validity radius; the value clamped into theirs) when there are at least five and
// each lies within half a tolerance of that plane, which follows smooth gradients; else from
// their weighted mean when their values agree (shade/shared_value.h); otherwise it waits for
// the next, finer level. A cell of one receiver shades it. Decisions depend only on shaded
// values and positions, never on timing.
#ifndef PBGI_SHADE_POINT_SHARING_H_
#define PBGI_SHADE_POINT_SHARING_H_

#include <cstdint>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "pbgi/shade.h"
#include "shade/engine.h"
#include "shade/image_sharing.h"

namespace pbgi::internal {

// Shades the batch of `engine` as a point set (options.sharing validated, without an image).
absl::Status ShadePointsShared(ShadeEngine& engine, absl::Span<const ShadeReceiver> receivers,
                               const ShadeOptions& options, absl::Span<ShadeResult> out,
                               absl::Span<uint8_t> shaded, SharingCounts* counts);

}  // namespace pbgi::internal

#endif  // PBGI_SHADE_POINT_SHARING_H_
