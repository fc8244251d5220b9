// CheckAllPages: a full pass over a store (`pbgi verify`).
#include <lmdb.h>

#include <memory>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "store/lmdb_check.h"
#include "store/lmdb_status.h"
#include "store/store_internal.h"

namespace pbgi {

absl::StatusOr<StoreCheckReport> CheckAllPages(const PageStore& store) {
  const PageStore::Impl& s = *store.impl_;
  const std::string where = absl::StrCat("store ", s.path);
  StoreCheckReport report;
  auto note = [&](absl::Status st) {
    if (report.first_error.ok()) report.first_error = std::move(st);
  };

  PBGI_RETURN_IF_ERROR(s.CheckUnchanged());
  // Open() checked LMDB's tree pages; the headers of the overflow runs, which no read uses,
  // are checked here only (LMDB's pages, so no page of ours is counted bad for them).
  internal::LmdbFile lmdb = s.lmdb;
  for (Section section : {Section::kNodes, Section::kPoints}) {
    note(internal::CheckLmdbSection(s.fd, lmdb, section, s.meta.page_size,
                                    /*overflow_headers=*/true, where));
  }
  report.lmdb_tree_pages = lmdb.tree_pages_read - s.lmdb.tree_pages_read;

  MDB_txn* txn = nullptr;
  PBGI_RETURN_IF_ERROR(
      internal::LmdbStatus(mdb_txn_begin(s.env, nullptr, MDB_RDONLY, &txn), where));
  absl::Status failure;
  // Compressed pages are decompressed too: a valid checksum over a payload that does not
  // decompress (a crafted page) is as bad as a damaged one.
  std::unique_ptr<uint64_t[]> whole;
  void* dctx = nullptr;
  for (Section section : {Section::kNodes, Section::kPoints}) {
    StoreCheckReport::SectionCounts& c = section == Section::kNodes ? report.nodes : report.points;
    MDB_cursor* cursor = nullptr;
    int rc = mdb_cursor_open(txn, s.Dbi(section), &cursor);
    if (rc != MDB_SUCCESS) {
      failure = internal::LmdbStatus(rc, where);
      break;
    }
    MDB_val key, val;
    bool have_prev = false;
    uint64_t prev = 0;
    for (rc = mdb_cursor_get(cursor, &key, &val, MDB_FIRST); rc == MDB_SUCCESS;
         rc = mdb_cursor_get(cursor, &key, &val, MDB_NEXT)) {
      if (key.mv_size != 8) {
        ++report.bad_pages;
        note(absl::DataLossError(absl::StrFormat("%s: %s section holds a key of %d bytes", where,
                                                 SectionName(section), key.mv_size)));
        continue;
      }
      const uint64_t page_no = internal::DecodeKey(static_cast<const uint8_t*>(key.mv_data));
      if (c.pages == 0) c.first_page_no = page_no;
      c.last_page_no = page_no;
      ++c.pages;
      if (have_prev && page_no != prev + 1) {
        note(absl::DataLossError(absl::StrFormat("%s: %s pages %d to %d are missing", where,
                                                 SectionName(section), prev + 1, page_no - 1)));
      }
      have_prev = true;
      prev = page_no;
      absl::Status page = internal::CheckPage(s.path, section, page_no, val.mv_data, val.mv_size,
                                              s.meta.page_size, /*verify_checksum=*/true);
      if (!page.ok()) {
        ++report.bad_pages;
        note(std::move(page));
        continue;
      }
      const auto* h = static_cast<const PageHeader*>(val.mv_data);
      if (h->codec == kPageCodecZstd) {
        if (whole == nullptr) whole.reset(new uint64_t[(s.meta.page_size + 7) / 8]);
        absl::Status d = internal::DecompressPage(s.path, section, page_no,
                                                  static_cast<const uint8_t*>(val.mv_data),
                                                  reinterpret_cast<uint8_t*>(whole.get()), &dctx);
        if (!d.ok()) {
          ++report.bad_pages;
          note(std::move(d));
          continue;
        }
      }
      c.records += h->record_count;
      c.payload_bytes += h->payload_bytes;
    }
    mdb_cursor_close(cursor);
    if (rc != MDB_NOTFOUND) {
      failure = internal::LmdbStatus(
          rc, absl::StrFormat("%s: scanning the %s section", where, SectionName(section)));
      break;
    }
    if (c.pages > 0 && c.first_page_no != 0) {
      note(absl::DataLossError(absl::StrFormat("%s: %s pages 0 to %d are missing", where,
                                               SectionName(section), c.first_page_no - 1)));
    }
  }
  mdb_txn_abort(txn);
  internal::FreeDecompressContext(dctx);
  PBGI_RETURN_IF_ERROR(failure);

  const StoreMeta& m = s.meta;
  auto count = [&](const char* what, uint64_t meta_value, uint64_t found) {
    if (meta_value != found) {
      note(
          absl::DataLossError(absl::StrFormat("%s: the meta record says %s = %d but the store "
                                              "holds %d",
                                              where, what, meta_value, found)));
    }
  };
  count("node_pages", m.node_pages, report.nodes.pages);
  count("point_pages", m.point_pages, report.points.pages);
  if (report.bad_pages == 0) {
    count("node_count (node records)", m.node_count, report.nodes.records);
    count("point_count (point records)", m.point_count, report.points.records);
  }
  return report;
}

}  // namespace pbgi
