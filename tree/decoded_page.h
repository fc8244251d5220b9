// Pages in the form traversal wants, copied out of the store's map (a PageView dies with its
// read transaction) and checked once, when they enter the cache, so the traversal can trust
// every index it follows within a page.
//
// Node pages split hot from cold: NodeHot (bounds, links, point range, area SH: what every
// visit reads) in one aligned array, the power SH (read only when a node becomes a cluster) in
// another. Point pages decode into Surfels.
#ifndef PBGI_TREE_DECODED_PAGE_H_
#define PBGI_TREE_DECODED_PAGE_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "glm/vec3.hpp"
#include "pbgi/store.h"
#include "pbgi/surfel.h"
#include "tree/format.h"

namespace pbgi::internal {

// What every visit of a node reads, with the per-node terms of the cut precomputed at decode
// time (the traversal then evaluates exactly the bits of the plain tests of tree/cut.h, minus
// their per-node setup). 128 bytes: two cache lines, never three.
struct alignas(64) NodeHot {
  glm::vec3 lo;
  float abs_max;  // AbsMax(lo, hi): the node's part of NodeMargin
  glm::vec3 hi;
  float reach;            // NodeReach(area)
  glm::vec3 centre;       // 0.5f * (lo + hi): the solid angle is measured from here
  float area_bound;       // ProjectedAreaBound(sh_area): no direction sees more projected area
  glm::vec3 near_centre;  // NodeNearSphere(lo, hi, reach)
  float near_radius2;
  Sh9 sh_area;
  uint8_t depth;
  uint8_t child_count;  // 0 for a leaf
  // NodeIsFlat(sh_area, lo, hi) (tree/cut.h): what Cut::curved_scale and the curved-box test
  // read, once per decoded page instead of per visit.
  uint8_t flat;
  uint8_t contrast;   // radiance databases: ContrastCode of the node's contrast (tree/format.h)
  uint64_t children;  // NodeRef of the first child (interior)
  uint64_t first_point;
  uint64_t point_count;
};
static_assert(sizeof(NodeHot) == 128);
// lo and hi as one array of floats: corner coordinate `axis` of lo is word axis, of hi word
// axis + 4 (the traversal picks the far corner of a node by index, without branches).
static_assert(offsetof(NodeHot, lo) == 0 && offsetof(NodeHot, hi) == 4 * sizeof(float));
inline glm::vec3 NodeCorner(const NodeHot& node, const uint32_t (&word)[3]) {
  const float* f = reinterpret_cast<const float*>(&node);
  return {f[word[0]], f[word[1]], f[word[2]]};
}

// Cache key of a page: the page number and one bit for the section.
inline uint64_t PageKey(Section section, uint64_t page_no) {
  return (page_no << 1) | (section == Section::kPoints ? 1u : 0u);
}

struct DecodedPage {
  Section section;
  uint64_t page_no = 0;
  uint32_t count = 0;                           // records
  std::unique_ptr<NodeHot[]> nodes;             // node pages
  std::unique_ptr<float[]> areas;               // node pages: total surfel area (clusters)
  std::unique_ptr<std::array<Sh9, 3>[]> power;  // node pages of radiance databases
  std::unique_ptr<Surfel[]> points;             // point pages

  // Bytes of the decoded arrays (what a cache charges for the page, besides the page itself).
  uint64_t ArrayBytes() const;
};

// An upper bound, over all unit directions w, of ProjectedAreaToward(c, w) as computed in
// float (tree/cut.h): per SH band, |c_band| * max |Y_band(w)| (Cauchy-Schwarz; the addition
// theorem gives sum_m Y_lm(w)^2 = (2l + 1) / (4 pi)), summed in double and grown by 1e-5 to
// cover float rounding. Infinity or NaN when a coefficient is not finite (the traversal then
// evaluates the exact value). A node whose bound over its squared distance is clearly below
// max_solid_angle is a cluster whichever way it is seen, without the SH evaluation.
float ProjectedAreaBound(const float* c);

// Checks and decodes one page into `out`. DataLoss naming `store_name`, the section and the
// page when the header or a record is inconsistent (wrong kind or number, too many records, a
// child link out of its page, a point range outside the database, a non-finite bound).
absl::Status DecodePage(const PageView& view, Section section, uint64_t page_no,
                        const StoreMeta& meta, const std::string& store_name, DecodedPage* out);

}  // namespace pbgi::internal

#endif  // PBGI_TREE_DECODED_PAGE_H_
