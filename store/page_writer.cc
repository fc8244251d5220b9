// PageWriter: appends fixed-size pages to a new store with MDB_APPEND | MDB_RESERVE (whole, or
// with compress_pages zstd-compressed and shorter where that pays), in batches, growing the map
// on MDB_MAP_FULL, and commits the meta record last (docs/design.md, "Store").
#include <fcntl.h>
#include <lmdb.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "store/lmdb_status.h"
#include "store/meta_codec.h"
#include "store/page_io.h"
#include "store/store_internal.h"
#include "store/write_lock.h"
// For ZSTD_c_literalCompressionMode, an experimental parameter of the stable
// ZSTD_CCtx_setParameter (the shared library takes it too).
#define ZSTD_STATIC_LINKING_ONLY
#include "zstd.h"

namespace pbgi {
namespace {

using internal::LmdbStatus;

// A write transaction's reserved pages stay at fixed addresses until it ends, as long as LMDB
// does not spill dirty pages to disk, which it starts to do near MDB_IDL_UM_MAX (2^17) dirty
// pages = 512 MiB. The map-growth retry relies on those addresses, so batches stay well below.
constexpr uint64_t kMaxBatchBytes = uint64_t{256} << 20;
constexpr uint32_t kMaxPageSize = 64u << 20;
// zstd's fastest regular level: measured on the city (docs/format.md, "Format version 3"),
// higher levels gain under 1% on these pages. Literals are stored raw, not Huffman-coded: a
// cache miss decompresses a whole page, and Huffman decoding of these high-entropy records
// was most of that (docs/format.md, "Session 10": node pages decompress 2.9x faster, points
// 1.35x, for 6 % more bytes). Any zstd decoder reads both kinds of frame.
constexpr int kZstdLevel = 1;

void RemoveFile(const std::string& p) { unlink(p.c_str()); }

}  // namespace

struct PageWriter::Impl {
  std::string path;        // the store directory
  std::string tmp_path;    // path/data.mdb.tmp, being written
  std::string final_path;  // path/data.mdb
  StoreOptions options;
  MDB_env* env = nullptr;
  MDB_txn* txn = nullptr;
  MDB_dbi meta_dbi = 0, nodes = 0, points = 0;
  uint64_t map_size = 0;
  uint32_t env_page = 4096;  // LMDB's page size (the OS page size)
  off_t written_end = 0;     // StreamOut: write-back started below this offset
  off_t dropped_end = 0;     // StreamOut: written back and dropped from the page cache below this

  // Pages reserved in the open write transaction, in append order: what a map-growth retry
  // must write again into the next transaction.
  struct Pending {
    Section section;
    uint64_t page_no;
    uint8_t* page;
    uint32_t size;  // stored bytes
  };
  std::vector<Pending> pending;
  uint64_t batch_bytes = 0;  // LMDB's bytes for the pending pages (LmdbBytes)
  uint64_t replays = 0;      // batches written again after the map grew under them

  bool has_last[2] = {false, false};
  uint64_t last[2] = {0, 0};
  uint64_t pages[2] = {0, 0};
  uint64_t bytes_written = 0;
  absl::Status failed;  // sticky: after an error the writer refuses to continue
  bool finished = false;
  std::optional<internal::WriterLock> lock;  // held from Create to destruction
  // Directories that Create made (deepest first): a writer that does not finish removes them
  // again when they are empty, so a failed build leaves nothing behind.
  std::vector<std::string> created_dirs;
  // compress_pages: zstd's context and the compressed payload of the page being appended.
  ZSTD_CCtx* zstd = nullptr;
  std::vector<uint8_t> compressed;

  static int Index(Section s) { return s == Section::kNodes ? 0 : 1; }
  MDB_dbi Dbi(Section s) const { return s == Section::kNodes ? nodes : points; }
  std::string Where() const { return absl::StrCat("store ", path, " (writing ", tmp_path, ")"); }

  ~Impl() {
    ZSTD_freeCCtx(zstd);
    if (txn != nullptr) mdb_txn_abort(txn);
    if (env != nullptr) mdb_env_close(env);
    // Only the lock's holder may touch the files: without it they belong to another writer.
    if (!finished && lock.has_value()) {
      RemoveFile(tmp_path);
      RemoveFile(tmp_path + internal::kLockSuffix);
    }
    if (lock.has_value()) lock->Release();
    if (!finished) {
      for (const std::string& d : created_dirs) {
        if (rmdir(d.c_str()) != 0) break;  // not empty (or gone): leave it and its parents
      }
    }
  }

  absl::Status Fail(absl::Status s) {
    if (txn != nullptr) {
      mdb_txn_abort(txn);
      txn = nullptr;
    }
    pending.clear();
    batch_bytes = 0;
    failed = s;
    return s;
  }

  int Begin() { return mdb_txn_begin(env, nullptr, 0, &txn); }

  // What LMDB allocates for a value of `size` bytes: without MDB_WRITEMAP every dirty page of a
  // write transaction is a malloc'd copy until the commit, and a page value takes whole overflow
  // pages (a 16-byte page header, then the value). The batch is counted in these bytes, so that
  // StoreOptions::batch_bytes bounds the memory the open transaction holds.
  uint64_t LmdbBytes(uint32_t size) const {
    return (uint64_t{size} + 16 + env_page - 1) / env_page * env_page;
  }

  // The most map pages one batch can add: its values' overflow pages (the batch commits once
  // they reach batch_bytes, so at most one page value more), a leaf entry per value and the
  // branch and freelist pages, counted generously.
  uint64_t BatchPagesBound() const {
    const uint64_t overflow = (options.batch_bytes + LmdbBytes(options.page_size)) / env_page + 1;
    return 2 * overflow + 64;
  }

  // Between transactions: grows the map (doubling, up to max_map_size) until a whole batch fits
  // after the last page, so that a batch never meets MDB_MAP_FULL and is never written twice.
  // A replay (GrowAndReplay) holds the batch's pages twice, once in its saved copy and once in
  // the new transaction's dirty pages, which took the build's peak RSS over --memory whenever
  // the map grew mid-batch (docs/design.md, "Memory plan").
  absl::Status GrowAhead() {
    MDB_envinfo info;
    PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_info(env, &info), Where()));
    const uint64_t need = (uint64_t{info.me_last_pgno} + 1 + BatchPagesBound()) * env_page;
    uint64_t next = map_size;
    while (next < need && next < options.max_map_size) {
      next = std::min(options.max_map_size, next * 2);
    }
    if (next == map_size) return absl::OkStatus();
    PBGI_RETURN_IF_ERROR(LmdbStatus(
        mdb_env_set_mapsize(env, next),
        absl::StrFormat("%s: growing the map from %d to %d bytes", Where(), map_size, next)));
    map_size = next;
    return absl::OkStatus();
  }

  int Reserve(Section section, uint64_t page_no, uint32_t size, uint8_t** out) {
    uint8_t key_bytes[8];
    internal::EncodeKey(page_no, key_bytes);
    MDB_val key{sizeof(key_bytes), key_bytes};
    MDB_val val{size, nullptr};
    const int rc = mdb_put(txn, Dbi(section), &key, &val, MDB_APPEND | MDB_RESERVE);
    *out = static_cast<uint8_t*>(val.mv_data);
    return rc;
  }

  // MDB_MAP_FULL inside the open transaction: LMDB has poisoned it. Save the batch's pages,
  // abort, double the map (up to max_map_size) and write the batch again, as often as needed.
  absl::Status GrowAndReplay() {
    if (!pending.empty()) ++replays;
    std::vector<size_t> at(pending.size() + 1, 0);
    for (size_t i = 0; i < pending.size(); ++i) at[i + 1] = at[i] + pending[i].size;
    std::vector<uint8_t> saved(at.back());
    for (size_t i = 0; i < pending.size(); ++i) {
      std::memcpy(saved.data() + at[i], pending[i].page, pending[i].size);
    }
    for (;;) {
      if (txn != nullptr) {
        mdb_txn_abort(txn);
        txn = nullptr;
      }
      if (map_size >= options.max_map_size) {
        return absl::ResourceExhaustedError(
            absl::StrFormat("%s: map full at %d bytes after %d pages: the store needs more than "
                            "StoreOptions::max_map_size (%d bytes)",
                            Where(), map_size, pages[0] + pages[1], options.max_map_size));
      }
      const uint64_t next = std::min(options.max_map_size, map_size * 2);
      PBGI_RETURN_IF_ERROR(LmdbStatus(
          mdb_env_set_mapsize(env, next),
          absl::StrFormat("%s: growing the map from %d to %d bytes", Where(), map_size, next)));
      map_size = next;
      PBGI_RETURN_IF_ERROR(LmdbStatus(Begin(), Where()));
      int rc = MDB_SUCCESS;
      for (size_t i = 0; i < pending.size() && rc == MDB_SUCCESS; ++i) {
        rc = Reserve(pending[i].section, pending[i].page_no, pending[i].size, &pending[i].page);
        if (rc == MDB_SUCCESS) {
          std::memcpy(pending[i].page, saved.data() + at[i], pending[i].size);
        }
      }
      if (rc == MDB_MAP_FULL) continue;
      return LmdbStatus(rc, absl::StrCat(Where(), ": rewriting a batch after growing the map"));
    }
  }

  // LMDB aborts a transaction whose commit fails, so a commit must not run out of map: when the
  // batch's pages (overflow runs, leaf entries, freelist) might not fit, grow first.
  absl::Status CommitBatch() {
    if (txn == nullptr) return absl::OkStatus();
    MDB_envinfo info;
    PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_info(env, &info), Where()));
    const uint64_t run = (uint64_t{options.page_size} + 16 + env_page - 1) / env_page;
    const uint64_t estimate =
        info.me_last_pgno + 1 + pending.size() * run + pending.size() / 64 + 64;
    if (estimate * env_page > map_size) PBGI_RETURN_IF_ERROR(GrowAndReplay());
    const int rc = mdb_txn_commit(txn);
    txn = nullptr;
    pending.clear();
    batch_bytes = 0;
    PBGI_RETURN_IF_ERROR(internal::LmdbWriteStatus(
        rc, absl::StrCat(Where(), ": committing a batch of pages"), tmp_path));
    ReleaseCommittedPages();
    return absl::OkStatus();
  }

  // After a batch commits, its pages are clean and the build will not read them again: release
  // them from the map (TrimMap) and from the page cache (StreamOut). Best effort: a failure here
  // changes nothing, Finish() still syncs everything.
  void ReleaseCommittedPages() {
    int fd = -1;
    if (mdb_env_get_fd(env, &fd) != MDB_SUCCESS || fd < 0) return;
    struct stat st;
    if (fstat(fd, &st) != 0) return;
    TrimMap(st);
    StreamOut(fd, st.st_size);
  }

  // The pages of data.mdb that LMDB reads through its map while appending (the B-tree's right
  // edge, and the neighbours that the kernel maps around each fault) count in the process's
  // RSS, and over a long build they add up to tens of MiB beyond the write batch. They are clean
  // (committed) file pages: dropping them from this process's map costs a re-fault of the few
  // that the next batch touches, and keeps the build's peak RSS within --memory. Nothing is
  // trimmed if /proc is not there.
  void TrimMap(const struct stat& file) {
    absl::StatusOr<internal::FileMapping> m = internal::FindFileMapping(file, nullptr, tmp_path);
    if (!m.ok()) return;
    (void)madvise(const_cast<uint8_t*>(m->start), m->bytes, MADV_DONTNEED);
  }

  // A build writes each page once and does not read it back, so its file should not fill the
  // page cache (which a memory cgroup charges to the build) or pile up as dirty memory that the
  // kernel then throttles. Start the write-back of what the batch appended, wait for the
  // previous batch's write-back (long done, as a rule) and drop those pages from the cache.
  // LMDB's meta pages and the B-tree's few branch pages are rewritten in place and re-read from
  // disk when needed.
  void StreamOut(int fd, off_t end) {
    if (end > written_end) {
      (void)sync_file_range(fd, written_end, end - written_end, SYNC_FILE_RANGE_WRITE);
    }
    if (written_end > dropped_end) {
      (void)sync_file_range(
          fd, dropped_end, written_end - dropped_end,
          SYNC_FILE_RANGE_WAIT_BEFORE | SYNC_FILE_RANGE_WRITE | SYNC_FILE_RANGE_WAIT_AFTER);
      (void)posix_fadvise(fd, dropped_end, written_end - dropped_end, POSIX_FADV_DONTNEED);
      dropped_end = written_end;
    }
    written_end = std::max(written_end, end);
  }

  absl::Status PutMeta(const std::string& record) {
    for (;;) {
      PBGI_RETURN_IF_ERROR(LmdbStatus(Begin(), Where()));
      MDB_val key{sizeof(internal::kMetaKey) - 1, const_cast<char*>(internal::kMetaKey)};
      MDB_val val{record.size(), const_cast<char*>(record.data())};
      int rc = mdb_put(txn, meta_dbi, &key, &val, 0);
      if (rc == MDB_SUCCESS) {
        rc = mdb_txn_commit(txn);
        txn = nullptr;
        if (rc != MDB_MAP_FULL) {
          return internal::LmdbWriteStatus(rc, absl::StrCat(Where(), ": meta record"), tmp_path);
        }
      }
      if (rc != MDB_MAP_FULL) {
        return internal::LmdbWriteStatus(rc, absl::StrCat(Where(), ": meta record"), tmp_path);
      }
      PBGI_RETURN_IF_ERROR(GrowAndReplay());  // nothing pending: grows the map only
      mdb_txn_abort(txn);
      txn = nullptr;
    }
  }
};

PageWriter::PageWriter(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
PageWriter::~PageWriter() = default;
uint32_t PageWriter::page_size() const { return impl_->options.page_size; }
uint64_t PageWriter::bytes_written() const { return impl_->bytes_written; }
uint64_t PageWriter::batch_replays() const { return impl_->replays; }

absl::StatusOr<std::unique_ptr<PageWriter>> PageWriter::Create(const std::string& path,
                                                               const StoreOptions& options) {
  if (options.page_size <= sizeof(PageHeader) || options.page_size > kMaxPageSize) {
    return absl::InvalidArgumentError(
        absl::StrFormat("store %s: page size %d must be more than %d and at most %d bytes", path,
                        options.page_size, sizeof(PageHeader), kMaxPageSize));
  }
  if (options.page_size % alignof(PageHeader) != 0) {
    // LMDB keeps values of a few KiB inside its own pages, 2-byte aligned unless every entry's
    // size is a multiple of 8; page views hand out a PageHeader*, which needs 8.
    return absl::InvalidArgumentError(
        absl::StrFormat("store %s: page size %d is not a multiple of %d (use EfficientPageSize(k))",
                        path, options.page_size, alignof(PageHeader)));
  }
  if (options.initial_map_size < (uint64_t{1} << 16) ||
      options.max_map_size < options.initial_map_size) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "store %s: map sizes must satisfy 64 KiB <= initial_map_size (%d) <= max_map_size (%d)",
        path, options.initial_map_size, options.max_map_size));
  }
  auto impl = std::make_unique<Impl>();
  impl->path = path;
  impl->tmp_path = absl::StrCat(path, "/", internal::kBuildingFile);
  impl->final_path = absl::StrCat(path, "/", internal::kDataFile);
  std::error_code ec;
  // The directories that do not exist yet, deepest first.
  for (std::filesystem::path p = std::filesystem::absolute(path, ec).lexically_normal();
       !ec && !p.empty() && p != p.root_path(); p = p.parent_path()) {
    if (p.filename().empty()) continue;  // a trailing separator
    if (std::filesystem::exists(p, ec) || ec) break;
    impl->created_dirs.push_back(p.string());
  }
  ec.clear();
  std::filesystem::create_directories(path, ec);
  if (ec || !std::filesystem::is_directory(path, ec)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("store %s: cannot create the store directory: %s", path,
                        ec ? ec.message() : std::string("a file of that name exists")));
  }
  // One writer per directory: a second one would delete the first one's file and the first
  // would then publish the second's half-written one.
  PBGI_ASSIGN_OR_RETURN(internal::WriterLock lock, internal::WriterLock::Acquire(path));
  impl->lock.emplace(std::move(lock));
  impl->options = options;
  impl->options.batch_bytes =
      std::clamp<uint64_t>(options.batch_bytes, options.page_size, kMaxBatchBytes);
  impl->map_size = options.initial_map_size;
  // A leftover from a build that died (the lock says no build is running).
  RemoveFile(impl->tmp_path);
  RemoveFile(impl->tmp_path + internal::kLockSuffix);

  const std::string where = impl->Where();
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_create(&impl->env), where));
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_set_maxdbs(impl->env, 4), where));
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_set_mapsize(impl->env, impl->map_size), where));
  // MDB_NOSYNC: batches are not synced one by one; Finish() syncs before and after the meta
  // record, which is what makes the store durable and visible.
  PBGI_RETURN_IF_ERROR(
      LmdbStatus(mdb_env_open(impl->env, impl->tmp_path.c_str(), MDB_NOSUBDIR | MDB_NOSYNC, 0644),
                 absl::StrCat(where, ": creating the file")));
  MDB_stat est;
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_stat(impl->env, &est), where));
  impl->env_page = est.ms_psize;

  PBGI_RETURN_IF_ERROR(LmdbStatus(impl->Begin(), where));
  int rc = mdb_dbi_open(impl->txn, internal::kMetaDb, MDB_CREATE, &impl->meta_dbi);
  if (rc == MDB_SUCCESS) rc = mdb_dbi_open(impl->txn, internal::kNodesDb, MDB_CREATE, &impl->nodes);
  if (rc == MDB_SUCCESS) {
    rc = mdb_dbi_open(impl->txn, internal::kPointsDb, MDB_CREATE, &impl->points);
  }
  if (rc == MDB_SUCCESS) {
    // An incomplete meta record first: should this file ever be taken for a store before
    // Finish(), Open() refuses it as incomplete.
    StoreMeta stub;
    stub.page_size = options.page_size;
    const std::string record = internal::EncodeMeta(stub, /*complete=*/false);
    MDB_val key{sizeof(internal::kMetaKey) - 1, const_cast<char*>(internal::kMetaKey)};
    MDB_val val{record.size(), const_cast<char*>(record.data())};
    rc = mdb_put(impl->txn, impl->meta_dbi, &key, &val, 0);
  }
  if (rc == MDB_SUCCESS) {
    rc = mdb_txn_commit(impl->txn);
    impl->txn = nullptr;
  }
  PBGI_RETURN_IF_ERROR(LmdbStatus(rc, absl::StrCat(where, ": creating the sections")));
  return std::unique_ptr<PageWriter>(new PageWriter(std::move(impl)));
}

absl::Status PageWriter::Append(Section section, uint64_t page_no, PageKind kind,
                                uint32_t record_count, absl::Span<const uint8_t> payload) {
  Impl& w = *impl_;
  if (!w.failed.ok()) return w.failed;
  if (w.finished) {
    return absl::FailedPreconditionError(absl::StrFormat("%s: Append after Finish", w.Where()));
  }
  const int si = Impl::Index(section);
  if (payload.size() > payload_capacity()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: %s page %d: payload of %d bytes exceeds the capacity of %d bytes", w.Where(),
        SectionName(section), page_no, payload.size(), payload_capacity()));
  }
  if (kind != internal::KindOf(section)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: %s page %d: page kind %d does not belong in this section", w.Where(),
                        SectionName(section), page_no, static_cast<int>(kind)));
  }
  if (w.has_last[si] && page_no <= w.last[si]) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: %s page %d appended after page %d: pages must come in increasing order", w.Where(),
        SectionName(section), page_no, w.last[si]));
  }
  if (w.txn == nullptr) {
    absl::Status grown = w.GrowAhead();
    if (!grown.ok()) return w.Fail(grown);
    const int rc = w.Begin();
    if (rc != MDB_SUCCESS) return w.Fail(LmdbStatus(rc, w.Where()));
  }
  // Compressed where that saves at least an eighth of the page. A compressed value is at least
  // one LMDB overflow page long (kMinCompressedPage), so LMDB never stores it inside a leaf
  // page, where it would be only 2-byte aligned.
  uint32_t size = w.options.page_size;
  uint32_t compressed = 0;
  if (w.options.compress_pages && !payload.empty()) {
    if (w.zstd == nullptr) {
      w.zstd = ZSTD_createCCtx();
      w.compressed.resize(ZSTD_compressBound(payload_capacity()));
      if (w.zstd != nullptr &&
          (ZSTD_isError(ZSTD_CCtx_setParameter(w.zstd, ZSTD_c_compressionLevel, kZstdLevel)) ||
           ZSTD_isError(
               ZSTD_CCtx_setParameter(w.zstd, ZSTD_c_literalCompressionMode, ZSTD_ps_disable)))) {
        return w.Fail(absl::InternalError("zstd refuses the page writer's parameters"));
      }
    }
    const size_t n = w.zstd == nullptr
                         ? 0
                         : ZSTD_compress2(w.zstd, w.compressed.data(), w.compressed.size(),
                                          payload.data(), payload.size());
    const uint64_t stored = std::max<uint64_t>(internal::kMinCompressedPage,
                                               (sizeof(PageHeader) + uint64_t{n} + 7) / 8 * 8);
    if (!ZSTD_isError(n) && n > 0 && stored <= w.options.page_size - w.options.page_size / 8) {
      size = static_cast<uint32_t>(stored);
      compressed = static_cast<uint32_t>(n);
    }
  }
  uint8_t* page = nullptr;
  int rc = w.Reserve(section, page_no, size, &page);
  while (rc == MDB_MAP_FULL) {
    absl::Status grown = w.GrowAndReplay();
    if (!grown.ok()) return w.Fail(grown);
    rc = w.Reserve(section, page_no, size, &page);
  }
  if (rc != MDB_SUCCESS) {
    return w.Fail(LmdbStatus(
        rc, absl::StrFormat("%s: appending %s page %d", w.Where(), SectionName(section), page_no)));
  }
  // Header, payload and zero padding go straight into the map's reserved space; the checksum
  // covers all of it after the checksum field.
  if (compressed == 0) {
    internal::FormatPage(page, size, kind, record_count, page_no, payload);
  } else {
    internal::FormatPage(page, size, kind, record_count, page_no,
                         absl::MakeConstSpan(w.compressed.data(), compressed));
    PageHeader h;
    std::memcpy(&h, page, sizeof(h));
    h.payload_bytes = static_cast<uint32_t>(payload.size());
    h.stored_payload_bytes = compressed;
    h.codec = kPageCodecZstd;
    std::memcpy(page, &h, sizeof(h));
  }
  const uint32_t crc = internal::PageChecksum(page, size);
  std::memcpy(page, &crc, sizeof(crc));

  w.pending.push_back({section, page_no, page, size});
  w.has_last[si] = true;
  w.last[si] = page_no;
  ++w.pages[si];
  w.bytes_written += size;
  w.batch_bytes += w.LmdbBytes(size);
  if (w.batch_bytes >= w.options.batch_bytes) {
    absl::Status s = w.CommitBatch();
    if (!s.ok()) return w.Fail(s);
  }
  return absl::OkStatus();
}

absl::Status PageWriter::Finish(const StoreMeta& meta) {
  Impl& w = *impl_;
  if (!w.failed.ok()) return w.failed;
  if (w.finished) return absl::FailedPreconditionError(absl::StrCat(w.Where(), ": Finish twice"));
  auto mismatch = [&](const char* field, uint64_t given, uint64_t actual) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the meta record says %s = %d but the writer wrote %d", w.Where(),
                        field, given, actual));
  };
  StoreMeta m = meta;
  if (m.magic != kStoreMagic) {
    return absl::InvalidArgumentError(absl::StrCat(w.Where(), ": meta record has a wrong magic"));
  }
  m.version = kStoreFormatVersion;
  if (m.node_pages != 0 && m.node_pages != w.pages[0]) {
    return mismatch("node_pages", m.node_pages, w.pages[0]);
  }
  if (m.point_pages != 0 && m.point_pages != w.pages[1]) {
    return mismatch("point_pages", m.point_pages, w.pages[1]);
  }
  m.page_size = w.options.page_size;
  m.node_pages = w.pages[0];
  m.point_pages = w.pages[1];

  absl::Status s = w.CommitBatch();
  // The pages must be on disk before the record that makes them visible.
  const bool sync = w.options.sync;
  if (s.ok() && sync) {
    s = internal::LmdbWriteStatus(mdb_env_sync(w.env, 1),
                                  absl::StrCat(w.Where(), ": syncing pages"), w.tmp_path);
  }
  if (s.ok()) s = w.PutMeta(internal::EncodeMeta(m, /*complete=*/true));
  if (s.ok() && sync) {
    s = internal::LmdbWriteStatus(mdb_env_sync(w.env, 1), absl::StrCat(w.Where(), ": syncing meta"),
                                  w.tmp_path);
  }
  if (!s.ok()) return w.Fail(s);
  mdb_env_close(w.env);
  w.env = nullptr;
  if (rename(w.tmp_path.c_str(), w.final_path.c_str()) != 0) {
    return w.Fail(LmdbStatus(errno, absl::StrFormat("%s: renaming %s to %s", w.Where(),
                                                    internal::kBuildingFile, internal::kDataFile)));
  }
  w.finished = true;
  RemoveFile(w.tmp_path + internal::kLockSuffix);
  // Make the rename itself durable. The new store is in place whatever happens here; a failure
  // is still an error, because the rename may not survive a power cut.
  if (sync) {
    const int dir = open(w.path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    const int rc = dir < 0 || fsync(dir) != 0 ? errno : 0;
    if (dir >= 0) close(dir);
    if (rc != 0) {
      return LmdbStatus(rc, absl::StrFormat("%s: the new store is in place, but syncing its "
                                            "directory failed, so the replacement may not "
                                            "survive a power cut",
                                            w.Where()));
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi
