// Where the builder's pages go: a PageWriter (LMDB) in production, memory in unit tests. Narrow
// on purpose, like LevelDB's Env: the builder needs nothing else from the store.
#ifndef PBGI_BUILD_PAGE_SINK_H_
#define PBGI_BUILD_PAGE_SINK_H_

#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/store.h"

namespace pbgi::internal {

// Like SectionName() of store.h, but header-only so unit tests need no store library.
inline const char* SectionLabel(Section s) { return s == Section::kNodes ? "nodes" : "points"; }

class PageSink {
 public:
  virtual ~PageSink() = default;
  virtual uint32_t page_size() const = 0;
  uint32_t payload_capacity() const { return page_size() - sizeof(PageHeader); }
  // Pages of one section arrive with increasing page numbers.
  virtual absl::Status Append(Section section, uint64_t page_no, PageKind kind,
                              uint32_t record_count, absl::Span<const uint8_t> payload) = 0;
};

// Read access to pages, for VerifyTree: returns the page's payload and record count.
struct PageRead {
  absl::Span<const uint8_t> payload;
  uint32_t record_count = 0;
  uint16_t kind = 0;
};
class PageGetter {
 public:
  virtual ~PageGetter() = default;
  virtual absl::StatusOr<PageRead> Get(Section section, uint64_t page_no) = 0;
};

// Holds every page in memory (tests). Pages are stored as full page_size byte arrays with a
// header whose checksum is left zero.
class MemoryPageSink final : public PageSink, public PageGetter {
 public:
  explicit MemoryPageSink(uint32_t page_size) : page_size_(page_size) {}
  uint32_t page_size() const override { return page_size_; }
  absl::Status Append(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                      absl::Span<const uint8_t> payload) override;
  absl::StatusOr<PageRead> Get(Section section, uint64_t page_no) override;

  // section -> page number -> page bytes (header included).
  const std::map<uint64_t, std::vector<uint8_t>>& pages(Section s) const {
    return s == Section::kNodes ? nodes_ : points_;
  }

 private:
  uint32_t page_size_;
  std::map<uint64_t, std::vector<uint8_t>> nodes_, points_;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_PAGE_SINK_H_
