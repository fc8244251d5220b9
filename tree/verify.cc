// VerifyTree: the octree's invariants, checked over any page source (tree/verify.h).
#include "tree/verify.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/types/span.h"
#include "pbgi/sh.h"
#include "pbgi/status.h"
#include "store/page_io.h"
#include "tree/format.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

// Float storage rounds each value once; sums of n floats differ from the float of the double
// sum by a few ulps of the magnitudes involved.
constexpr double kRelTol = 2e-5;
// Format version 3 stores SH in fixed point scaled by the largest coefficient of the node
// (tree/format.h): each stored coefficient is within scale / (2 * kMax) of its exact sum. The
// check allows a whole step (scale / kMax) per record involved.
constexpr double kAreaShStep = 1.0 / 32767;
constexpr double kPowerShStep = 1.0 / 127;

double MaxAbs(const float* c, int n) {
  double m = 0;
  for (int k = 0; k < n; ++k) m = std::max(m, std::abs(double{c[k]}));
  return m;
}

struct Sums {
  double area = 0, area_abs = 0;
  std::array<double, 9> sh{}, sh_abs{};
  std::array<std::array<double, 9>, 3> pw{}, pw_abs{};
  // Quantization allowance of the children's SH (their steps, summed).
  double sh_q = 0;
  std::array<double, 3> pw_q{};
};

class Verifier {
 public:
  // Node pages and point pages through readers of their own, so that a point page stays valid
  // while node pages are read (a view lives until its reader's next read).
  Verifier(const StoreMeta& meta, PageReader& nodes, PageReader& points)
      : meta_(meta),
        nodes_reader_(nodes),
        points_reader_(points),
        radiance_(HasRadiance(meta.channels)),
        record_size_(NodeRecordSize(meta.channels)),
        per_point_page_(PointsPerPage(meta.page_size, meta.channels)),
        grid_(PositionGrid::Of(meta)) {}

  absl::Status Run() {
    PBGI_RETURN_IF_ERROR(CheckPageCounts());
    NodeRecordRadiance root;
    PBGI_RETURN_IF_ERROR(ReadNode(meta_.root, &root, 1));
    // The builder records the root's bounds as the store's; a record crafted with other bounds
    // (and a valid checksum) would have `pbgi info` print a box that does not hold the points.
    for (int k = 0; k < 3; ++k) {
      if (root.common.lo[k] != meta_.bounds.lo[k] || root.common.hi[k] != meta_.bounds.hi[k]) {
        return absl::DataLossError(absl::StrFormat(
            "the meta record's bounds (%g, %g, %g) .. (%g, %g, %g) are not the root node's "
            "(%g, %g, %g) .. (%g, %g, %g)",
            meta_.bounds.lo.x, meta_.bounds.lo.y, meta_.bounds.lo.z, meta_.bounds.hi.x,
            meta_.bounds.hi.y, meta_.bounds.hi.z, root.common.lo[0], root.common.lo[1],
            root.common.lo[2], root.common.hi[0], root.common.hi[1], root.common.hi[2]));
      }
    }
    PBGI_RETURN_IF_ERROR(Visit(meta_.root, root, 0));
    if (next_point_ != meta_.point_count) {
      return absl::DataLossError(absl::StrFormat(
          "leaves cover %d points but the meta record counts %d", next_point_, meta_.point_count));
    }
    if (nodes_ != meta_.node_count) {
      return absl::DataLossError(absl::StrFormat(
          "the tree has %d nodes but the meta record counts %d", nodes_, meta_.node_count));
    }
    if (max_depth_ != meta_.max_depth) {
      return absl::DataLossError(absl::StrFormat("the tree is %d deep but the meta record says %d",
                                                 max_depth_, meta_.max_depth));
    }
    return absl::OkStatus();
  }

 private:
  absl::Status CheckPageCounts() {
    uint64_t records = 0;
    for (uint64_t p = 0; p < meta_.node_pages; ++p) {
      PBGI_ASSIGN_OR_RETURN(PageView r, nodes_reader_.Read(Section::kNodes, p));
      records += r.header->record_count;
    }
    if (records != meta_.node_count) {
      return absl::DataLossError(
          absl::StrFormat("node pages hold %d records but the meta record counts %d nodes", records,
                          meta_.node_count));
    }
    const uint64_t want_pages = (meta_.point_count + per_point_page_ - 1) / per_point_page_;
    if (want_pages != meta_.point_pages) {
      return absl::DataLossError(absl::StrFormat("%d points need %d point pages, meta says %d",
                                                 meta_.point_count, want_pages, meta_.point_pages));
    }
    for (uint64_t p = 0; p < meta_.point_pages; ++p) {
      PBGI_ASSIGN_OR_RETURN(PageView r, points_reader_.Read(Section::kPoints, p));
      const uint64_t want =
          p + 1 < meta_.point_pages ? per_point_page_ : meta_.point_count - p * per_point_page_;
      if (r.header->record_count != want) {
        return absl::DataLossError(absl::StrFormat("point page %d holds %d points, expected %d", p,
                                                   r.header->record_count, want));
      }
    }
    return absl::OkStatus();
  }

  // Reads `count` consecutive records starting at `ref` (a sibling group must share a page).
  absl::Status ReadNode(NodeRef ref, NodeRecordRadiance* out, uint32_t count) {
    PBGI_ASSIGN_OR_RETURN(PageView r, nodes_reader_.Read(Section::kNodes, RefPage(ref)));
    if (uint64_t{RefSlot(ref)} + count > r.header->record_count ||
        (uint64_t{RefSlot(ref)} + count) * record_size_ > r.payload.size()) {
      return absl::DataLossError(absl::StrFormat(
          "node page %d: records [%d, %d) requested but the page holds %d", RefPage(ref),
          RefSlot(ref), RefSlot(ref) + count, r.header->record_count));
    }
    for (uint32_t i = 0; i < count; ++i) {
      out[i] = DecodeNodeRecord(r.payload.data() + size_t{RefSlot(ref) + i} * record_size_,
                                meta_.channels, grid_);
    }
    return absl::OkStatus();
  }

  absl::StatusOr<Surfel> ReadPoint(uint64_t index) {
    const uint64_t page = index / per_point_page_;
    if (!have_point_page_ || page != point_page_no_) {
      PBGI_ASSIGN_OR_RETURN(point_page_, points_reader_.Read(Section::kPoints, page));
      point_page_no_ = page;
      have_point_page_ = true;
    }
    const uint32_t slot = static_cast<uint32_t>(index % per_point_page_);
    if (slot >= point_page_.header->record_count) {
      return absl::DataLossError(
          absl::StrFormat("point %d: slot %d missing from point page %d", index, slot, page));
    }
    return DecodePoint(point_page_.payload.data(), slot, meta_.channels, grid_);
  }

  static bool Contains(const NodeRecordCommon& n, const float lo[3], const float hi[3]) {
    for (int k = 0; k < 3; ++k) {
      if (!(lo[k] >= n.lo[k] && hi[k] <= n.hi[k])) return false;
    }
    return true;
  }

  absl::Status Compare(const char* what, NodeRef ref, const NodeRecordRadiance& n, const Sums& s) {
    auto close = [](double want, double got, double scale) {
      return std::abs(want - got) <= kRelTol * scale + 1e-30;
    };
    const NodeRecordCommon& c = n.common;
    const double sh_q = s.sh_q + kAreaShStep * MaxAbs(c.sh_area, 9);
    std::array<double, 3> pw_q;
    for (int ch = 0; ch < 3; ++ch) pw_q[ch] = s.pw_q[ch] + kPowerShStep * MaxAbs(n.sh_power[ch], 9);
    if (!close(s.area, c.area, s.area_abs + std::abs(double(c.area)))) {
      return absl::DataLossError(absl::StrFormat("node %d/%d: area %g but its %s sum to %g",
                                                 RefPage(ref), RefSlot(ref), c.area, what, s.area));
    }
    for (int k = 0; k < 9; ++k) {
      if (!(std::abs(s.sh[k] - c.sh_area[k]) <=
            kRelTol * (s.sh_abs[k] + std::abs(double(c.sh_area[k]))) + sh_q + 1e-30)) {
        return absl::DataLossError(
            absl::StrFormat("node %d/%d: area SH coefficient %d is %g but its %s sum to %g",
                            RefPage(ref), RefSlot(ref), k, c.sh_area[k], what, s.sh[k]));
      }
      if (!radiance_) continue;
      for (int ch = 0; ch < 3; ++ch) {
        if (!(std::abs(s.pw[ch][k] - n.sh_power[ch][k]) <=
              kRelTol * (s.pw_abs[ch][k] + std::abs(double(n.sh_power[ch][k]))) + pw_q[ch] +
                  1e-30)) {
          return absl::DataLossError(absl::StrFormat(
              "node %d/%d: power SH (colour %d) coefficient %d is %g but its %s sum to %g",
              RefPage(ref), RefSlot(ref), ch, k, n.sh_power[ch][k], what, s.pw[ch][k]));
        }
      }
    }
    return absl::OkStatus();
  }

  // The luminance of a node record's mean radiance (band 0 of power over band 0 of area, as the
  // builder and the cut compute it) and a bound on what the stored quantization moves it by.
  struct Lum {
    double l = 0.0, err = 0.0;
  };
  static Lum NodeLum(const NodeRecordRadiance& n) {
    const double a0 = n.common.sh_area[0];
    if (!(a0 > 0.0)) return {0.0, std::numeric_limits<double>::infinity()};
    double dp = 0.0;
    for (int ch = 0; ch < 3; ++ch) dp += kPowerShStep * MaxAbs(n.sh_power[ch], 9);
    const double l = RecordLuminance(n);
    const double da = kAreaShStep * MaxAbs(n.common.sh_area, 9) / a0;
    return {l, dp / (3.0 * a0) + std::abs(l) * 2.0 * da + 1e-6 * std::abs(l)};
  }

  // The stored contrast (tree/format.h, ContrastCode: rounded up to 1/16 octave of 1 + c) against
  // the largest stray of the node's parts' luminance from its own, within what the quantization
  // of the records allows.
  absl::Status CheckContrast(NodeRef ref, const NodeRecordRadiance& n,
                             absl::Span<const Lum> parts) {
    if (!radiance_ || parts.empty()) return absl::OkStatus();
    const Lum m = NodeLum(n);
    if (!std::isfinite(m.err)) return absl::OkStatus();
    double lo = 0.0, hi = 0.0;
    for (const Lum& q : parts) {
      const double d = std::abs(q.l - m.l), e = q.err + m.err;
      lo = std::max(lo, (d - e) / (m.l + m.err));
      hi = m.l - m.err > 0.0 ? std::max(hi, (d + e) / (m.l - m.err))
                             : std::numeric_limits<double>::infinity();
    }
    const double c = n.contrast;
    const bool low = c < lo * (1.0 - 1e-6) - 1e-6;
    const bool high =
        std::isfinite(hi) && c < 6e4 && c > (1.0 + hi) * std::exp2(1.0 / 16.0) - 1.0 + 1e-4;
    if (low || high) {
      return absl::DataLossError(absl::StrFormat(
          "node %d/%d: radiance contrast %g, but its parts' luminance strays %g to %g from its "
          "own",
          RefPage(ref), RefSlot(ref), c, lo, hi));
    }
    return absl::OkStatus();
  }

  absl::Status Visit(NodeRef ref, const NodeRecordRadiance& n, uint32_t depth) {
    const NodeRecordCommon& c = n.common;
    ++nodes_;
    if (nodes_ > meta_.node_count) {
      return absl::DataLossError(absl::StrFormat(
          "the tree has more nodes than the meta record's %d (a cycle?)", meta_.node_count));
    }
    auto where = [&]() { return absl::StrFormat("node %d/%d", RefPage(ref), RefSlot(ref)); };
    if (c.depth != depth) {
      return absl::DataLossError(
          absl::StrFormat("%s: depth %d, expected %d", where(), c.depth, depth));
    }
    max_depth_ = std::max(max_depth_, depth);
    if (c.first_point != next_point_) {
      return absl::DataLossError(
          absl::StrFormat("%s: first point %d, but depth-first order puts point %d next", where(),
                          c.first_point, next_point_));
    }
    if (c.point_count == 0) {
      return absl::DataLossError(absl::StrFormat("%s: holds no points", where()));
    }
    Sums s;
    if (c.flags & kNodeFlagLeaf) {
      if (c.child_count != 0) {
        return absl::DataLossError(absl::StrFormat("%s: a leaf with children", where()));
      }
      if (c.point_count > meta_.leaf_size && depth < kMaxSplitDepth) {
        return absl::DataLossError(
            absl::StrFormat("%s: a leaf of %d points above the maximum depth (leaf size %d)",
                            where(), c.point_count, meta_.leaf_size));
      }
      if (c.first_point + c.point_count > meta_.point_count) {
        return absl::DataLossError(absl::StrFormat("%s: points past the end", where()));
      }
      std::vector<Lum> parts;
      for (uint64_t i = c.first_point; i < c.first_point + c.point_count; ++i) {
        PBGI_ASSIGN_OR_RETURN(Surfel p, ReadPoint(i));
        if (radiance_) {
          // A two-sided surfel's mean radiance is that of its two sides, as the builder has it.
          const double front = double(p.radiance[0]) + p.radiance[1] + p.radiance[2];
          const double back = double(p.back_radiance[0]) + p.back_radiance[1] + p.back_radiance[2];
          parts.push_back({p.two_sided ? (front + back) / 6.0 : front / 3.0, 0.0});
        }
        const float pos[3] = {p.position.x, p.position.y, p.position.z};
        if (!Contains(c, pos, pos)) {
          return absl::DataLossError(
              absl::StrFormat("%s: point %d lies outside the node's bounds", where(), i));
        }
        const double a = sh::kPi * double(p.radius) * double(p.radius);
        const auto y = sh::ProjectClampedCosine<double>(p.normal.x, p.normal.y, p.normal.z, a);
        // A two-sided surfel is the pair (n, -n), its front radiance on n's lobe and its back
        // radiance on -n's, as the builder aggregates it.
        std::array<double, 9> area = y;
        std::array<std::array<double, 9>, 3> power;
        for (int ch = 0; ch < 3; ++ch) {
          if (p.two_sided) {
            sh::ProjectTwoSided(y.data(), double{p.radiance[ch]}, double{p.back_radiance[ch]},
                                power[ch].data());
          } else {
            for (int k = 0; k < 9; ++k) power[ch][k] = y[k] * p.radiance[ch];
          }
        }
        if (p.two_sided) {
          for (int k = 0; k < 9; ++k) area[k] = (k >= 1 && k <= 3) ? 0.0 : 2.0 * y[k];
        }
        s.area += a;
        s.area_abs += a;
        for (int k = 0; k < 9; ++k) {
          s.sh[k] += area[k];
          s.sh_abs[k] += std::abs(area[k]);
          for (int ch = 0; ch < 3; ++ch) {
            s.pw[ch][k] += power[ch][k];
            s.pw_abs[ch][k] += std::abs(power[ch][k]);
          }
        }
      }
      next_point_ += c.point_count;
      PBGI_RETURN_IF_ERROR(CheckContrast(ref, n, parts));
      return Compare("points", ref, n, s);
    }
    if (c.child_count < 1 || c.child_count > 8) {
      return absl::DataLossError(
          absl::StrFormat("%s: interior node with %d children", where(), c.child_count));
    }
    if (depth >= kMaxSplitDepth) {
      return absl::DataLossError(
          absl::StrFormat("%s: interior node at the maximum depth", where()));
    }
    NodeRecordRadiance kids[8];
    PBGI_RETURN_IF_ERROR(ReadNode(c.children, kids, c.child_count));
    for (uint32_t i = 0; i < c.child_count; ++i) {
      const NodeRecordCommon& k = kids[i].common;
      if (!Contains(c, k.lo, k.hi)) {
        return absl::DataLossError(
            absl::StrFormat("%s: child %d's bounds are not inside its parent's", where(), i));
      }
      PBGI_RETURN_IF_ERROR(
          Visit(MakeNodeRef(RefPage(c.children), RefSlot(c.children) + i), kids[i], depth + 1));
      s.area += k.area;
      s.area_abs += std::abs(double(k.area));
      s.sh_q += kAreaShStep * MaxAbs(k.sh_area, 9);
      for (int ch = 0; ch < 3; ++ch) s.pw_q[ch] += kPowerShStep * MaxAbs(kids[i].sh_power[ch], 9);
      for (int j = 0; j < 9; ++j) {
        s.sh[j] += k.sh_area[j];
        s.sh_abs[j] += std::abs(double(k.sh_area[j]));
        for (int ch = 0; ch < 3; ++ch) {
          s.pw[ch][j] += kids[i].sh_power[ch][j];
          s.pw_abs[ch][j] += std::abs(double(kids[i].sh_power[ch][j]));
        }
      }
    }
    if (next_point_ != c.first_point + c.point_count) {
      return absl::DataLossError(absl::StrFormat("%s: counts %d points but its children hold %d",
                                                 where(), c.point_count,
                                                 next_point_ - c.first_point));
    }
    Lum parts[8];
    for (uint32_t i = 0; i < c.child_count; ++i) parts[i] = NodeLum(kids[i]);
    PBGI_RETURN_IF_ERROR(CheckContrast(ref, n, absl::MakeConstSpan(parts, c.child_count)));
    return Compare("children", ref, n, s);
  }

  const StoreMeta& meta_;
  PageReader& nodes_reader_;
  PageReader& points_reader_;
  bool radiance_;
  uint32_t record_size_;
  uint32_t per_point_page_;
  PositionGrid grid_;
  uint64_t next_point_ = 0;
  uint64_t nodes_ = 0;
  uint32_t max_depth_ = 0;
  bool have_point_page_ = false;
  uint64_t point_page_no_ = 0;
  PageView point_page_;
};

}  // namespace

absl::Status VerifyTreePages(const StoreMeta& meta, const PageSource& pages) {
  if (meta.point_count == 0) return absl::DataLossError("the store holds no points");
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageReader> nodes, pages.NewReader());
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageReader> points, pages.NewReader());
  Verifier v(meta, *nodes, *points);
  return v.Run();
}

}  // namespace pbgi::internal
