#include "build/neighbour_estimate.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "base/math.h"
#include "glm/gtc/type_ptr.hpp"
#include "nanoflann.hpp"
#include "pbgi/status.h"

namespace pbgi::internal {
namespace {

// nanoflann's view of the window's positions.
struct Cloud {
  const std::vector<SortRecord>* records;
  size_t kdtree_get_point_count() const { return records->size(); }
  float kdtree_get_pt(size_t i, size_t d) const { return (*records)[i].position[d]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud>, Cloud,
                                                 3, uint32_t>;

// The eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix (cyclic Jacobi).
glm::vec3 SmallestEigenvector(std::array<std::array<double, 3>, 3> a) {
  std::array<std::array<double, 3>, 3> v;
  SymmetricEigen3(&a, &v);
  int m = 0;
  for (int i = 1; i < 3; ++i) {
    if (a[i][i] < a[m][m]) m = i;
  }
  return glm::normalize(glm::vec3(float(v[0][m]), float(v[1][m]), float(v[2][m])));
}

}  // namespace

NeighbourEstimator::NeighbourEstimator(const BuildOptions::Estimate& options, const Bounds& bounds)
    : options_(options), centre_(bounds.Center()) {
  options_.neighbours = std::clamp(options_.neighbours, 3, 64);
  // A floor for coincident points (all k neighbours at distance 0): a millionth of the scene.
  min_radius_ = std::max(1e-30f, 1e-6f * glm::length(bounds.Extent()));
  window_.reserve(3 * kBlock);
}

absl::Status NeighbourEstimator::Add(const SortRecord& r, Sink sink) {
  window_.push_back(r);
  // [previous | current | next] complete: estimate the current block.
  if (window_.size() - cur_ == 2 * kBlock) {
    const size_t previous = cur_;
    PBGI_RETURN_IF_ERROR(EstimateRange(cur_, cur_ + kBlock, sink));
    // The current block becomes the previous one; the one before it is done with.
    window_.erase(window_.begin(), window_.begin() + static_cast<std::ptrdiff_t>(previous));
    cur_ -= previous;
  }
  return absl::OkStatus();
}

absl::Status NeighbourEstimator::Finish(Sink sink) {
  if (cur_ < window_.size()) PBGI_RETURN_IF_ERROR(EstimateRange(cur_, window_.size(), sink));
  window_.clear();
  cur_ = 0;
  return absl::OkStatus();
}

absl::Status NeighbourEstimator::EstimateRange(size_t begin, size_t end, Sink sink) {
  Cloud cloud{&window_};
  Tree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();
  const size_t k = std::min<size_t>(size_t(options_.neighbours) + 1, window_.size());
  std::vector<uint32_t> idx(k);
  std::vector<float> d2(k);
  for (size_t i = begin; i < end; ++i) {
    SortRecord& r = window_[i];
    const size_t n = tree.knnSearch(r.position, k, idx.data(), d2.data());
    if (options_.radius) {
      // The nearest is the point itself (or a coincident one): neighbours j = 1..n-1.
      double sum = 0;
      for (size_t j = 1; j < n; ++j) sum += d2[j];
      const double kk = double(n - 1);
      float radius = kk > 0 ? float(std::sqrt(2.0 * sum / (kk * (kk + 1)))) : 0.0f;
      if (!(radius >= min_radius_)) radius = last_radius_ > 0 ? last_radius_ : min_radius_;
      r.radius = EncodeRadius(radius, RadiusTwoSided(r.radius), RadiusSheet(r.radius));
      last_radius_ = radius;
    }
    if (options_.normals) {
      glm::dvec3 mean(0.0);
      for (size_t j = 0; j < n; ++j) mean += glm::dvec3(glm::make_vec3(window_[idx[j]].position));
      mean /= double(n);
      std::array<std::array<double, 3>, 3> c{};
      for (size_t j = 0; j < n; ++j) {
        const glm::dvec3 d = glm::dvec3(glm::make_vec3(window_[idx[j]].position)) - mean;
        for (int a = 0; a < 3; ++a)
          for (int b = 0; b < 3; ++b) c[a][b] += d[a] * d[b];
      }
      glm::vec3 normal = n >= 3 ? SmallestEigenvector(c) : glm::vec3(0, 0, 1);
      if (!std::isfinite(normal.x) || !std::isfinite(normal.y) || !std::isfinite(normal.z)) {
        normal = glm::vec3(0, 0, 1);
      }
      const glm::vec3 p = glm::make_vec3(r.position);
      const glm::vec3 away = options_.towards_viewpoint ? options_.viewpoint - p : p - centre_;
      if (glm::dot(normal, away) < 0) normal = -normal;
      r.normal[0] = normal.x, r.normal[1] = normal.y, r.normal[2] = normal.z;
    }
  }
  for (size_t i = begin; i < end; ++i) PBGI_RETURN_IF_ERROR(sink(window_[i]));
  cur_ = end;
  return absl::OkStatus();
}

}  // namespace pbgi::internal
