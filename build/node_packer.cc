#include "build/node_packer.h"

#include <algorithm>
#include <cstring>
#include <deque>
#include <utility>

#include "absl/strings/str_format.h"
#include "pbgi/status.h"

namespace pbgi::internal {

NodePacker::NodePacker(Layout layout, Channels channels, PageSink* sink, uint64_t shuffle_seed,
                       const PositionGrid& grid)
    : layout_(layout),
      channels_(channels),
      sink_(sink),
      grid_(grid),
      seed_(shuffle_seed),
      record_size_(NodeRecordSize(channels)),
      capacity_(NodesPerPage(sink->page_size(), channels)),
      // A quarter page: units small enough that a page holds several neighbours (measured
      // against C and C/2, docs/format.md), and at least one sibling group.
      unit_records_(std::max<uint32_t>(8, capacity_ / 4)) {
  page_buf_.reserve(size_t{capacity_} * record_size_);
}

std::unique_ptr<Group> NodePacker::MakeGroup(absl::Span<ClosedNode> nodes) {
  auto g = std::make_unique<Group>();
  g->nodes.reserve(nodes.size());
  for (ClosedNode& c : nodes) g->nodes.push_back(c.node);
  // The vector never grows again, so these back pointers stay valid.
  for (PendingNode& n : g->nodes) {
    if (n.child_group == nullptr) continue;
    if (n.child_group->written) {
      // An upper subtree written early: its top waited as a stub for this record.
      n.rec.common.children = n.child_group->ref;
      Group* stub = n.child_group;
      n.child_group = nullptr;
      std::erase_if(stubs_, [stub](const std::unique_ptr<Group>& s) { return s.get() == stub; });
    } else {
      n.child_group->parent = &n;
    }
  }
  return g;
}

absl::Status NodePacker::WritePage(uint64_t page_no, const std::vector<Group*>& groups) {
  uint64_t count = 0;
  for (const Group* g : groups) count += g->nodes.size();
  if (count > capacity_) {
    return absl::InternalError(
        absl::StrFormat("node page %d: %d records exceed capacity %d", page_no, count, capacity_));
  }
  // Sized once a page: a resize per record zero-filled each record before it was encoded.
  page_buf_.resize(count * record_size_);
  uint8_t* dst = page_buf_.data();
  for (const Group* g : groups) {
    for (const PendingNode& n : g->nodes) {
      if (n.child_group != nullptr) {
        return absl::InternalError(absl::StrFormat(
            "node page %d: a node's child group was not placed before its parent", page_no));
      }
      EncodeNodeRecord(n.rec, channels_, grid_, dst);
      dst += record_size_;
    }
  }
  records_written_ += count;
  return sink_->Append(Section::kNodes, page_no, PageKind::kNode, static_cast<uint32_t>(count),
                       page_buf_);
}

void NodePacker::PlaceInPage(uint64_t page_no, const std::vector<Group*>& groups) {
  uint32_t slot = 0;
  for (Group* g : groups) {
    g->ref = MakeNodeRef(page_no, slot);
    slot += static_cast<uint32_t>(g->nodes.size());
    if (g->parent != nullptr) {
      g->parent->rec.common.children = g->ref;
      g->parent->child_group = nullptr;
    }
  }
}

absl::Status NodePacker::AppendUnit(PendingSet set) {
  if (set.records == 0) return absl::OkStatus();
  // Next fit in Z-order. A unit that does not fit continues on the next page (at a group
  // boundary, in pre-order) if at least half a unit of room is left, which keeps pages ~full;
  // otherwise it starts a new page, which keeps most units whole. A page left behind is written
  // once the whole unit is placed: only then do its records know their children's refs.
  const uint32_t room = capacity_ - seq_records_;
  if (set.records > room && room < unit_records_ / 2) PBGI_RETURN_IF_ERROR(FlushSequential());
  struct LeftPage {
    uint64_t page_no;
    std::vector<Group*> groups;
    std::vector<std::unique_ptr<Group>> owned;
  };
  std::vector<LeftPage> left;
  for (auto& g : set.groups) {
    if (seq_records_ + g->nodes.size() > capacity_) {
      left.push_back({next_page_, std::move(seq_groups_), std::move(seq_owned_)});
      seq_groups_.clear();
      seq_owned_.clear();
      seq_records_ = 0;
      ++next_page_;
    }
    PBGI_RETURN_IF_ERROR(AppendSequential(g.get()));
    seq_owned_.push_back(std::move(g));
  }
  for (const LeftPage& p : left) PBGI_RETURN_IF_ERROR(WritePage(p.page_no, p.groups));
  return absl::OkStatus();
}

std::vector<std::vector<Group*>> NodePacker::PackNextFit(const std::vector<Group*>& seq) const {
  std::vector<std::vector<Group*>> pages;
  uint64_t fill = capacity_;
  for (Group* g : seq) {
    if (fill + g->nodes.size() > capacity_) {
      pages.emplace_back();
      fill = 0;
    }
    pages.back().push_back(g);
    fill += g->nodes.size();
  }
  return pages;
}

absl::Status NodePacker::PlaceAndWritePages(const std::vector<std::vector<Group*>>& pages) {
  // Place every page first (a parent may point at a later page), then write them in order.
  for (size_t i = 0; i < pages.size(); ++i) PlaceInPage(next_page_ + i, pages[i]);
  for (const auto& p : pages) PBGI_RETURN_IF_ERROR(WritePage(next_page_++, p));
  return absl::OkStatus();
}

absl::Status NodePacker::WriteUpperSubtree(Group* top) {
  // The bottom page being filled owns the next page number: close it first.
  PBGI_RETURN_IF_ERROR(FlushSequential());
  std::vector<Group*> seq;
  std::vector<Group*> stack{top};
  while (!stack.empty()) {
    Group* g = stack.back();
    stack.pop_back();
    seq.push_back(g);
    for (size_t i = g->nodes.size(); i-- > 0;) {
      if (g->nodes[i].child_group != nullptr) stack.push_back(g->nodes[i].child_group);
    }
  }
  uint64_t records = 0;
  for (const Group* g : seq) records += g->nodes.size();
  if (records != top->subtree_records) {
    return absl::InternalError(
        absl::StrFormat("node packer: an upper subtree counts %d records but holds %d",
                        top->subtree_records, records));
  }
  // Level by level: pre-order restricted to one depth is that depth's Z-order.
  std::stable_sort(seq.begin(), seq.end(), [](const Group* a, const Group* b) {
    return a->nodes[0].rec.common.depth < b->nodes[0].rec.common.depth;
  });
  PBGI_RETURN_IF_ERROR(PlaceAndWritePages(PackNextFit(seq)));
  for (Group* g : seq) {
    g->written = true;
    g->nodes = std::vector<PendingNode>();  // a written group keeps only its ref
  }
  upper_held_ -= records;
  std::erase(upper_tops_, top);
  // The top stays (as a stub) until its parent record takes its ref; the rest is freed.
  for (auto& g : all_) {
    if (g.get() == top) stubs_.push_back(std::move(g));
  }
  std::erase_if(all_, [](const std::unique_ptr<Group>& g) { return g == nullptr || g->written; });
  return absl::OkStatus();
}

absl::Status NodePacker::KeepUpperUnderLimit() {
  while (upper_held_ * kBytesPerUpperRecord > upper_limit_bytes_ && !upper_tops_.empty()) {
    Group* largest = upper_tops_[0];
    for (Group* g : upper_tops_) {
      if (g->subtree_records > largest->subtree_records) largest = g;
    }
    PBGI_RETURN_IF_ERROR(WriteUpperSubtree(largest));
    ++early_upper_writes_;
  }
  return absl::OkStatus();
}

absl::Status NodePacker::CloseCoherent(std::unique_ptr<Group> group,
                                       absl::Span<ClosedNode> children, PendingSet* out) {
  uint64_t total = group->nodes.size();
  bool upper = false;
  for (const ClosedNode& c : children) {
    upper = upper || c.set.upper;
    total += c.set.records;
  }
  out->groups.clear();
  if (!upper && total <= unit_records_) {
    // A small node: its descendants, in pre-order, wait for its parent.
    out->groups.push_back(std::move(group));
    for (ClosedNode& c : children) {
      for (auto& g : c.set.groups) out->groups.push_back(std::move(g));
      c.set = PendingSet{};
    }
    out->records = total;
    out->upper = false;
    return absl::OkStatus();
  }
  // An upper node: each small child's subtree is a complete unit.
  for (ClosedNode& c : children) {
    if (!c.set.upper) PBGI_RETURN_IF_ERROR(AppendUnit(std::move(c.set)));
    c.set = PendingSet{};
  }
  // The upper children's subtrees (still held) now hang below this group.
  group->subtree_records = group->nodes.size();
  for (const PendingNode& n : group->nodes) {
    if (n.child_group == nullptr) continue;
    group->subtree_records += n.child_group->subtree_records;
    std::erase(upper_tops_, n.child_group);
  }
  upper_tops_.push_back(group.get());
  upper_held_ += group->nodes.size();
  upper_records_ += group->nodes.size();
  peak_upper_held_ = std::max(peak_upper_held_, upper_held_);
  all_.push_back(std::move(group));
  out->records = 0;
  out->upper = true;
  return KeepUpperUnderLimit();
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
      return CloseCoherent(std::move(g), children, &node->set);
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
  PBGI_RETURN_IF_ERROR(PlaceAndWritePages(PackNextFit(order)));
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
      Group* raw = g.get();
      PendingSet set;
      PBGI_RETURN_IF_ERROR(CloseCoherent(std::move(g), absl::MakeSpan(&root, 1), &set));
      // A tree of at most one unit is written whole; otherwise the root group tops the upper
      // part, written level by level after every bottom page.
      const bool upper = set.upper;
      if (!upper) PBGI_RETURN_IF_ERROR(AppendUnit(std::move(set)));
      PBGI_RETURN_IF_ERROR(FlushSequential());
      if (upper && !raw->written) PBGI_RETURN_IF_ERROR(WriteUpperSubtree(raw));
      if (upper_held_ != 0 || !upper_tops_.empty() || !all_.empty()) {
        return absl::InternalError(
            absl::StrFormat("node packer: %d upper records left unwritten", upper_held_));
      }
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
