#include "build/octree_builder.h"

#include <algorithm>
#include <cstring>
#include <utility>

#include "absl/strings/str_format.h"
#include "build/spill_codec.h"
#include "pbgi/sh.h"
#include "pbgi/status.h"
#include "tree/morton.h"

namespace pbgi::internal {

PointPageWriter::PointPageWriter(Channels channels, PageSink* sink, const PositionGrid& grid)
    : channels_(channels),
      sink_(sink),
      grid_(grid),
      record_size_(PointRecordSize(channels)),
      per_page_(PointsPerPage(sink->page_size(), channels)) {
  buf_.resize(size_t{per_page_} * record_size_);
}

absl::Status PointPageWriter::Add(const SortRecord& r, SortRecord* stored) {
  uint8_t* dst = buf_.data() + size_t{count_} * record_size_;
  if (input_packed_) {
    std::memcpy(dst, SpillCodec::PackedBytes(&r), record_size_);
    *stored = MakeSortRecord(r.key, DecodePointRecord(dst, channels_, grid_));
  } else {
    EncodePointRecord(r.position, r.normal, r.radius, r.radiance, channels_, grid_, dst);
    *stored =
        input_quantized_ ? r : MakeSortRecord(r.key, DecodePointRecord(dst, channels_, grid_));
  }
  ++points_;
  if (++count_ == per_page_) return Flush();
  return absl::OkStatus();
}

absl::Status PointPageWriter::AddPacked(const SortRecord& r) {
  // Copies of a constant size (two moves, not a call).
  uint8_t* dst = buf_.data() + size_t{count_} * record_size_;
  if (record_size_ == kPointRecordRadianceBytes) {
    std::memcpy(dst, SpillCodec::PackedBytes(&r), kPointRecordRadianceBytes);
  } else if (record_size_ == kPointRecordBothSidesBytes) {
    std::memcpy(dst, SpillCodec::PackedBytes(&r), kPointRecordBothSidesBytes);
  } else {
    std::memcpy(dst, SpillCodec::PackedBytes(&r), kPointRecordOcclusionBytes);
  }
  ++points_;
  if (++count_ == per_page_) return Flush();
  return absl::OkStatus();
}

absl::Status PointPageWriter::Flush() {
  if (count_ == 0) return absl::OkStatus();
  absl::Status s =
      sink_->Append(Section::kPoints, next_page_, PageKind::kPoint, count_,
                    absl::Span<const uint8_t>(buf_.data(), size_t{count_} * record_size_));
  ++next_page_;
  count_ = 0;
  return s;
}

namespace {

// Two doubles, one SSE2 register (GCC / Clang vector extensions, as raster/simd.h). Each lane
// is summed in the same order as the scalar loop it replaces, so the sums are bit-identical.
typedef double V2d __attribute__((vector_size(16)));

inline V2d Load2(const double* p) {
  V2d v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void Store2(double* p, V2d v) { std::memcpy(p, &v, sizeof v); }

// sum[k] += c[k] * l for k < 9.
inline void AddScaled9(const double* c, double l, double* sum) {
  const V2d ll = {l, l};
  for (int k = 0; k < 8; k += 2) Store2(sum + k, Load2(sum + k) + Load2(c + k) * ll);
  sum[8] += c[8] * l;
}

// sum[k] += c[k] for k < 9.
inline void Add9(const double* c, double* sum) {
  for (int k = 0; k < 8; k += 2) Store2(sum + k, Load2(sum + k) + Load2(c + k));
  sum[8] += c[8];
}

}  // namespace

void NodeAggregate::AddPoint(const SortRecord& r, bool radiance) {
  bounds.Extend(glm::vec3(r.position[0], r.position[1], r.position[2]));
  const double radius = RadiusValue(r.radius);
  const double a = sh::kPi * radius * radius;
  area += a;
  auto c = sh::ProjectClampedCosine<double>(r.normal[0], r.normal[1], r.normal[2], a);
  if (!RadiusTwoSided(r.radius)) {
    Add9(c.data(), sh_area.data());
    if (radiance) {
      for (int ch = 0; ch < 3; ++ch) AddScaled9(c.data(), r.radiance[ch], sh_power[ch].data());
      const double l = (double{r.radiance[0]} + r.radiance[1] + r.radiance[2]) / 3.0;
      lum_min = std::min(lum_min, l);
      lum_max = std::max(lum_max, l);
    }
    return;
  }
  // A two-sided surfel is the pair (n, -n): A |n.w|, band 1 cancels and the even bands double.
  // Its power is the front's radiance times n's lobe plus the back's times -n's: the even bands
  // take the sum of the radiances, band 1 their difference (sh::ProjectTwoSided).
  float front[3], back[3];
  RecordRadiances(r.radius, r.radiance, front, back);
  std::array<double, 9> area2;
  for (int k = 0; k < 9; ++k) area2[k] = (k >= 1 && k <= 3) ? 0.0 : 2.0 * c[k];
  Add9(area2.data(), sh_area.data());
  if (radiance) {
    for (int ch = 0; ch < 3; ++ch) {
      std::array<double, 9> p;
      sh::ProjectTwoSided(c.data(), double{front[ch]}, double{back[ch]}, p.data());
      Add9(p.data(), sh_power[ch].data());
    }
    // Its luminance for the contrast is that of its mean radiance, band 0 of its power over
    // band 0 of its area, (front + back) / 2, as a node's is: how its sides differ is in band
    // 1, which the cluster model shows (counted here, it refined every node of a lit sheet).
    const double l =
        ((double{front[0]} + front[1] + front[2]) + (double{back[0]} + back[1] + back[2])) / 6.0;
    lum_min = std::min(lum_min, l);
    lum_max = std::max(lum_max, l);
  }
}

double NodeAggregate::Luminance() const {
  if (!(sh_area[0] > 0.0)) return 0.0;
  return (sh_power[0][0] + sh_power[1][0] + sh_power[2][0]) / (3.0 * sh_area[0]);
}

namespace {
// |l - mean| / mean, the contrast's term for one part (tree/format.h, ContrastCode): 0 when
// both are 0, large when only the mean is.
double RelativeStray(double l, double mean) {
  const double d = std::fabs(l - mean);
  if (!(d > 0.0)) return 0.0;
  return mean > 0.0 ? d / mean : 1e30;
}
}  // namespace

void NodeAggregate::Add(const NodeAggregate& o) {
  bounds.Extend(o.bounds);
  area += o.area;
  Add9(o.sh_area.data(), sh_area.data());
  for (int ch = 0; ch < 3; ++ch) Add9(o.sh_power[ch].data(), sh_power[ch].data());
}

OctreeBuilder::OctreeBuilder(uint32_t leaf_size, Channels channels, PointPageWriter* points,
                             NodePacker* packer)
    : leaf_size_(std::max<uint32_t>(leaf_size, 1)),
      channels_(channels),
      points_(points),
      packer_(packer),
      window_(leaf_size_ + 1),
      window_rank_(leaf_size_ + 1) {
  stack_.reserve(kMaxSplitDepth + 1);
}

absl::Status OctreeBuilder::Add(const SortRecord& r) { return Push(r, nullptr); }

absl::Status OctreeBuilder::Add(const SortRecord& r, const SortRecord& stored) {
  return Push(r, &stored);
}

absl::Status OctreeBuilder::Push(const SortRecord& r, const SortRecord* stored) {
  if (any_ && r.key < last_key_) {
    return absl::InternalError(absl::StrFormat("octree pass: point %d arrived out of Morton order",
                                               next_point_ + window_size_));
  }
  const uint32_t rank = any_ && r.key == last_key_ ? std::min(last_rank_ + 1, kMaxRank) : 0;
  any_ = true;
  last_key_ = r.key;
  last_rank_ = rank;
  const size_t cap = window_.size();
  const size_t at = (window_head_ + window_size_) % cap;
  window_[at] = r;
  window_rank_[at] = rank;
  if (stored != nullptr) {
    if (window_stored_.empty()) window_stored_.resize(cap);
    window_stored_[at] = *stored;
  }
  if (++window_size_ == cap) {
    // The oldest point is i, the newest i + leaf_size.
    PBGI_RETURN_IF_ERROR(Process(window_[window_head_],
                                 stored != nullptr ? &window_stored_[window_head_] : nullptr,
                                 window_rank_[window_head_], true, r.key, rank));
    window_head_ = (window_head_ + 1) % cap;
    --window_size_;
  }
  return absl::OkStatus();
}

PendingNode OctreeBuilder::MakeRecord(const OpenNode& n, bool leaf) const {
  PendingNode p;
  NodeRecordCommon& c = p.rec.common;
  for (int k = 0; k < 3; ++k) {
    c.lo[k] = n.agg.bounds.lo[k];
    c.hi[k] = n.agg.bounds.hi[k];
  }
  c.flags = leaf ? kNodeFlagLeaf : 0;
  c.child_count = 0;
  c.children = kNoNodeRef;
  c.first_point = n.first_point;
  c.point_count = n.count;
  c.area = static_cast<float>(n.agg.area);
  c.depth = n.depth;
  for (int k = 0; k < 9; ++k) c.sh_area[k] = static_cast<float>(n.agg.sh_area[k]);
  c.pad = 0;
  p.rec.contrast = 0.0f;
  if (HasRadiance(channels_)) {
    for (int ch = 0; ch < 3; ++ch) {
      for (int k = 0; k < 9; ++k) {
        p.rec.sh_power[ch][k] = static_cast<float>(n.agg.sh_power[ch][k]);
      }
    }
    if (leaf && n.agg.lum_min <= n.agg.lum_max) {
      const double l = n.agg.Luminance();
      p.rec.contrast = static_cast<float>(std::min(
          1e30, std::max(RelativeStray(n.agg.lum_min, l), RelativeStray(n.agg.lum_max, l))));
    }
  }
  return p;
}

absl::Status OctreeBuilder::Deliver(ClosedNode closed, const NodeAggregate& agg, uint64_t count) {
  if (stack_.empty()) {
    if (have_root_) return absl::InternalError("octree pass: a second root closed");
    root_ = std::move(closed);
    have_root_ = true;
    return absl::OkStatus();
  }
  OpenNode& parent = stack_.back();
  if (parent.children.size() == 8) {
    return absl::InternalError(
        absl::StrFormat("octree pass: node at depth %d got a ninth child", parent.depth));
  }
  parent.children.push_back(std::move(closed));
  parent.agg.Add(agg);
  parent.count += count;
  return absl::OkStatus();
}

absl::Status OctreeBuilder::CloseLeaf() {
  leaf_open_ = false;
  ++stats_.nodes;
  ++stats_.leaves;
  stats_.max_depth = std::max(stats_.max_depth, leaf_.depth);
  stats_.max_leaf_points = std::max(stats_.max_leaf_points, leaf_.count);
  ClosedNode c;
  c.node = MakeRecord(leaf_, true);
  return Deliver(std::move(c), leaf_.agg, leaf_.count);
}

absl::Status OctreeBuilder::CloseTop() {
  OpenNode n = std::move(stack_.back());
  stack_.pop_back();
  ++stats_.nodes;
  ClosedNode c;
  c.node = MakeRecord(n, false);
  if (HasRadiance(channels_)) {
    // The contrast over the children's mean radiances (tree/format.h, ContrastCode).
    const double l = n.agg.Luminance();
    double stray = 0.0;
    for (const ClosedNode& child : n.children) {
      stray = std::max(stray, RelativeStray(RecordLuminance(child.node.rec), l));
    }
    c.node.rec.contrast = static_cast<float>(std::min(1e30, stray));
  }
  PBGI_RETURN_IF_ERROR(packer_->CloseInterior(absl::MakeSpan(n.children), &c));
  PBGI_RETURN_IF_ERROR(Deliver(std::move(c), n.agg, n.count));
  n.children.clear();
  spare_children_.push_back(std::move(n.children));
  return absl::OkStatus();
}

absl::Status OctreeBuilder::Process(const SortRecord& r, const SortRecord* stored, uint32_t rank,
                                    bool have_ahead, uint64_t ahead_key, uint32_t ahead_rank) {
  if (leaf_open_) {
    if (PrefixAt(r.key, rank, leaf_.depth) == leaf_.prefix) {
      ++leaf_.count;
      ++next_point_;
      return AddPoint(r, stored);
    }
    PBGI_RETURN_IF_ERROR(CloseLeaf());
  }
  while (!stack_.empty() && PrefixAt(r.key, rank, stack_.back().depth) != stack_.back().prefix) {
    PBGI_RETURN_IF_ERROR(CloseTop());
  }
  if (stack_.empty() && have_root_) {
    return absl::InternalError("octree pass: a point arrived after the root closed");
  }
  // Point r is the first point of every node below the stack top that contains it.
  for (uint32_t d = stack_.empty() ? 0 : stack_.back().depth + 1;; ++d) {
    OpenNode n;
    n.depth = d;
    n.prefix = PrefixAt(r.key, rank, d);
    n.first_point = next_point_;
    // Below depth 21 the ranks split what the keys cannot (coincident points).
    const bool interior =
        d < kMaxSplitDepth && have_ahead && PrefixAt(ahead_key, ahead_rank, d) == n.prefix;
    if (!interior) {
      leaf_ = std::move(n);
      leaf_open_ = true;
      break;
    }
    if (spare_children_.empty()) {
      n.children.reserve(8);
    } else {
      n.children = std::move(spare_children_.back());
      spare_children_.pop_back();
    }
    stack_.push_back(std::move(n));
  }
  ++leaf_.count;
  ++next_point_;
  return AddPoint(r, stored);
}

absl::Status OctreeBuilder::AddPoint(const SortRecord& r, const SortRecord* stored) {
  if (stored != nullptr) {
    PBGI_RETURN_IF_ERROR(points_->AddPacked(r));
    leaf_.agg.AddPoint(*stored, HasRadiance(channels_));
    return absl::OkStatus();
  }
  SortRecord as_stored;
  PBGI_RETURN_IF_ERROR(points_->Add(r, &as_stored));
  leaf_.agg.AddPoint(as_stored, HasRadiance(channels_));
  return absl::OkStatus();
}

absl::StatusOr<NodeRef> OctreeBuilder::Finish() {
  const size_t cap = window_.size();
  while (window_size_ > 0) {
    PBGI_RETURN_IF_ERROR(Process(window_[window_head_],
                                 window_stored_.empty() ? nullptr : &window_stored_[window_head_],
                                 window_rank_[window_head_], false, 0, 0));
    window_head_ = (window_head_ + 1) % cap;
    --window_size_;
  }
  if (leaf_open_) PBGI_RETURN_IF_ERROR(CloseLeaf());
  while (!stack_.empty()) PBGI_RETURN_IF_ERROR(CloseTop());
  if (!have_root_) return absl::InvalidArgumentError("octree pass: no points");
  const NodeRecordCommon& rc = root_.node.rec.common;
  stats_.bounds.lo = glm::vec3(rc.lo[0], rc.lo[1], rc.lo[2]);
  stats_.bounds.hi = glm::vec3(rc.hi[0], rc.hi[1], rc.hi[2]);
  PBGI_RETURN_IF_ERROR(points_->Flush());
  return packer_->Finish(std::move(root_));
}

}  // namespace pbgi::internal
