// Radii and normals for surfels whose source lacks them (point clouds from scanners and point
// tools: Open3D and PCL write normals without radii, or neither), estimated from each surfel's
// k nearest neighbours in the Morton-sorted stream of the build's octree pass
// (docs/design.md, "Build").
//
// Points arrive in Morton order and leave in the same order, a block behind: each block of
// kBlock points is estimated with the block before and the block after it as context (a k-d tree
// over the three, nanoflann), so memory is three blocks whatever the input's size, and a point's
// neighbours are found wherever they lie in those 3 * kBlock points. Morton order keeps a
// block's spatial neighbours in the adjacent blocks except along some octant boundaries; a point
// there misses the neighbours on the far side and overestimates its radius (at most by about
// sqrt(2), half a disk of neighbours), docs/format.md has the measured error.
//
// Radius: on a surface sampled with density rho, pi rho d_j^2 of the j-th neighbour distance
// has mean j (a Poisson process), so pi r^2 = 1 / rho = 2 sum_j d_j^2 / (k (k + 1)) over the k
// nearest: each surfel stands for the area around it, and the surfels' total area is the
// surface's. Normal: the eigenvector of the smallest eigenvalue of the neighbours' covariance
// (PCA), turned away from the centre of the bounds, or towards a viewpoint (a scanner's
// position).
//
// Not thread-safe.
#ifndef PBGI_BUILD_NEIGHBOUR_ESTIMATE_H_
#define PBGI_BUILD_NEIGHBOUR_ESTIMATE_H_

#include <cstdint>
#include <vector>

#include "absl/functional/function_ref.h"
#include "absl/status/status.h"
#include "build/sort_record.h"
#include "pbgi/build.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

class NeighbourEstimator {
 public:
  static constexpr size_t kBlock = 32768;
  // Bytes the estimator holds at most (three blocks of records, their positions, the tree).
  static constexpr uint64_t kMemoryBytes = 3 * kBlock * (sizeof(SortRecord) + 64);

  using Sink = absl::FunctionRef<absl::Status(const SortRecord&)>;

  NeighbourEstimator(const BuildOptions::Estimate& options, const Bounds& bounds);
  // Takes the next record in Morton order; may pass earlier records, finished, to `sink`.
  absl::Status Add(const SortRecord& r, Sink sink);
  // Finishes and passes every record left.
  absl::Status Finish(Sink sink);

 private:
  // Estimates window_[begin, end) with all of window_ as context and passes them on.
  absl::Status EstimateRange(size_t begin, size_t end, Sink sink);

  BuildOptions::Estimate options_;
  glm::vec3 centre_;
  float min_radius_;
  // window_[0, cur_): the previous block (estimated, kept as context); window_[cur_, end): the
  // current block and the next, as they fill.
  std::vector<SortRecord> window_;
  size_t cur_ = 0;  // first record not yet estimated
  float last_radius_ = 0;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_NEIGHBOUR_ESTIMATE_H_
