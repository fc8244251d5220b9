// The LMDB side of the page seam (store/page_io.h): pbgi::PageStore as a PageSource, one ReadTxn
// per PageReader; and the one page-image writer.
#include "store/page_io.h"

#include <cstring>
#include <memory>
#include <string>
#include <utility>

namespace pbgi::internal {

void FormatPage(uint8_t* page, size_t page_bytes, PageKind kind, uint32_t record_count,
                uint64_t page_no, absl::Span<const uint8_t> payload) {
  PageHeader h{};
  h.kind = static_cast<uint16_t>(kind);
  h.format = static_cast<uint16_t>(kStoreFormatVersion);
  h.record_count = record_count;
  h.payload_bytes = static_cast<uint32_t>(payload.size());
  h.page_no = page_no;
  std::memcpy(page, &h, sizeof(h));
  if (!payload.empty()) std::memcpy(page + sizeof(h), payload.data(), payload.size());
  std::memset(page + sizeof(h) + payload.size(), 0, page_bytes - sizeof(h) - payload.size());
}

namespace {

class StorePageReader final : public PageReader {
 public:
  explicit StorePageReader(ReadTxn txn) : txn_(std::move(txn)) {}
  absl::StatusOr<PageView> Read(Section section, uint64_t page_no) override {
    return txn_.Get(section, page_no);
  }

 private:
  ReadTxn txn_;
};

class StorePageSource final : public PageSource {
 public:
  StorePageSource(std::unique_ptr<PageStore> owned, const PageStore* store)
      : owned_(std::move(owned)), store_(store) {}
  const StoreMeta& meta() const override { return store_->meta(); }
  const std::string& name() const override { return store_->path(); }
  absl::StatusOr<std::unique_ptr<PageReader>> NewReader() const override {
    absl::StatusOr<ReadTxn> txn = store_->BeginRead();
    if (!txn.ok()) return txn.status();
    return std::unique_ptr<PageReader>(new StorePageReader(std::move(*txn)));
  }
  uint64_t FileBytes() const override { return store_->FileBytes(); }
  absl::StatusOr<uint64_t> MapResidentBytes() const override { return store_->MapResidentBytes(); }

 private:
  std::unique_ptr<PageStore> owned_;  // null when borrowed
  const PageStore* store_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PageSource>> OpenStorePageSource(const std::string& path,
                                                                bool verify_checksums,
                                                                bool copy_pages) {
  StoreOptions options;
  options.verify_checksums = verify_checksums;
  options.copy_pages = copy_pages;
  absl::StatusOr<std::unique_ptr<PageStore>> store = PageStore::Open(path, options);
  if (!store.ok()) return store.status();
  const PageStore* raw = store->get();
  return std::unique_ptr<PageSource>(new StorePageSource(std::move(*store), raw));
}

std::unique_ptr<PageSource> BorrowStorePageSource(const PageStore& store) {
  return std::make_unique<StorePageSource>(nullptr, &store);
}

}  // namespace pbgi::internal
