// Packs closed octree nodes into node pages (docs/design.md, "Build" step 5).
//
// Nodes arrive in post-order, children before parents. The children of one node (a sibling
// group) always share one page, so a parent points at them with one NodeRef and a count
// (tree/format.h).
//
// Coherent layout. A gather at the default cut visits ~90 nodes per level, in a disc of a few
// cells around the receiver at every level of the tree (the far field), and descends to the
// leaves only near it. A page that holds one level of a region serves that disc best; a page
// that holds a treelet (a group and the levels below it) covers only a few cells of its top
// level, so the disc at that level spans many pages (docs/format.md has the measurements). So:
//  - Bottom: let D(n) be the number of records below node n. A node is *small* when
//    D(n) <= kUnitRecords (a quarter page): it carries a pending set, its descendants' sibling
//    groups in pre-order. When a node closes as *upper* (not small), each small child's set is a
//    complete subtree, a unit: units are appended to the current page in Z-order (next fit), so
//    a page holds neighbouring small subtrees and a walk that enters one stays in the page to
//    the leaves. A unit that does not fit continues on the next page at a sibling-group
//    boundary when at least half a unit of room is left; otherwise it starts a new page.
//  - Top: the sibling groups of upper nodes' children are held in memory and written level by
//    level (breadth-first, each level in Z-order), the way the breadth-first layout writes the
//    whole tree: a page holds ~C neighbouring nodes of one depth. They are written at Finish,
//    after all bottom pages, so page numbers only grow; the root's page comes first among them.
// Memory: at most 21 x 8 pending sets of kUnitRecords records, one page, and the upper groups,
// about 8 x nodes / kUnitRecords records. The upper groups are bounded by upper_limit_bytes():
// beyond it, the largest closed upper subtree is written at once, level by level on its own
// pages (the same layout, cut at that subtree's boundary), and only a stub stays until its
// parent closes.
//
// Not thread-safe.
#ifndef PBGI_BUILD_NODE_PACKER_H_
#define PBGI_BUILD_NODE_PACKER_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/build.h"
#include "store/page_io.h"
#include "tree/format.h"

namespace pbgi::internal {

struct Group;

// A node record waiting for its page, and its pending child group (if that group is not placed
// yet; once placed, rec.common.children holds its ref and child_group is null).
struct PendingNode {
  NodeRecordRadiance rec{};
  Group* child_group = nullptr;
};

// One sibling group: records stored contiguously in one page.
struct Group {
  std::vector<PendingNode> nodes;
  PendingNode* parent = nullptr;  // the record pointing at this group (null for the root group)
  NodeRef ref = kNoNodeRef;       // first slot, once placed
  // Coherent layout, upper groups: records of this group and of the unwritten upper groups
  // below it; `written` once placed and written (then `nodes` is released).
  uint64_t subtree_records = 0;
  bool written = false;
};

// Coherent layout: `upper` marks a node whose descendants are more than a unit; its child group
// is then held in memory (or already written) and `groups` is empty.
struct PendingSet {
  std::vector<std::unique_ptr<Group>> groups;
  uint64_t records = 0;
  bool upper = false;
};

// A closed node as its parent sees it.
struct ClosedNode {
  PendingNode node;
  PendingSet set;
};

class NodePacker {
 public:
  // Node records are encoded on `grid` (tree/format.h).
  NodePacker(Layout layout, Channels channels, PageSink* sink, uint64_t shuffle_seed,
             const PositionGrid& grid);
  NodePacker(const NodePacker&) = delete;
  NodePacker& operator=(const NodePacker&) = delete;

  // Records per node page.
  uint32_t capacity() const { return capacity_; }
  // Coherent layout: the largest small subtree (records below a node), a quarter page.
  uint32_t unit_records() const { return unit_records_; }

  // Coherent layout: bytes of upper groups held in memory before the largest closed upper
  // subtree is written early. The default, kDefaultUpperLimitBytes, holds the upper part of
  // ~5 M points (16 KiB pages) or ~20 M points (64 KiB pages) whole.
  static constexpr uint64_t kDefaultUpperLimitBytes = uint64_t{16} << 20;
  void set_upper_limit_bytes(uint64_t bytes) { upper_limit_bytes_ = bytes; }
  uint64_t upper_limit_bytes() const { return upper_limit_bytes_; }
  // Bytes held per upper record (the record, its pointers, its share of the group).
  static constexpr uint64_t kBytesPerUpperRecord = sizeof(PendingNode) + 24;

  // The interior node `node` closes with `children` (1..8, in child order). Links node to its
  // child group and gives it its pending set.
  absl::Status CloseInterior(absl::Span<ClosedNode> children, ClosedNode* node);
  // The root closed: writes everything left and returns the root's NodeRef.
  absl::StatusOr<NodeRef> Finish(ClosedNode root);

  uint64_t pages() const { return next_page_; }
  uint64_t records_written() const { return records_written_; }
  // Coherent layout: upper records (all of them, whether written early or at Finish), the most
  // held in memory at once, and the upper subtrees written early to stay under the limit.
  uint64_t upper_records() const { return upper_records_; }
  uint64_t peak_upper_held() const { return peak_upper_held_; }
  uint64_t early_upper_writes() const { return early_upper_writes_; }

 private:
  std::unique_ptr<Group> MakeGroup(absl::Span<ClosedNode> nodes);
  absl::Status WritePage(uint64_t page_no, const std::vector<Group*>& groups);
  // Assigns refs to `groups`, laid out in this order from slot 0 of page_no.
  void PlaceInPage(uint64_t page_no, const std::vector<Group*>& groups);
  // Sequential packing of groups in the given order (postorder, breadth-first, shuffled).
  absl::Status AppendSequential(Group* g);
  absl::Status FlushSequential();
  absl::Status WriteAllInMemory(Group* root);
  // Coherent layout.
  absl::Status CloseCoherent(std::unique_ptr<Group> group, absl::Span<ClosedNode> children,
                             PendingSet* out);
  absl::Status AppendUnit(PendingSet set);
  // Writes the upper subtree below (and including) `top`, level by level.
  absl::Status WriteUpperSubtree(Group* top);
  absl::Status KeepUpperUnderLimit();
  // Groups in the order given, packed next fit into pages (a group never straddles two).
  std::vector<std::vector<Group*>> PackNextFit(const std::vector<Group*>& seq) const;
  // Assigns refs to every page's groups from next_page_ on, then writes the pages.
  absl::Status PlaceAndWritePages(const std::vector<std::vector<Group*>>& pages);

  Layout layout_;
  Channels channels_;
  PageSink* sink_;
  PositionGrid grid_;
  uint64_t seed_;
  uint32_t record_size_;
  uint32_t capacity_;
  uint32_t unit_records_;
  uint64_t next_page_ = 0;
  uint64_t records_written_ = 0;
  // Sequential layouts and the coherent bottom: the page being filled.
  std::vector<Group*> seq_groups_;
  uint32_t seq_records_ = 0;
  std::vector<std::unique_ptr<Group>> seq_owned_;
  // Breadth-first and shuffled: every group, until Finish. Coherent: the upper groups.
  std::vector<std::unique_ptr<Group>> all_;
  // Coherent: tops of the closed upper subtrees whose parent has not closed yet.
  std::vector<Group*> upper_tops_;
  // Coherent: tops of upper subtrees written early, kept until their parent record takes the ref.
  std::vector<std::unique_ptr<Group>> stubs_;
  uint64_t upper_held_ = 0;
  uint64_t upper_records_ = 0;
  uint64_t peak_upper_held_ = 0;
  uint64_t early_upper_writes_ = 0;
  uint64_t upper_limit_bytes_ = kDefaultUpperLimitBytes;
  std::vector<uint8_t> page_buf_;
  PendingNode root_holder_;  // stand-in parent that receives the root's ref
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_NODE_PACKER_H_
