// Pages in the form traversal wants, copied out of the store's map (a PageView dies with its
// read transaction) and checked once, when they enter the cache, so the traversal can trust
// every index it follows within a page.
//
// Node pages split hot from cold: NodeHot (bounds, links, point range, area SH: what every
// visit reads) in one aligned array, the power SH (read only when a node becomes a cluster) in
// another. Point pages decode into Surfels.
#ifndef PBGI_QUERY_DECODED_PAGE_H_
#define PBGI_QUERY_DECODED_PAGE_H_

#include <array>
#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "glm/vec3.hpp"
#include "pbgi/store.h"
#include "pbgi/surfel.h"
#include "query/page_cache.h"
#include "store/page_format.h"

namespace pbgi::internal {

struct alignas(16) NodeHot {
  glm::vec3 lo;
  uint32_t child_count;  // 0 for a leaf
  glm::vec3 hi;
  uint32_t depth;
  uint64_t children;  // NodeRef of the first child (interior)
  uint64_t first_point;
  uint64_t point_count;
  float area;
  float reach;  // NodeReach(area)
  float sh_area[9];
  uint32_t pad[3];
};

// Cache key of a page: the page number and one bit for the section.
inline uint64_t PageKey(Section section, uint64_t page_no) {
  return (page_no << 1) | (section == Section::kPoints ? 1u : 0u);
}

class DecodedPage final : public CacheValue {
 public:
  Section section;
  uint64_t page_no = 0;
  uint32_t count = 0;                           // records
  std::unique_ptr<NodeHot[]> nodes;             // node pages
  std::unique_ptr<std::array<Sh9, 3>[]> power;  // node pages of radiance databases
  std::unique_ptr<Surfel[]> points;             // point pages

  uint64_t Charge() const;
};

// Checks and decodes one page. DataLoss naming `store_name`, the section and the page when the
// header or a record is inconsistent (wrong kind or number, too many records, a child link out
// of its page, a point range outside the database, a non-finite bound).
absl::StatusOr<std::unique_ptr<DecodedPage>> DecodePage(const PageView& view, Section section,
                                                        uint64_t page_no, const StoreMeta& meta,
                                                        const std::string& store_name);

}  // namespace pbgi::internal

#endif  // PBGI_QUERY_DECODED_PAGE_H_
