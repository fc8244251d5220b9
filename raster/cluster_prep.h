// Cluster preparation: a gathered cluster in the receiver's frame, culled or turned into a
// PreparedSplat (direction, solid angle, depth, mean normal and plane, radiance). Two paths
// with the same results bit for bit: one cluster at a time (any model), and eight (AVX2) or
// four (baseline ISA) at a time in SIMD lanes (the moment model), which the rasterizer uses for
// all but the last clusters. Preparation is most of a receiver's instructions at the default cut
// (~600 clusters, ~35 surfels), and lane-parallel it costs about a third of the scalar path.
#ifndef PBGI_RASTER_CLUSTER_PREP_H_
#define PBGI_RASTER_CLUSTER_PREP_H_

#include <cstddef>

#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// The receiver's frame (t, b, n orthonormal, n its normal) and the options preparation reads.
struct ClusterFrame {
  ClusterFrame(const glm::vec3& origin, const glm::vec3& t, const glm::vec3& b, const glm::vec3& n,
               float max_distance, HitSides sides, ClusterModel model);
  glm::vec3 origin, t, b, n;
  glm::vec3 half_abs_n;  // |n| / 2 per axis: a box's half extent along n is its dot with ext
  float max_distance;
  HitSides sides;
  ClusterModel model;
};

// Prepares one cluster into *out; false (and *out partly written) when it is culled: empty
// bounds, wholly behind the tangent plane, beyond max_distance, or no area facing the receiver.
template <bool kRad>
bool PrepareClusterOne(const Cluster& c, const ClusterFrame& f, PreparedSplat* out);

// Prepares c[0..count) into out[0..], the splats of the clusters not culled, in order; returns
// how many. out[0..count) must be writable. With the moment model, eight clusters at a time in
// SIMD lanes with `avx2` (only where CpuHasAvx2()), else four, and the last few one at a time:
// the same results as PrepareClusterOne bit for bit.
template <bool kRad>
int PrepareClusters(const Cluster* c, size_t count, const ClusterFrame& f, PreparedSplat* out,
                    bool avx2);

// Whether this CPU can run the AVX2 builds of PrepareClusters and of the rasterizer's
// splatting (x86-64 with AVX2; checked once).
bool CpuHasAvx2();
// Whether Shade() uses them: CpuHasAvx2() unless a test asked for the baseline build.
bool UseAvx2();
void ForceBaselineIsaForTesting(bool force);

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define PBGI_RASTER_HAS_AVX2 1
#else
#define PBGI_RASTER_HAS_AVX2 0
#endif

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_CLUSTER_PREP_H_
