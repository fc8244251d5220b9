#include "build/page_sink.h"

#include <cstring>

#include "absl/strings/str_format.h"

namespace pbgi::internal {

absl::Status MemoryPageSink::Append(Section section, uint64_t page_no, PageKind kind,
                                    uint32_t record_count, absl::Span<const uint8_t> payload) {
  auto& m = section == Section::kNodes ? nodes_ : points_;
  if (payload.size() > payload_capacity()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s page %d: payload of %d bytes exceeds capacity %d",
                        SectionLabel(section), page_no, payload.size(), payload_capacity()));
  }
  if (!m.empty() && m.rbegin()->first >= page_no) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s page %d appended after page %d", SectionLabel(section), page_no, m.rbegin()->first));
  }
  std::vector<uint8_t> bytes(page_size_, 0);
  PageHeader h{};
  h.kind = static_cast<uint16_t>(kind);
  h.format = kStoreFormatVersion;
  h.record_count = record_count;
  h.payload_bytes = static_cast<uint32_t>(payload.size());
  h.page_no = page_no;
  std::memcpy(bytes.data(), &h, sizeof(h));
  if (!payload.empty()) std::memcpy(bytes.data() + sizeof(h), payload.data(), payload.size());
  m.emplace(page_no, std::move(bytes));
  return absl::OkStatus();
}

absl::StatusOr<PageRead> MemoryPageSink::Get(Section section, uint64_t page_no) {
  const auto& m = pages(section);
  auto it = m.find(page_no);
  if (it == m.end()) {
    return absl::NotFoundError(
        absl::StrFormat("%s page %d does not exist", SectionLabel(section), page_no));
  }
  PageHeader h;
  std::memcpy(&h, it->second.data(), sizeof(h));
  PageRead r;
  r.payload = absl::Span<const uint8_t>(it->second.data() + sizeof(h), h.payload_bytes);
  r.record_count = h.record_count;
  r.kind = h.kind;
  return r;
}

}  // namespace pbgi::internal
