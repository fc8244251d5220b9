#include "store/mem_page_store.h"

#include <algorithm>
#include <chrono>
#include <thread>

#include "absl/strings/str_format.h"

namespace pbgi::internal {

class MemPageStore::Reader final : public PageReader {
 public:
  explicit Reader(const MemPageStore* store) : store_(store) {}

  absl::StatusOr<PageView> Read(Section section, uint64_t page_no) override {
    store_->reads_.fetch_add(1, std::memory_order_relaxed);
    if (int us = store_->read_delay_us_.load(std::memory_order_relaxed); us > 0) {
      std::this_thread::sleep_for(std::chrono::microseconds(us));
    }
    const Page* page = store_->Find(section, page_no);
    if (page == nullptr) {
      return absl::NotFoundError(absl::StrFormat("%s: %s page %d not found", store_->name_,
                                                 SectionName(section), page_no));
    }
    page->reads.fetch_add(1, std::memory_order_relaxed);
    if (!page->fail.ok()) return page->fail;
    return ViewOf(*page);
  }

 private:
  const MemPageStore* store_;
};

MemPageStore::MemPageStore(StoreMeta meta, std::string name)
    : meta_(std::move(meta)), name_(std::move(name)) {}

MemPageStore::MemPageStore(uint32_t page_size, std::string name) : name_(std::move(name)) {
  meta_.page_size = page_size;
}

absl::Status MemPageStore::Append(Section section, uint64_t page_no, PageKind kind,
                                  uint32_t record_count, absl::Span<const uint8_t> payload) {
  if (payload.size() > payload_capacity() && !allow_oversize_) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s page %d: payload of %d bytes exceeds capacity %d", SectionName(section),
                        page_no, payload.size(), payload_capacity()));
  }
  const int s = static_cast<int>(section);
  auto last = pages_.lower_bound({s + 1, 0});
  if (last != pages_.begin() && (--last)->first.first == s && last->first.second >= page_no) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s page %d appended after page %d", SectionName(section), page_no, last->first.second));
  }
  auto page = std::make_unique<Page>();
  page->bytes.resize(std::max<size_t>(meta_.page_size, sizeof(PageHeader) + payload.size()));
  FormatPage(page->bytes.data(), page->bytes.size(), kind, record_count, page_no, payload);
  pages_[{s, page_no}] = std::move(page);
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<PageReader>> MemPageStore::NewReader() const {
  return std::unique_ptr<PageReader>(new Reader(this));
}

const MemPageStore::Page* MemPageStore::Find(Section section, uint64_t page_no) const {
  auto it = pages_.find({static_cast<int>(section), page_no});
  return it == pages_.end() ? nullptr : it->second.get();
}

PageView MemPageStore::ViewOf(const Page& page) {
  PageView view;
  view.header = reinterpret_cast<const PageHeader*>(page.bytes.data());
  const size_t payload =
      std::min<size_t>(view.header->payload_bytes, page.bytes.size() - sizeof(PageHeader));
  view.payload = absl::MakeConstSpan(page.bytes.data() + sizeof(PageHeader), payload);
  return view;
}

absl::StatusOr<PageView> MemPageStore::Get(Section section, uint64_t page_no) const {
  const Page* page = Find(section, page_no);
  if (page == nullptr) {
    return absl::NotFoundError(
        absl::StrFormat("%s page %d does not exist", SectionName(section), page_no));
  }
  return ViewOf(*page);
}

std::map<uint64_t, std::vector<uint8_t>> MemPageStore::pages(Section section) const {
  std::map<uint64_t, std::vector<uint8_t>> out;
  for (const auto& [key, page] : pages_) {
    if (key.first == static_cast<int>(section)) out.emplace(key.second, page->bytes);
  }
  return out;
}

std::vector<uint8_t>* MemPageStore::MutablePage(Section section, uint64_t page_no) {
  auto it = pages_.find({static_cast<int>(section), page_no});
  return it == pages_.end() ? nullptr : &it->second->bytes;
}

void MemPageStore::FailPage(Section section, uint64_t page_no, absl::Status status) {
  auto it = pages_.find({static_cast<int>(section), page_no});
  if (it != pages_.end()) it->second->fail = std::move(status);
}

uint64_t MemPageStore::reads_of(Section section, uint64_t page_no) const {
  const Page* page = Find(section, page_no);
  return page == nullptr ? 0 : page->reads.load(std::memory_order_relaxed);
}

size_t MemPageStore::page_count(Section section) const {
  size_t n = 0;
  for (const auto& [key, page] : pages_) n += key.first == static_cast<int>(section);
  return n;
}

}  // namespace pbgi::internal
