// The LMDB page source: pbgi::PageStore and one ReadTxn per PageReader. Kept in its own file so
// that code using only the in-memory fake does not pull in the store.
#include <memory>
#include <string>

#include "query/page_source.h"

namespace pbgi::internal {
namespace {

class LmdbPageReader final : public PageReader {
 public:
  explicit LmdbPageReader(ReadTxn txn) : txn_(std::move(txn)) {}
  absl::StatusOr<PageView> Read(Section section, uint64_t page_no) override {
    return txn_.Get(section, page_no);
  }

 private:
  ReadTxn txn_;
};

class LmdbPageSource final : public PageSource {
 public:
  explicit LmdbPageSource(std::unique_ptr<PageStore> store) : store_(std::move(store)) {}
  const StoreMeta& meta() const override { return store_->meta(); }
  const std::string& name() const override { return store_->path(); }
  absl::StatusOr<std::unique_ptr<PageReader>> NewReader() const override {
    absl::StatusOr<ReadTxn> txn = store_->BeginRead();
    if (!txn.ok()) return txn.status();
    return std::unique_ptr<PageReader>(new LmdbPageReader(std::move(*txn)));
  }
  uint64_t FileBytes() const override { return store_->FileBytes(); }
  absl::StatusOr<uint64_t> MapResidentBytes() const override {
    return store_->MapResidentBytes();
  }

 private:
  std::unique_ptr<PageStore> store_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PageSource>> OpenLmdbPageSource(const std::string& path,
                                                               bool verify_checksums,
                                                               bool copy_pages) {
  StoreOptions options;
  options.verify_checksums = verify_checksums;
  options.copy_pages = copy_pages;
  absl::StatusOr<std::unique_ptr<PageStore>> store = PageStore::Open(path, options);
  if (!store.ok()) return store.status();
  return std::unique_ptr<PageSource>(new LmdbPageSource(std::move(*store)));
}

}  // namespace pbgi::internal
