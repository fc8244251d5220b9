#include "tree/decoded_page.h"

#include <cmath>
#include <cstring>

#include "absl/strings/str_format.h"
#include "pbgi/query.h"
#include "pbgi/sh.h"
#include "tree/cut.h"

namespace pbgi::internal {
namespace {

template <typename... Args>
absl::Status Corrupt(const std::string& store, Section section, uint64_t page_no,
                     const absl::FormatSpec<Args...>& format, const Args&... args) {
  return absl::DataLossError(absl::StrFormat("%s: %s page %d is corrupt: %s", store,
                                             SectionName(section), page_no,
                                             absl::StrFormat(format, args...)));
}

bool Finite3(const float* v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

}  // namespace

float ProjectedAreaBound(const float* c) {
  auto sq = [&](int i) { return double{c[i]} * double{c[i]}; };
  const double band0 = std::abs(double{c[0]}) * sh::kY0;
  const double band1 = std::sqrt(sq(1) + sq(2) + sq(3)) * std::sqrt(3.0 / (4.0 * sh::kPi));
  const double band2 =
      std::sqrt(sq(4) + sq(5) + sq(6) + sq(7) + sq(8)) * std::sqrt(5.0 / (4.0 * sh::kPi));
  return static_cast<float>((band0 + band1 + band2) * (1.0 + 1e-5) + 1e-30);
}

uint64_t DecodedPage::ArrayBytes() const {
  uint64_t bytes = 0;
  if (nodes) bytes += uint64_t{count} * (sizeof(NodeHot) + sizeof(float));
  if (power) bytes += uint64_t{count} * sizeof(std::array<Sh9, 3>);
  if (points) bytes += uint64_t{count} * sizeof(Surfel);
  return bytes;
}

absl::Status DecodePage(const PageView& view, Section section, uint64_t page_no,
                        const StoreMeta& meta, const std::string& store, DecodedPage* page) {
  if (view.header == nullptr) return Corrupt(store, section, page_no, "no header");
  const PageHeader& h = *view.header;
  const PageKind want = section == Section::kNodes ? PageKind::kNode : PageKind::kPoint;
  if (h.kind != static_cast<uint16_t>(want)) {
    return Corrupt(store, section, page_no, "kind %d, expected %d", h.kind, static_cast<int>(want));
  }
  if (h.page_no != page_no) {
    return Corrupt(store, section, page_no, "header says page %d", h.page_no);
  }
  page->section = section;
  page->page_no = page_no;
  page->count = h.record_count;
  const uint8_t* data = view.payload.data();
  const PositionGrid grid = PositionGrid::Of(meta);

  if (section == Section::kNodes) {
    const uint32_t rec = NodeRecordSize(meta.channels);
    if (h.record_count == 0 || uint64_t{h.record_count} * rec > view.payload.size()) {
      return Corrupt(store, section, page_no, "%d node records of %d bytes in a %d-byte payload",
                     h.record_count, rec, view.payload.size());
    }
    page->nodes.reset(new NodeHot[h.record_count]);
    page->areas.reset(new float[h.record_count]);
    if (HasRadiance(meta.channels)) page->power.reset(new std::array<Sh9, 3>[h.record_count]);
    for (uint32_t i = 0; i < h.record_count; ++i) {
      const NodeRecordRadiance full = DecodeNodeRecord(data + size_t{i} * rec, meta.channels, grid);
      const NodeRecordCommon& r = full.common;
      if (!Finite3(r.lo) || !Finite3(r.hi) || r.lo[0] > r.hi[0] || r.lo[1] > r.hi[1] ||
          r.lo[2] > r.hi[2] || !std::isfinite(r.area) || r.area < 0) {
        return Corrupt(store, section, page_no, "node %d has bad bounds or area", i);
      }
      const bool leaf = (r.flags & kNodeFlagLeaf) != 0;
      if (leaf ? r.child_count != 0 : (r.child_count < 1 || r.child_count > 8)) {
        return Corrupt(store, section, page_no, "node %d: %d children (leaf flag %d)", i,
                       r.child_count, leaf ? 1 : 0);
      }
      if (!leaf && RefSlot(r.children) + r.child_count > 0x10000u) {
        return Corrupt(store, section, page_no, "node %d: children run past a page", i);
      }
      if (r.point_count > meta.point_count || r.first_point > meta.point_count - r.point_count) {
        return Corrupt(store, section, page_no, "node %d: points [%d, +%d) outside the %d points",
                       i, r.first_point, r.point_count, meta.point_count);
      }
      if (r.depth >= static_cast<uint32_t>(kMaxTreeDepth)) {
        return Corrupt(store, section, page_no, "node %d: depth %d", i, r.depth);
      }
      NodeHot& n = page->nodes[i];
      n.lo = {r.lo[0], r.lo[1], r.lo[2]};
      n.hi = {r.hi[0], r.hi[1], r.hi[2]};
      n.abs_max = AbsMax(n.lo, n.hi);
      page->areas[i] = r.area;
      n.area_bound = ProjectedAreaBound(r.sh_area);
      n.reach = NodeReach(r.area);
      n.centre = 0.5f * (n.lo + n.hi);
      const NearSphere near = NodeNearSphere(n.lo, n.hi, n.reach);
      n.near_centre = near.centre;
      n.near_radius2 = near.radius2;
      std::memcpy(n.sh_area.data(), r.sh_area, sizeof(n.sh_area));
      n.depth = static_cast<uint8_t>(r.depth);
      n.child_count = static_cast<uint8_t>(leaf ? 0 : r.child_count);
      n.flat = NodeIsFlat(n.sh_area.data(), n.lo, n.hi) ? 1 : 0;
      n.contrast = page->power ? data[size_t{i} * rec + kNodeContrastOffset] : uint8_t{0};
      n.children = leaf ? kNoNodeRef : r.children;
      n.first_point = r.first_point;
      n.point_count = r.point_count;
      if (page->power) {
        for (int c = 0; c < 3; ++c) {
          std::memcpy(page->power[i][c].data(), full.sh_power[c], sizeof(full.sh_power[c]));
        }
      }
    }
  } else {
    const uint32_t rec = PointRecordSize(meta.channels);
    const uint64_t per_page = PointsPerPage(meta.page_size, meta.channels);
    const uint64_t first = page_no * per_page;
    const uint64_t expect =
        first >= meta.point_count ? 0 : std::min(per_page, meta.point_count - first);
    if (h.record_count != expect || uint64_t{h.record_count} * rec > view.payload.size()) {
      return Corrupt(store, section, page_no, "%d point records (expected %d) in %d bytes",
                     h.record_count, expect, view.payload.size());
    }
    page->points.reset(new Surfel[h.record_count]);
    for (uint32_t i = 0; i < h.record_count; ++i) {
      page->points[i] = DecodePoint(data, i, meta.channels, grid);
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
