// The narrow seam through which the query layer reads pages (STYLE.md, "Ownership and
// interfaces"): a PageSource is a finished store, a PageReader is one thread's read snapshot of
// it. Two implementations: LMDB (lmdb_page_source.cc, through pbgi::PageStore) and an in-memory
// fake (MemPageSource, LevelDB memenv style) that unit tests fill with hand-made pages.
//
// Virtual calls happen only on a miss in both cache levels, never on the warm traversal path.
#ifndef PBGI_QUERY_PAGE_SOURCE_H_
#define PBGI_QUERY_PAGE_SOURCE_H_

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

namespace pbgi::internal {

// One thread's reads. Not thread-safe.
class PageReader {
 public:
  virtual ~PageReader() = default;
  // The page's bytes, valid until the next Read() on this reader or its destruction.
  // NotFound if absent; DataLoss naming the page if it is damaged.
  virtual absl::StatusOr<PageView> Read(Section section, uint64_t page_no) = 0;
};

// A finished store. Thread-safe.
class PageSource {
 public:
  virtual ~PageSource() = default;
  virtual const StoreMeta& meta() const = 0;
  // What error messages call the store (its path).
  virtual const std::string& name() const = 0;
  virtual absl::StatusOr<std::unique_ptr<PageReader>> NewReader() const = 0;
  // Bytes of the store on disk (0 when not a file).
  virtual uint64_t FileBytes() const { return 0; }
  // Resident bytes of the store's memory map in this process (0 when there is none).
  virtual absl::StatusOr<uint64_t> MapResidentBytes() const { return 0; }
};

// Opens an LMDB store (pbgi::PageStore) as a page source; `copy_pages` as in StoreOptions.
absl::StatusOr<std::unique_ptr<PageSource>> OpenLmdbPageSource(const std::string& path,
                                                               bool verify_checksums,
                                                               bool copy_pages = true);

// An in-memory store for tests. Fill it (PutPage) before any reader reads; after that it is safe
// to read from many threads. Faults can be injected per page (FailPage, MutablePage) and every
// read is counted.
class MemPageSource final : public PageSource {
 public:
  MemPageSource(StoreMeta meta, std::string name);

  const StoreMeta& meta() const override { return meta_; }
  StoreMeta& mutable_meta() { return meta_; }
  const std::string& name() const override { return name_; }
  absl::StatusOr<std::unique_ptr<PageReader>> NewReader() const override;

  // Stores a page: a PageHeader (kind, number, count, payload size; checksum 0) and `payload`,
  // zero-padded to the meta's page size.
  void PutPage(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
               absl::Span<const uint8_t> payload);
  // The whole stored page (header included), to corrupt it; nullptr if absent.
  std::vector<uint8_t>* MutablePage(Section section, uint64_t page_no);
  // From now on, reading this page returns `status`.
  void FailPage(Section section, uint64_t page_no, absl::Status status);
  // Every read sleeps this long first (to widen races in single-flight tests).
  void set_read_delay_us(int us) { read_delay_us_ = us; }

  uint64_t reads() const { return reads_.load(std::memory_order_relaxed); }
  uint64_t reads_of(Section section, uint64_t page_no) const;
  size_t page_count(Section section) const;

 private:
  class Reader;
  using Key = std::pair<int, uint64_t>;
  struct Page {
    std::vector<uint8_t> bytes;
    absl::Status fail;
    mutable std::atomic<uint64_t> reads{0};
  };

  StoreMeta meta_;
  std::string name_;
  std::map<Key, std::unique_ptr<Page>> pages_;
  mutable std::atomic<uint64_t> reads_{0};
  std::atomic<int> read_delay_us_{0};
};

}  // namespace pbgi::internal

#endif  // PBGI_QUERY_PAGE_SOURCE_H_
