// Morton (Z-order) keys: 21 bits per axis interleaved into 63 bits (Morton 1966). Z-order is the
// depth-first order of the octree whose cell at depth d is the key prefix of 3*d bits. The point
// order on disk is this order (tree/format.h); the builder sorts by it and the query layer
// orders receivers by it.
#ifndef PBGI_TREE_MORTON_H_
#define PBGI_TREE_MORTON_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "glm/common.hpp"
#include "glm/vec3.hpp"
#include "pbgi/surfel.h"
#include "tree/format.h"

namespace pbgi::internal {

inline constexpr int kMortonBitsPerAxis = 21;
inline constexpr uint32_t kMaxOctreeDepth = 21;  // a depth-21 cell holds one key

// Below a depth-21 cell that holds more than a leaf's points (coincident points, or points
// closer than a cell), the tree goes on splitting by arrival order: the i-th point of the cell
// (its rank) has a virtual key of kVirtualLevels octal digits, most significant first, and the
// node at depth 21 + v holds the points whose ranks share the top v digits. So the pile gets
// aggregates at every level and the cut works on it like on any other subtree, with leaves of
// at most the leaf size (down to one point at kMaxSplitDepth). Ranks beyond kMaxRank all go to
// the cell's last leaf. A pile of n points makes a chain of 10 - ceil(log8 n) single-child
// nodes above its first split.
inline constexpr uint32_t kVirtualLevels = 10;
inline constexpr uint32_t kMaxSplitDepth = kMaxOctreeDepth + kVirtualLevels;  // 31
inline constexpr uint32_t kMaxRank = (1u << (3 * kVirtualLevels)) - 1;

// The node of depth `depth` that holds the point of `key` and rank `rank` in its cell.
struct TreePrefix {
  uint64_t key = 0;   // KeyPrefix(key, depth), the whole key below depth 21
  uint32_t rank = 0;  // the rank's top (depth - 21) octal digits below depth 21, else 0
  bool operator==(const TreePrefix& o) const { return key == o.key && rank == o.rank; }
  bool operator!=(const TreePrefix& o) const { return !(*this == o); }
};

// Spreads the low 21 bits of v so that bit i lands at bit 3*i.
inline uint64_t SpreadBits3(uint32_t v) {
  uint64_t x = v & 0x1fffffu;
  x = (x | x << 32) & 0x1f00000000ffffull;
  x = (x | x << 16) & 0x1f0000ff0000ffull;
  x = (x | x << 8) & 0x100f00f00f00f00full;
  x = (x | x << 4) & 0x10c30c30c30c30c3ull;
  x = (x | x << 2) & 0x1249249249249249ull;
  return x;
}

inline uint64_t MortonEncode(uint32_t x, uint32_t y, uint32_t z) {
  return SpreadBits3(x) | (SpreadBits3(y) << 1) | (SpreadBits3(z) << 2);
}

// The key prefix identifying the depth-d cell that contains `key`.
inline uint64_t KeyPrefix(uint64_t key, uint32_t depth) {
  return depth == 0 ? 0 : key >> (3 * (kMaxOctreeDepth - depth));
}

inline TreePrefix PrefixAt(uint64_t key, uint32_t rank, uint32_t depth) {
  if (depth <= kMaxOctreeDepth) return {KeyPrefix(key, depth), 0};
  return {key, rank >> (3 * (kMaxSplitDepth - depth))};
}

// Points may lie outside declared bounds by float rounding (a sampled point on a triangle's
// edge), never by more: a margin of 1e-5 of the box (and 1e-6 of its coordinates) catches a
// stale or wrong declaration without refusing rounding. The builder refuses a point outside
// it; the reader accepts a key box (build statistic key_bounds) whose tolerance holds the
// points' box.
inline Bounds KeyBoundsTolerance(const Bounds& b) {
  const glm::vec3 e = b.Extent();
  const float m = std::max({e.x, e.y, e.z});
  const float c = std::max({std::abs(b.lo.x), std::abs(b.lo.y), std::abs(b.lo.z), std::abs(b.hi.x),
                            std::abs(b.hi.y), std::abs(b.hi.z)});
  const float pad = 1e-5f * m + 1e-6f * c;
  Bounds out = b;
  out.lo -= glm::vec3(pad);
  out.hi += glm::vec3(pad);
  return out;
}

// Maps positions to keys inside a cube around the bounds, padded so that rounding never pushes
// a point out; points on the upper boundary land in the last cell (clamped), never outside.
// The cube of the octree's root cell around the bounds, padded so that rounding never pushes
// a point out: the cell at depth d with key prefix k is the cube of side size / 2^d at
// origin + (the prefix's x, y, z) * that side.
struct MortonCube {
  glm::dvec3 origin{0.0};
  double size = 0.0;

  explicit MortonCube(const Bounds& b) {
    glm::dvec3 lo(b.lo), hi(b.hi);
    glm::dvec3 center = 0.5 * (lo + hi);
    double half = 0.5 * std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
    // Pad relative to both the size and the magnitude of the coordinates (a cloud far from
    // the origin has a float spacing much larger than its own extent allows for).
    double mag = std::max({std::abs(center.x), std::abs(center.y), std::abs(center.z)});
    half = half * (1.0 + 1e-6) + mag * 1e-7 + 1e-30;
    if (!(half > 0) || !std::isfinite(half)) half = 1.0;
    origin = center - glm::dvec3(half);
    size = 2.0 * half;
  }

  // The depth-d cell that contains p (a point of a node at that depth: its bounds' lo corner).
  Bounds CellOf(const glm::vec3& p, uint32_t depth) const {
    // Below the key's resolution (a pile split by arrival rank) the cell is the finest one.
    const uint32_t d = std::min<uint32_t>(depth, kMortonBitsPerAxis);
    const double cells = double(uint64_t{1} << d);
    const double side = size / cells;
    // Clamped first, then truncated: the same as floor then clamp (a value below 0 ends at 0
    // either way), without a libm floor call per axis (most of a gather's cost per cell).
    // A NaN coordinate (never stored: the builder refuses it) lands in cell 0, not in a
    // conversion of NaN to an integer.
    const glm::dvec3 q = (glm::dvec3(p) - origin) / side;
    auto index = [cells](double v) {
      return v > 0.0 ? double(int64_t(std::min(v, cells - 1.0))) : 0.0;
    };
    const glm::dvec3 i(index(q.x), index(q.y), index(q.z));
    Bounds cell;
    cell.lo = glm::vec3(origin + i * side);
    cell.hi = glm::vec3(origin + (i + 1.0) * side);
    return cell;
  }
};

// The position grid of a store (tree/format.h) over the cube: one cell per depth-21 Morton cell,
// in float.
inline PositionGrid GridOfCube(const MortonCube& cube) {
  PositionGrid g;
  for (int a = 0; a < 3; ++a) g.origin[a] = static_cast<float>(cube.origin[a]);
  g.step = static_cast<float>(cube.size / double(1u << kMortonBitsPerAxis));
  return g;
}

class MortonQuantizer {
 public:
  explicit MortonQuantizer(const Bounds& b) {
    const MortonCube cube(b);
    origin_ = cube.origin;
    scale_ = double(1u << kMortonBitsPerAxis) / cube.size;
  }

  uint64_t Key(const glm::vec3& p) const {
    return MortonEncode(Quantize(p.x, origin_.x), Quantize(p.y, origin_.y),
                        Quantize(p.z, origin_.z));
  }

 private:
  uint32_t Quantize(float v, double origin) const {
    double q = (double(v) - origin) * scale_;
    constexpr double kMax = double((1u << kMortonBitsPerAxis) - 1);
    if (!(q > 0)) return 0;
    if (q >= kMax) return (1u << kMortonBitsPerAxis) - 1;
    return static_cast<uint32_t>(q);
  }

  glm::dvec3 origin_;
  double scale_;
};

// The order that visits `count` points in Z-order inside their own bounds: indices sorted by
// the Morton key of position(i) (ties by index). Receivers are visited in this order (ZOrder in
// pbgi/query.h, the shading driver) so that consecutive ones walk neighbouring subtrees.
template <typename PositionFn>
std::vector<uint32_t> MortonOrder(size_t count, PositionFn&& position) {
  Bounds b;
  for (size_t i = 0; i < count; ++i) b.Extend(position(i));
  const MortonQuantizer quantizer(b);
  std::vector<std::pair<uint64_t, uint32_t>> keyed(count);
  for (size_t i = 0; i < count; ++i) {
    keyed[i] = {quantizer.Key(position(i)), static_cast<uint32_t>(i)};
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<uint32_t> order(count);
  for (size_t i = 0; i < keyed.size(); ++i) order[i] = keyed[i].second;
  return order;
}

}  // namespace pbgi::internal

#endif  // PBGI_TREE_MORTON_H_
