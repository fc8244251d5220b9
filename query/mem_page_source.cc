#include <chrono>
#include <cstring>
#include <thread>

#include "absl/strings/str_format.h"
#include "query/page_source.h"

namespace pbgi::internal {

class MemPageSource::Reader final : public PageReader {
 public:
  explicit Reader(const MemPageSource* src) : src_(src) {}

  absl::StatusOr<PageView> Read(Section section, uint64_t page_no) override {
    src_->reads_.fetch_add(1, std::memory_order_relaxed);
    if (int us = src_->read_delay_us_.load(std::memory_order_relaxed); us > 0) {
      std::this_thread::sleep_for(std::chrono::microseconds(us));
    }
    auto it = src_->pages_.find({static_cast<int>(section), page_no});
    if (it == src_->pages_.end()) {
      return absl::NotFoundError(
          absl::StrFormat("%s: %s page %d not found", src_->name_, SectionName(section), page_no));
    }
    const Page& page = *it->second;
    page.reads.fetch_add(1, std::memory_order_relaxed);
    if (!page.fail.ok()) return page.fail;
    PageView view;
    view.header = reinterpret_cast<const PageHeader*>(page.bytes.data());
    size_t payload =
        std::min<size_t>(view.header->payload_bytes, page.bytes.size() - sizeof(PageHeader));
    view.payload = absl::MakeConstSpan(page.bytes.data() + sizeof(PageHeader), payload);
    return view;
  }

 private:
  const MemPageSource* src_;
};

MemPageSource::MemPageSource(StoreMeta meta, std::string name)
    : meta_(std::move(meta)), name_(std::move(name)) {}

absl::StatusOr<std::unique_ptr<PageReader>> MemPageSource::NewReader() const {
  return std::unique_ptr<PageReader>(new Reader(this));
}

void MemPageSource::PutPage(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                            absl::Span<const uint8_t> payload) {
  auto page = std::make_unique<Page>();
  size_t size = std::max<size_t>(meta_.page_size, sizeof(PageHeader) + payload.size());
  page->bytes.assign(size, 0);
  PageHeader h{};
  h.kind = static_cast<uint16_t>(kind);
  h.format = kStoreFormatVersion;
  h.record_count = record_count;
  h.payload_bytes = static_cast<uint32_t>(payload.size());
  h.page_no = page_no;
  std::memcpy(page->bytes.data(), &h, sizeof(h));
  if (!payload.empty()) {
    std::memcpy(page->bytes.data() + sizeof(h), payload.data(), payload.size());
  }
  pages_[{static_cast<int>(section), page_no}] = std::move(page);
}

std::vector<uint8_t>* MemPageSource::MutablePage(Section section, uint64_t page_no) {
  auto it = pages_.find({static_cast<int>(section), page_no});
  return it == pages_.end() ? nullptr : &it->second->bytes;
}

void MemPageSource::FailPage(Section section, uint64_t page_no, absl::Status status) {
  auto it = pages_.find({static_cast<int>(section), page_no});
  if (it != pages_.end()) it->second->fail = std::move(status);
}

uint64_t MemPageSource::reads_of(Section section, uint64_t page_no) const {
  auto it = pages_.find({static_cast<int>(section), page_no});
  return it == pages_.end() ? 0 : it->second->reads.load(std::memory_order_relaxed);
}

size_t MemPageSource::page_count(Section section) const {
  size_t n = 0;
  for (const auto& [key, page] : pages_) n += key.first == static_cast<int>(section);
  return n;
}

}  // namespace pbgi::internal
