// Packs closed octree nodes into node pages (DESIGN.md, "Build" step 5).
//
// Nodes arrive in post-order, children before parents. The children of one node (a sibling
// group) always share one page, so a parent points at them with one NodeRef and a count
// (store/page_format.h). In the coherent layout a closed node carries a "pending set": the
// sibling groups below it that are not yet written, at most one page of records. When a node
// closes, its children's groups become a new group and its children's pending sets merge into
// the node's; while the merged set exceeds a page, the largest child set is flushed as a page of
// its own. A flushed set (a treelet: a group and as many levels below it as fit, in pre-order)
// goes whole into the page being filled when it fits, so treelets that close one after the other
// (neighbours in Z-order) share a page; otherwise it starts a new page (when less than a quarter
// of the current one is free) or continues onto the next page at a sibling-group boundary.
// Page numbers are assigned as pages fill; a page is written once every record in it knows its
// children's ref. At most (depth x 8) pending sets plus one page are held in memory.
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
#include "build/page_sink.h"
#include "pbgi/build.h"
#include "store/page_format.h"

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
};

// Groups below a closed node that are not yet written, in pre-order.
struct PendingSet {
  std::vector<std::unique_ptr<Group>> groups;
  uint64_t records = 0;
};

// A closed node as its parent sees it.
struct ClosedNode {
  PendingNode node;
  PendingSet set;
};

class NodePacker {
 public:
  NodePacker(Layout layout, Channels channels, PageSink* sink, uint64_t shuffle_seed);
  NodePacker(const NodePacker&) = delete;
  NodePacker& operator=(const NodePacker&) = delete;

  // Records per node page.
  uint32_t capacity() const { return capacity_; }

  // The interior node `node` closes with `children` (1..8, in child order). Links node to its
  // child group and gives it its pending set.
  absl::Status CloseInterior(absl::Span<ClosedNode> children, ClosedNode* node);
  // The root closed: writes everything left and returns the root's NodeRef.
  absl::StatusOr<NodeRef> Finish(ClosedNode root);

  uint64_t pages() const { return next_page_; }
  uint64_t records_written() const { return records_written_; }

 private:
  std::unique_ptr<Group> MakeGroup(absl::Span<ClosedNode> nodes);
  absl::Status MergeAndFlush(std::unique_ptr<Group> group, absl::Span<ClosedNode> children,
                             PendingSet* out);
  absl::Status FlushSet(PendingSet set);
  absl::Status WritePage(uint64_t page_no, const std::vector<Group*>& groups);
  // Sequential packing of groups in the given order (postorder, breadth-first, shuffled).
  absl::Status AppendSequential(Group* g);
  absl::Status FlushSequential();
  absl::Status WriteAllInMemory(Group* root);

  Layout layout_;
  Channels channels_;
  PageSink* sink_;
  uint64_t seed_;
  uint32_t record_size_;
  uint32_t capacity_;
  uint64_t next_page_ = 0;
  uint64_t records_written_ = 0;
  // Sequential layouts: the page being filled.
  std::vector<Group*> seq_groups_;
  uint32_t seq_records_ = 0;
  std::vector<std::unique_ptr<Group>> seq_owned_;
  // Breadth-first and shuffled: every group, until Finish.
  std::vector<std::unique_ptr<Group>> all_;
  std::vector<uint8_t> page_buf_;
  PendingNode root_holder_;  // stand-in parent that receives the root's ref
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_NODE_PACKER_H_
