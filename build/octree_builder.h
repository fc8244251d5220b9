// Builds the octree in one streaming pass over points sorted by Morton key (docs/design.md, "Build"
// step 3; Salmon & Warren 1997; Kontkanen et al. keep leaf_size + 1 points in memory).
//
// A node is interior iff it holds more than leaf_size points and lies above the maximum depth.
// Since a node's points are contiguous in Morton order, when point i is the first point of a
// node at depth d, the node is interior iff point i + leaf_size shares its depth-d key prefix:
// a look-ahead window of leaf_size + 1 points decides every node when it opens. Open nodes (at
// most 22, the path to the current point) accumulate aggregates in double; a node closes when the
// first point outside it arrives, children before parents, and goes to the NodePacker. Points
// stream straight to point pages in arrival (= Morton = depth-first) order.
//
// Not thread-safe.
#ifndef PBGI_BUILD_OCTREE_BUILDER_H_
#define PBGI_BUILD_OCTREE_BUILDER_H_

#include <array>
#include <cstdint>
#include <limits>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "build/node_packer.h"
#include "build/sort_record.h"
#include "pbgi/surfel.h"
#include "store/page_io.h"
#include "tree/format.h"
#include "tree/morton.h"

namespace pbgi::internal {

// Writes points in order into full point pages, encoded on `grid` (tree/format.h).
class PointPageWriter {
 public:
  PointPageWriter(Channels channels, PageSink* sink, const PositionGrid& grid);
  // Appends r and sets *stored to r as the page holds it (quantized): what every reader of the
  // store will decode, so the node aggregates are made from it.
  absl::Status Add(const SortRecord& r, SortRecord* stored);
  // Every record that Add will get is already as a page holds it (it was decoded from a compact
  // sort run, build/spill_codec.h), so Add hands it back as it is: encoding a decoded record is
  // idempotent, and decoding it again was about 7 % of the octree pass thread's instructions
  // (docs/format.md, "Session 12").
  void set_input_quantized(bool q) { input_quantized_ = q; }
  // Every record that Add will get is packed (SpillCodec::Pack): its bytes are the point record
  // already, so Add copies them into the page and decodes them once for *stored, instead of
  // encoding the record (docs/format.md, "Session 13").
  void set_input_packed(bool p) { input_packed_ = p; }
  // With set_input_packed: appends r's point record, whose decoded form the caller already has
  // (SpillCodec::UnpackBlock, a block at a time).
  absl::Status AddPacked(const SortRecord& r);
  absl::Status Flush();
  uint64_t pages() const { return next_page_; }
  uint64_t points() const { return points_; }

 private:
  Channels channels_;
  PageSink* sink_;
  PositionGrid grid_;
  uint32_t record_size_;
  uint32_t per_page_;
  std::vector<uint8_t> buf_;
  uint32_t count_ = 0;
  uint64_t next_page_ = 0;
  uint64_t points_ = 0;
  bool input_quantized_ = false;
  bool input_packed_ = false;
};

// Sums of a node's points, in double (docs/design.md, "Build" step 4).
struct NodeAggregate {
  Bounds bounds;
  double area = 0;
  std::array<double, 9> sh_area{};
  std::array<std::array<double, 9>, 3> sh_power{};
  // A leaf's least and greatest surfel luminance (the mean of the channels), for its contrast
  // (NodeRecordRadiance::contrast); not merged by Add().
  double lum_min = std::numeric_limits<double>::infinity();
  double lum_max = -std::numeric_limits<double>::infinity();

  void AddPoint(const SortRecord& r, bool radiance);
  // The luminance of the mean radiance: band 0 of the power over band 0 of the projected area
  // (0 without area).
  double Luminance() const;
  void Add(const NodeAggregate& o);
};

struct OctreeStats {
  uint64_t nodes = 0;
  uint64_t leaves = 0;
  uint32_t max_depth = 0;
  uint64_t max_leaf_points = 0;
  Bounds bounds;
};

class OctreeBuilder {
 public:
  OctreeBuilder(uint32_t leaf_size, Channels channels, PointPageWriter* points, NodePacker* packer);
  // Points must arrive in non-decreasing key order.
  absl::Status Add(const SortRecord& r);
  // As Add, for a PointPageWriter with set_input_packed, with `stored` = SpillCodec::Unpack(r)
  // made beforehand (SpillCodec::UnpackBlock), so that AddPoint does not decode r again. Use
  // either this or Add for all the points of a build.
  absl::Status Add(const SortRecord& r, const SortRecord& stored);
  // Closes every open node and returns the root's ref. REQUIRES: at least one point.
  absl::StatusOr<NodeRef> Finish();
  const OctreeStats& stats() const { return stats_; }

 private:
  struct OpenNode {
    uint32_t depth = 0;
    TreePrefix prefix;
    uint64_t first_point = 0;
    uint64_t count = 0;
    NodeAggregate agg;
    std::vector<ClosedNode> children;
  };

  // `rank`: the point's rank among the points of its key (tree/morton.h, kVirtualLevels); the
  // ahead point is the one leaf_size places later.
  // `stored`: r as its point page holds it, when known (else null).
  absl::Status Process(const SortRecord& r, const SortRecord* stored, uint32_t rank,
                       bool have_ahead, uint64_t ahead_key, uint32_t ahead_rank);
  // Writes r to its point page and adds it, as stored, to the open leaf's aggregate.
  absl::Status AddPoint(const SortRecord& r, const SortRecord* stored);
  // Puts r (and `stored`, if not null) into the window; processes the oldest point when full.
  absl::Status Push(const SortRecord& r, const SortRecord* stored);
  PendingNode MakeRecord(const OpenNode& n, bool leaf) const;
  absl::Status CloseLeaf();
  absl::Status CloseTop();
  absl::Status Deliver(ClosedNode closed, const NodeAggregate& agg, uint64_t count);

  uint32_t leaf_size_;
  Channels channels_;
  PointPageWriter* points_;
  NodePacker* packer_;
  // Look-ahead window: a ring of leaf_size + 1 records.
  std::vector<SortRecord> window_;
  std::vector<uint32_t> window_rank_;      // each window record's rank (same ring positions)
  std::vector<SortRecord> window_stored_;  // Add(r, stored): each record's `stored` (same ring)
  size_t window_head_ = 0, window_size_ = 0;
  uint32_t last_rank_ = 0;
  uint64_t next_point_ = 0;  // global index of the next point to place
  uint64_t last_key_ = 0;
  bool any_ = false;
  std::vector<OpenNode> stack_;  // open interior nodes, root first
  // Children vectors of closed interior nodes, emptied with their capacity kept: an interior
  // node takes one instead of growing a new one (4 allocations for 8 children).
  std::vector<std::vector<ClosedNode>> spare_children_;
  bool leaf_open_ = false;
  OpenNode leaf_;
  bool have_root_ = false;
  ClosedNode root_;
  OctreeStats stats_;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_OCTREE_BUILDER_H_
