#include "build/node_packer.h"

#include <cstring>
#include <deque>
#include <utility>

#include "absl/strings/str_format.h"
#include "pbgi/status.h"

namespace pbgi::internal {

NodePacker::NodePacker(Layout layout, Channels channels, PageSink* sink, uint64_t shuffle_seed)
    : layout_(layout),
      channels_(channels),
      sink_(sink),
      seed_(shuffle_seed),
      record_size_(NodeRecordSize(channels)),
      capacity_(NodesPerPage(sink->page_size(), channels)) {
  page_buf_.reserve(size_t{capacity_} * record_size_);
}

std::unique_ptr<Group> NodePacker::MakeGroup(absl::Span<ClosedNode> nodes) {
  auto g = std::make_unique<Group>();
  g->nodes.reserve(nodes.size());
  for (ClosedNode& c : nodes) g->nodes.push_back(c.node);
  // The vector never grows again, so these back pointers stay valid.
  for (PendingNode& n : g->nodes) {
    if (n.child_group != nullptr) n.child_group->parent = &n;
  }
  return g;
}

absl::Status NodePacker::WritePage(uint64_t page_no, const std::vector<Group*>& groups) {
  page_buf_.clear();
  uint32_t count = 0;
  for (const Group* g : groups) {
    for (const PendingNode& n : g->nodes) {
      if (n.child_group != nullptr) {
        return absl::InternalError(absl::StrFormat(
            "node page %d: a node's child group was not placed before its parent", page_no));
      }
      const uint8_t* p = reinterpret_cast<const uint8_t*>(&n.rec);
      page_buf_.insert(page_buf_.end(), p, p + record_size_);
      ++count;
    }
  }
  if (count > capacity_) {
    return absl::InternalError(
        absl::StrFormat("node page %d: %d records exceed capacity %d", page_no, count, capacity_));
  }
  records_written_ += count;
  return sink_->Append(Section::kNodes, page_no, PageKind::kNode, count, page_buf_);
}

absl::Status NodePacker::FlushSet(PendingSet set) {
  // A treelet goes whole into the page being filled when it fits, so treelets that close one
  // after the other (neighbours in Z-order) share a page. When it does not fit and that page is
  // nearly full, it starts a new page; otherwise it is split at sibling-group boundaries, in
  // pre-order, onto the next page, which bounds the waste per page to a quarter.
  const uint32_t room = capacity_ - seq_records_;
  if (set.records > room && room < capacity_ / 4) PBGI_RETURN_IF_ERROR(FlushSequential());
  struct ClosedPage {
    uint64_t page_no;
    std::vector<Group*> groups;
    std::vector<std::unique_ptr<Group>> owned;
  };
  std::vector<ClosedPage> closed;
  for (auto& g : set.groups) {
    if (seq_records_ + g->nodes.size() > capacity_) {
      // Written below, once every group of the set is placed: only then are the children of
      // its records sure to have refs.
      closed.push_back({next_page_, std::move(seq_groups_), std::move(seq_owned_)});
      seq_groups_.clear();
      seq_owned_.clear();
      seq_records_ = 0;
      ++next_page_;
    }
    PBGI_RETURN_IF_ERROR(AppendSequential(g.get()));
    seq_owned_.push_back(std::move(g));
  }
  for (const ClosedPage& c : closed) PBGI_RETURN_IF_ERROR(WritePage(c.page_no, c.groups));
  return absl::OkStatus();
}

absl::Status NodePacker::MergeAndFlush(std::unique_ptr<Group> group,
                                       absl::Span<ClosedNode> children, PendingSet* out) {
  uint64_t total = group->nodes.size();
  for (const ClosedNode& c : children) total += c.set.records;
  while (total > capacity_) {
    size_t largest = 0;
    for (size_t i = 1; i < children.size(); ++i) {
      if (children[i].set.records > children[largest].set.records) largest = i;
    }
    PendingSet& s = children[largest].set;
    if (s.records == 0) {
      return absl::InternalError("node packer: a sibling group does not fit in one page");
    }
    total -= s.records;
    PBGI_RETURN_IF_ERROR(FlushSet(std::move(s)));
    s = PendingSet{};
  }
  out->groups.clear();
  out->groups.push_back(std::move(group));
  for (ClosedNode& c : children) {
    for (auto& g : c.set.groups) out->groups.push_back(std::move(g));
    c.set = PendingSet{};
  }
  out->records = total;
  return absl::OkStatus();
}

absl::Status NodePacker::AppendSequential(Group* g) {
  if (seq_records_ + g->nodes.size() > capacity_) PBGI_RETURN_IF_ERROR(FlushSequential());
  g->ref = MakeNodeRef(next_page_, seq_records_);
  seq_records_ += static_cast<uint32_t>(g->nodes.size());
  seq_groups_.push_back(g);
  if (g->parent != nullptr) {
    g->parent->rec.common.children = g->ref;
    g->parent->child_group = nullptr;
  }
  return absl::OkStatus();
}

absl::Status NodePacker::FlushSequential() {
  if (seq_groups_.empty()) return absl::OkStatus();
  PBGI_RETURN_IF_ERROR(WritePage(next_page_, seq_groups_));
  ++next_page_;
  seq_groups_.clear();
  seq_owned_.clear();
  seq_records_ = 0;
  return absl::OkStatus();
}

absl::Status NodePacker::CloseInterior(absl::Span<ClosedNode> children, ClosedNode* node) {
  if (children.empty() || children.size() > 8) {
    return absl::InternalError(
        absl::StrFormat("node packer: an interior node with %d children", children.size()));
  }
  std::unique_ptr<Group> g = MakeGroup(children);
  Group* raw = g.get();
  node->node.rec.common.child_count = static_cast<uint32_t>(children.size());
  switch (layout_) {
    case Layout::kCoherent:
      node->node.child_group = raw;
      return MergeAndFlush(std::move(g), children, &node->set);
    case Layout::kPostOrder:
      // Children groups were placed when the children closed, so this group is complete.
      PBGI_RETURN_IF_ERROR(AppendSequential(raw));
      seq_owned_.push_back(std::move(g));
      node->node.rec.common.children = raw->ref;
      node->node.child_group = nullptr;
      return absl::OkStatus();
    case Layout::kBreadthFirst:
    case Layout::kShuffled:
      node->node.child_group = raw;
      all_.push_back(std::move(g));
      return absl::OkStatus();
  }
  return absl::InternalError("node packer: unknown layout");
}

absl::Status NodePacker::WriteAllInMemory(Group* root) {
  std::vector<Group*> order;
  order.reserve(all_.size() + 1);
  if (layout_ == Layout::kBreadthFirst) {
    std::deque<Group*> queue{root};
    while (!queue.empty()) {
      Group* g = queue.front();
      queue.pop_front();
      order.push_back(g);
      for (PendingNode& n : g->nodes) {
        if (n.child_group != nullptr) queue.push_back(n.child_group);
      }
    }
  } else {
    order.push_back(root);
    for (auto& g : all_) order.push_back(g.get());
    // Fisher-Yates with splitmix64, so the layout is the same on every platform.
    uint64_t state = seed_;
    auto next = [&state]() {
      uint64_t z = (state += 0x9e3779b97f4a7c15ull);
      z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
      z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
      return z ^ (z >> 31);
    };
    for (size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[next() % i]);
  }
  if (order.size() != all_.size() + 1) {
    return absl::InternalError("node packer: breadth-first walk missed sibling groups");
  }
  // Place every group first (refs resolve into parents), then serialize page by page.
  std::vector<std::vector<Group*>> pages;
  uint32_t fill = capacity_;
  for (Group* g : order) {
    if (fill + g->nodes.size() > capacity_) {
      pages.emplace_back();
      fill = 0;
    }
    g->ref = MakeNodeRef(next_page_ + pages.size() - 1, fill);
    fill += static_cast<uint32_t>(g->nodes.size());
    pages.back().push_back(g);
    if (g->parent != nullptr) {
      g->parent->rec.common.children = g->ref;
      g->parent->child_group = nullptr;
    }
  }
  for (auto& p : pages) PBGI_RETURN_IF_ERROR(WritePage(next_page_++, p));
  all_.clear();
  return absl::OkStatus();
}

absl::StatusOr<NodeRef> NodePacker::Finish(ClosedNode root) {
  // The root record lives in a group of its own; a stand-in parent receives its ref.
  PendingNode& holder = root_holder_;
  holder = PendingNode{};
  std::unique_ptr<Group> g = MakeGroup(absl::MakeSpan(&root, 1));
  g->parent = &holder;
  holder.child_group = g.get();
  switch (layout_) {
    case Layout::kCoherent: {
      PendingSet set;
      PBGI_RETURN_IF_ERROR(MergeAndFlush(std::move(g), absl::MakeSpan(&root, 1), &set));
      PBGI_RETURN_IF_ERROR(FlushSet(std::move(set)));
      PBGI_RETURN_IF_ERROR(FlushSequential());
      break;
    }
    case Layout::kPostOrder:
      PBGI_RETURN_IF_ERROR(AppendSequential(g.get()));
      seq_owned_.push_back(std::move(g));
      PBGI_RETURN_IF_ERROR(FlushSequential());
      break;
    case Layout::kBreadthFirst:
    case Layout::kShuffled: {
      Group* raw = g.get();
      PBGI_RETURN_IF_ERROR(WriteAllInMemory(raw));
      break;
    }
  }
  if (holder.child_group != nullptr) return absl::InternalError("node packer: root not placed");
  return holder.rec.common.children;
}

}  // namespace pbgi::internal
