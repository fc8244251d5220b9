// Compressed pages (StoreOptions::compress_pages, docs/format.md "Format version 3"): stored
// shorter than page_size where zstd pays, read back whole; a damaged, crafted or truncated
// compressed page is DataLoss naming the page, never a crash.
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/store.h"
#include "store/crc32c.h"
#include "tests/store/store_test_util.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;
using testing_store::PagePayload;
using testing_store::ScratchDir;

constexpr uint32_t kPageSize = EfficientPageSize(4);  // 16368 bytes

// Records of a compact page: mostly small numbers, as quantized records are.
std::vector<uint8_t> Compressible(uint64_t page_no, size_t n) {
  std::vector<uint8_t> p = PagePayload(Section::kNodes, page_no, n);
  for (size_t i = 0; i < n; ++i) {
    if (i % 16 != 0) p[i] = static_cast<uint8_t>(i % 20 < 10 ? 0 : i / 20);
  }
  return p;
}

struct Written {
  std::vector<std::vector<uint8_t>> payloads;  // page i of the points section
};

// Page i: compressible full (i % 3 == 0), incompressible full (1), compressible and short (2).
Written WriteStore(const std::string& path, int pages) {
  StoreOptions o;
  o.page_size = kPageSize;
  o.compress_pages = true;
  o.sync = false;
  auto w = PageWriter::Create(path, o);
  EXPECT_TRUE(w.ok()) << w.status();
  Written out;
  const size_t cap = (*w)->payload_capacity();
  StoreMeta meta;
  for (int i = 0; i < pages; ++i) {
    std::vector<uint8_t> p = i % 3 == 0   ? Compressible(i, cap)
                             : i % 3 == 1 ? PagePayload(Section::kPoints, i, cap)
                                          : Compressible(i, 100);
    EXPECT_TRUE((*w)->Append(Section::kPoints, i, PageKind::kPoint, 7, p).ok());
    meta.point_count += 7;
    out.payloads.push_back(std::move(p));
  }
  meta.layout = "test";
  EXPECT_TRUE((*w)->Finish(meta).ok());
  return out;
}

std::string ReadFile(const std::string& f) {
  std::ifstream in(f, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}
void WriteFile(const std::string& f, const std::string& bytes) {
  std::ofstream out(f, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Offset in data.mdb of the stored points page `page_no` (an overflow run: a 16-byte LMDB
// header, then our page at a 4 KiB boundary), or 0.
size_t FindPage(const std::string& bytes, uint64_t page_no) {
  for (size_t off = 0; off + 4096 <= bytes.size(); off += 4096) {
    PageHeader h;
    std::memcpy(&h, bytes.data() + off + 16, sizeof(h));
    if (h.kind == static_cast<uint16_t>(PageKind::kPoint) && h.format == kStoreFormatVersion &&
        h.page_no == page_no && h.record_count == 7) {
      return off + 16;
    }
  }
  return 0;
}

TEST(CompressedPageTest, RoundTripAndSmallerFile) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  const Written w = WriteStore(path, 12);
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  auto txn = (*store)->BeginRead();
  ASSERT_TRUE(txn.ok());
  for (int i = 0; i < 12; ++i) {
    auto v = txn->Get(Section::kPoints, i);
    ASSERT_TRUE(v.ok()) << v.status();
    EXPECT_EQ(v->header->page_no, uint64_t(i));
    EXPECT_EQ(v->header->record_count, 7u);
    EXPECT_EQ(v->header->codec, kPageCodecNone);  // readers always see the page whole
    ASSERT_EQ(v->payload.size(), w.payloads[i].size());
    EXPECT_TRUE(std::equal(v->payload.begin(), v->payload.end(), w.payloads[i].begin())) << i;
  }
  // Eight of the twelve pages compress: well under 12 whole pages on disk (LMDB's own pages
  // included).
  EXPECT_LT((*store)->FileBytes(), uint64_t{10} * kPageSize);
  auto report = CheckAllPages(**store);
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_TRUE(report->ok()) << report->first_error;
  EXPECT_EQ(report->points.pages, 12u);
  // The file holds page 0 compressed and page 1 whole.
  const std::string bytes = ReadFile(path + "/data.mdb");
  PageHeader h0, h1;
  std::memcpy(&h0, bytes.data() + FindPage(bytes, 0), sizeof(h0));
  std::memcpy(&h1, bytes.data() + FindPage(bytes, 1), sizeof(h1));
  EXPECT_EQ(h0.codec, kPageCodecZstd);
  EXPECT_GT(h0.stored_payload_bytes, 0u);
  EXPECT_LT(h0.stored_payload_bytes, h0.payload_bytes / 2);
  EXPECT_EQ(h1.codec, kPageCodecNone);
}

// Damage the compressed payload of page 3: a checksum mismatch; with the checksum recomputed
// (a crafted page), zstd's error; a compressed size cut short or too long, or an unknown codec
// (checksum recomputed), likewise. Each names the page.
TEST(CompressedPageTest, DamagedOrTruncatedCompressedPageIsDataLossNamingThePage) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  WriteStore(path, 6);
  const std::string file = path + "/data.mdb";
  const std::string good = ReadFile(file);
  const size_t at = FindPage(good, 3);
  ASSERT_NE(at, 0u);
  PageHeader h;
  std::memcpy(&h, good.data() + at, sizeof(h));
  ASSERT_EQ(h.codec, kPageCodecZstd);
  // The stored page's size, as the writer chose it: the header and the compressed payload,
  // rounded up to 8 bytes, at least one LMDB overflow page (4080 bytes).
  const size_t stored =
      std::max<size_t>(4080, (sizeof(PageHeader) + h.stored_payload_bytes + 7) / 8 * 8);

  auto get3 = [&](bool verify) -> absl::Status {
    StoreOptions o;
    o.verify_checksums = verify;
    auto store = PageStore::Open(path, o);
    if (!store.ok()) return store.status();
    auto txn = (*store)->BeginRead();
    if (!txn.ok()) return txn.status();
    return txn->Get(Section::kPoints, 3).status();
  };
  auto rechecksum = [&](std::string* bytes) {
    const uint32_t crc =
        internal::Crc32c(0, reinterpret_cast<const uint8_t*>(bytes->data()) + at + 4, stored - 4);
    std::memcpy(&(*bytes)[at], &crc, 4);
  };
  ASSERT_TRUE(get3(true).ok());

  std::string bad = good;
  bad[at + sizeof(PageHeader) + h.stored_payload_bytes / 2] ^= 0x5a;
  WriteFile(file, bad);
  absl::Status s = get3(true);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("points page 3"));
  EXPECT_THAT(std::string(s.message()), HasSubstr("checksum"));
  // Crafted: a damaged frame (its magic number) behind a valid checksum.
  bad = good;
  bad[at + sizeof(PageHeader)] ^= 0x5a;
  rechecksum(&bad);
  WriteFile(file, bad);
  s = get3(true);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("points page 3 is corrupt"));
  EXPECT_THAT(std::string(s.message()), HasSubstr("compressed payload"));

  // Truncated: the header claims fewer compressed bytes than the frame has.
  bad = good;
  PageHeader t = h;
  t.stored_payload_bytes = h.stored_payload_bytes / 2;
  std::memcpy(&bad[at], &t, sizeof(t));
  rechecksum(&bad);
  WriteFile(file, bad);
  s = get3(true);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("points page 3 is corrupt"));

  // A compressed size larger than what is stored.
  bad = good;
  t = h;
  t.stored_payload_bytes = static_cast<uint32_t>(stored);
  std::memcpy(&bad[at], &t, sizeof(t));
  rechecksum(&bad);
  WriteFile(file, bad);
  s = get3(true);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("points page 3 is corrupt"));

  // An unknown codec.
  bad = good;
  t = h;
  t.codec = 9;
  std::memcpy(&bad[at], &t, sizeof(t));
  rechecksum(&bad);
  WriteFile(file, bad);
  s = get3(true);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("points page 3 is corrupt"));

  // `pbgi verify`'s pass finds the crafted page too.
  bad = good;
  bad[at + sizeof(PageHeader) + 1] ^= 0x11;
  rechecksum(&bad);
  WriteFile(file, bad);
  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  auto report = CheckAllPages(**store);
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_FALSE(report->ok());
  EXPECT_EQ(report->bad_pages, 1u);
  EXPECT_THAT(std::string(report->first_error.message()), HasSubstr("points page 3"));
}

}  // namespace
}  // namespace pbgi
