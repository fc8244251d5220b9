// The one page seam between the store and the modules above it (docs/design.md, "Seams"), narrow
// on purpose like LevelDB's Env:
//  - PageSink: where a build appends pages (a PageWriter in production: StoreWriterSink);
//  - PageSource: a finished store (OpenStorePageSource over LMDB), and PageReader, one thread's
//    read snapshot of it, which hands out PageViews.
// One in-memory implementation of both serves the tests (store/mem_page_store.h). The builder
// writes through a PageSink, the query layer and the tree checker read through a PageSource.
// Virtual calls happen only on a miss in both cache levels, never on the warm traversal path.
//
// Internal: not part of the public API.
#ifndef PBGI_STORE_PAGE_IO_H_
#define PBGI_STORE_PAGE_IO_H_

#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/store.h"

namespace pbgi::internal {

// Where a build's pages go. Pages of one section arrive with increasing page numbers. One
// thread.
class PageSink {
 public:
  virtual ~PageSink() = default;
  virtual uint32_t page_size() const = 0;
  uint32_t payload_capacity() const { return page_size() - sizeof(PageHeader); }
  virtual absl::Status Append(Section section, uint64_t page_no, PageKind kind,
                              uint32_t record_count, absl::Span<const uint8_t> payload) = 0;
};

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

// The one writer of a page image: the header (kind, format, record count, payload size, page
// number; checksum 0), the payload and zero padding up to `page_bytes` bytes at `page`.
// REQUIRES: page_bytes >= sizeof(PageHeader) + payload.size().
void FormatPage(uint8_t* page, size_t page_bytes, PageKind kind, uint32_t record_count,
                uint64_t page_no, absl::Span<const uint8_t> payload);

// A PageSink over a PageWriter (not owned).
class StoreWriterSink final : public PageSink {
 public:
  explicit StoreWriterSink(PageWriter* writer) : writer_(writer) {}
  uint32_t page_size() const override { return writer_->page_size(); }
  absl::Status Append(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                      absl::Span<const uint8_t> payload) override {
    return writer_->Append(section, page_no, kind, record_count, payload);
  }

 private:
  PageWriter* writer_;
};

// Opens an LMDB store (pbgi::PageStore) as a page source; `copy_pages` as in StoreOptions.
absl::StatusOr<std::unique_ptr<PageSource>> OpenStorePageSource(const std::string& path,
                                                                bool verify_checksums,
                                                                bool copy_pages = true);
// A page source over an open PageStore that the caller keeps alive (one ReadTxn per reader).
std::unique_ptr<PageSource> BorrowStorePageSource(const PageStore& store);

}  // namespace pbgi::internal

#endif  // PBGI_STORE_PAGE_IO_H_
