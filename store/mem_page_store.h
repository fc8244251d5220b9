// The one in-memory store for tests (LevelDB memenv style): a PageSink that a build or a test
// appends pages to, and a PageSource that Databases and the tree checker read, with the fault
// injection the tests rely on (FailPage, MutablePage, a read delay) and every read counted.
// Pages are held as full page images (FormatPage: header with checksum 0, payload, zero padding).
//
// Thread safety: append (and inject faults) before any reader reads; after that it is safe to
// read from many threads. Internal.
#ifndef PBGI_STORE_MEM_PAGE_STORE_H_
#define PBGI_STORE_MEM_PAGE_STORE_H_

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/store.h"
#include "store/page_io.h"

namespace pbgi::internal {

class MemPageStore final : public PageSink, public PageSource {
 public:
  // An empty store of `meta.page_size` pages; `name` is what error messages call it.
  MemPageStore(StoreMeta meta, std::string name);
  explicit MemPageStore(uint32_t page_size, std::string name = "memory");

  // PageSink: refuses a payload over the capacity and pages out of order, as PageWriter does.
  uint32_t page_size() const override { return meta_.page_size; }
  absl::Status Append(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                      absl::Span<const uint8_t> payload) override;

  // PageSource.
  const StoreMeta& meta() const override { return meta_; }
  StoreMeta& mutable_meta() { return meta_; }
  const std::string& name() const override { return name_; }
  absl::StatusOr<std::unique_ptr<PageReader>> NewReader() const override;

  // A view of a stored page without counting a read (for tests that inspect what was written).
  absl::StatusOr<PageView> Get(Section section, uint64_t page_no) const;
  // Page number -> whole page image (header included) of one section, copied.
  std::map<uint64_t, std::vector<uint8_t>> pages(Section section) const;
  size_t page_count(Section section) const;

  // Hand-made stores (tests/query/fake_db.h) may hold a sibling group larger than a page: from
  // now on Append() stores such a payload in a page as large as it needs.
  void AllowOversizePages() { allow_oversize_ = true; }

  // Fault injection. The whole stored page (header included), to corrupt it; nullptr if absent.
  std::vector<uint8_t>* MutablePage(Section section, uint64_t page_no);
  // From now on, reading this page returns `status`.
  void FailPage(Section section, uint64_t page_no, absl::Status status);
  // Every read sleeps this long first (to widen races in single-flight tests).
  void set_read_delay_us(int us) { read_delay_us_ = us; }

  uint64_t reads() const { return reads_.load(std::memory_order_relaxed); }
  uint64_t reads_of(Section section, uint64_t page_no) const;

 private:
  class Reader;
  using Key = std::pair<int, uint64_t>;
  struct Page {
    std::vector<uint8_t> bytes;
    absl::Status fail;
    mutable std::atomic<uint64_t> reads{0};
  };
  const Page* Find(Section section, uint64_t page_no) const;
  static PageView ViewOf(const Page& page);

  StoreMeta meta_;
  std::string name_;
  std::map<Key, std::unique_ptr<Page>> pages_;
  mutable std::atomic<uint64_t> reads_{0};
  std::atomic<int> read_delay_us_{0};
  bool allow_oversize_ = false;
};

}  // namespace pbgi::internal

#endif  // PBGI_STORE_MEM_PAGE_STORE_H_
