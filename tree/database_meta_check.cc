// CheckDatabaseMeta: what a meta record must say to describe a pbgi database (tree/verify.h).
#include <cmath>
#include <string>

#include "absl/strings/str_format.h"
#include "pbgi/store.h"
#include "store/meta_codec.h"
#include "tree/format.h"
#include "tree/verify.h"

namespace pbgi::internal {

absl::Status CheckDatabaseMeta(const StoreMeta& m, const std::string& name) {
  auto bad = [&](const std::string& what) {
    return absl::DataLossError(
        absl::StrFormat("%s: the meta record does not describe a pbgi database: %s", name, what));
  };
  if (m.sh_order != 2) return bad(absl::StrFormat("SH order %d (only 2 exists)", m.sh_order));
  if (m.page_size <= sizeof(PageHeader) + NodeRecordSize(m.channels) ||
      m.page_size % alignof(PageHeader) != 0) {
    return bad(absl::StrFormat("page size %d cannot hold a node record", m.page_size));
  }
  if (m.point_count == 0) return bad("it holds no points (a build never writes an empty database)");
  if (m.node_count == 0 || m.node_pages == 0) {
    return bad(absl::StrFormat("%d nodes in %d pages for %d points", m.node_count, m.node_pages,
                               m.point_count));
  }
  if (m.leaf_size == 0) return bad("leaf size 0");
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(m.bounds.lo[i]) || !std::isfinite(m.bounds.hi[i]) ||
        !(m.bounds.lo[i] <= m.bounds.hi[i])) {
      return bad(absl::StrFormat("bounds (%g, %g, %g) .. (%g, %g, %g) are empty, inverted or not "
                                 "finite",
                                 m.bounds.lo.x, m.bounds.lo.y, m.bounds.lo.z, m.bounds.hi.x,
                                 m.bounds.hi.y, m.bounds.hi.z));
    }
  }
  const uint64_t ppp = PointsPerPage(m.page_size, m.channels);
  if (m.point_pages != (m.point_count + ppp - 1) / ppp) {
    return bad(absl::StrFormat("%d points need %d point pages of %d, it says %d", m.point_count,
                               (m.point_count + ppp - 1) / ppp, ppp, m.point_pages));
  }
  if (m.node_pages > m.node_count) {
    return bad(absl::StrFormat("%d nodes cannot fill %d node pages", m.node_count, m.node_pages));
  }
  if (RefPage(m.root) >= m.node_pages) {
    return bad(absl::StrFormat("the root is in node page %d, outside the %d node pages",
                               RefPage(m.root), m.node_pages));
  }
  if (m.max_depth >= kMaxStoredDepth) {
    return bad(absl::StrFormat("depth %d (at most %d)", m.max_depth,
                               kMaxStoredDepth - 1));
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
