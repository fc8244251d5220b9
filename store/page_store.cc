// PageStore (read-only opening of a finished store) and ReadTxn.
#include <fcntl.h>
#include <lmdb.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "store/crc32c.h"
#include "store/lmdb_check.h"
#include "store/lmdb_status.h"
#include "store/meta_codec.h"
#include "store/store_internal.h"
#include "store/write_lock.h"
#include "zstd.h"

namespace pbgi {

const char* SectionName(Section s) {
  switch (s) {
    case Section::kNodes:
      return "nodes";
    case Section::kPoints:
      return "points";
  }
  return "unknown";
}

namespace internal {

uint32_t PageChecksum(const void* page, uint32_t page_size) {
  return Crc32c(0, static_cast<const uint8_t*>(page) + 4, page_size - 4);
}

absl::Status CheckPage(const std::string& path, Section section, uint64_t page_no, const void* data,
                       size_t size, uint32_t page_size, bool verify_checksum) {
  auto loss = [&](const std::string& what) {
    return absl::DataLossError(absl::StrFormat("store %s: %s page %d is corrupt: %s", path,
                                               SectionName(section), page_no, what));
  };
  if (size < sizeof(PageHeader)) {
    return loss(absl::StrFormat("stored size %d bytes, shorter than a page header", size));
  }
  PageHeader h;
  std::memcpy(&h, data, sizeof(h));
  const bool compressed = h.codec == kPageCodecZstd;
  if (compressed ? (size < kMinCompressedPage || size > page_size) : size != page_size) {
    return loss(absl::StrFormat("stored size %d bytes, the store's page size is %d%s", size,
                                page_size, compressed ? " (a compressed page)" : ""));
  }
  if (reinterpret_cast<uintptr_t>(data) % alignof(PageHeader) != 0) {
    return loss("stored at a misaligned address (page size not a multiple of 8?)");
  }
  if (verify_checksum) {
    const uint32_t actual = PageChecksum(data, static_cast<uint32_t>(size));
    if (actual != h.checksum) {
      return loss(absl::StrFormat("checksum mismatch (stored 0x%08x, computed 0x%08x)", h.checksum,
                                  actual));
    }
  }
  if (h.page_no != page_no) {
    return loss(absl::StrFormat("its header says it is page %d (misplaced page)", h.page_no));
  }
  if (h.kind != static_cast<uint16_t>(KindOf(section))) {
    return loss(absl::StrFormat("page kind %d does not belong in this section", h.kind));
  }
  if (h.payload_bytes > page_size - sizeof(PageHeader)) {
    return loss(absl::StrFormat("payload of %d bytes does not fit a page of %d bytes",
                                h.payload_bytes, page_size));
  }
  if (h.codec != kPageCodecNone && h.codec != kPageCodecZstd) {
    return loss(absl::StrFormat("unknown codec %d", h.codec));
  }
  if (compressed && h.stored_payload_bytes > size - sizeof(PageHeader)) {
    return loss(absl::StrFormat("compressed payload of %d bytes in a stored page of %d bytes",
                                h.stored_payload_bytes, size));
  }
  return absl::OkStatus();
}

absl::Status DecompressPage(const std::string& path, Section section, uint64_t page_no,
                            const uint8_t* stored, uint8_t* out, void** dctx) {
  PageHeader h;
  std::memcpy(&h, stored, sizeof(h));
  if (*dctx == nullptr) *dctx = ZSTD_createDCtx();
  if (*dctx == nullptr) return absl::ResourceExhaustedError("zstd: no memory for a context");
  const size_t n =
      ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(*dctx), out + sizeof(PageHeader), h.payload_bytes,
                          stored + sizeof(PageHeader), h.stored_payload_bytes);
  if (ZSTD_isError(n) || n != h.payload_bytes) {
    return absl::DataLossError(absl::StrFormat(
        "store %s: %s page %d is corrupt: its compressed payload (%d bytes) %s", path,
        SectionName(section), page_no, h.stored_payload_bytes,
        ZSTD_isError(n) ? absl::StrCat("does not decompress: ", ZSTD_getErrorName(n))
                        : absl::StrFormat("decompresses to %d bytes, not %d", n, h.payload_bytes)));
  }
  h.codec = kPageCodecNone;
  h.stored_payload_bytes = 0;
  std::memcpy(out, &h, sizeof(h));
  return absl::OkStatus();
}

void FreeDecompressContext(void* dctx) { ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(dctx)); }

absl::Status ReadFully(int fd, void* out, size_t size, uint64_t offset, const std::string& file) {
  auto* p = static_cast<uint8_t*>(out);
  while (size > 0) {
    const ssize_t n = pread(fd, p, size, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return LmdbStatus(errno, absl::StrFormat("reading %s at offset %d", file, offset));
    if (n == 0) {
      return absl::DataLossError(absl::StrFormat(
          "reading %s at offset %d: the file ends %d bytes early", file, offset, size));
    }
    p += n, size -= static_cast<size_t>(n), offset += static_cast<uint64_t>(n);
  }
  return absl::OkStatus();
}

}  // namespace internal

// ---------------------------------------------------------------------------------------------
// ReadTxn

struct ReadTxn::Impl {
  const PageStore::Impl* store = nullptr;
  MDB_txn* txn = nullptr;
  bool active = false;
  std::unique_ptr<uint64_t[]> buffer;  // copy_pages: one page, 8-byte aligned
  std::unique_ptr<uint64_t[]> whole;   // a compressed page, decompressed
  void* dctx = nullptr;                // zstd's decompression context
  ~Impl() {
    if (txn != nullptr) mdb_txn_abort(txn);
    internal::FreeDecompressContext(dctx);
  }
};

ReadTxn::ReadTxn(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ReadTxn::ReadTxn(ReadTxn&&) noexcept = default;
ReadTxn& ReadTxn::operator=(ReadTxn&&) noexcept = default;
ReadTxn::~ReadTxn() = default;

absl::StatusOr<PageView> ReadTxn::Get(Section section, uint64_t page_no) {
  if (impl_ == nullptr || !impl_->active) {
    return absl::FailedPreconditionError(
        "ReadTxn::Get on a transaction that was reset (call Renew() first) or moved from");
  }
  const PageStore::Impl& s = *impl_->store;
  uint8_t key_bytes[8];
  internal::EncodeKey(page_no, key_bytes);
  MDB_val key{sizeof(key_bytes), key_bytes};
  MDB_val val;
  const int rc = mdb_get(impl_->txn, s.Dbi(section), &key, &val);
  if (rc != MDB_SUCCESS) {
    if (rc == MDB_NOTFOUND) {
      return absl::NotFoundError(absl::StrFormat("store %s: %s page %d does not exist", s.path,
                                                 SectionName(section), page_no));
    }
    return internal::LmdbStatus(
        rc, absl::StrFormat("store %s: reading %s page %d", s.path, SectionName(section), page_no));
  }
  const void* data = val.mv_data;
  if (s.options.copy_pages) {
    // LMDB found the value without touching it (an overflow run is located by its page number
    // alone); read it from the file rather than the map, so it never becomes resident here.
    const auto* at = static_cast<const uint8_t*>(val.mv_data);
    if (at < s.map_addr || val.mv_size > s.file_bytes ||
        static_cast<uint64_t>(at - s.map_addr) > s.file_bytes - val.mv_size) {
      return absl::DataLossError(
          absl::StrFormat("store %s: %s page %d lies outside %s (%d bytes at offset %d of %d)",
                          s.path, SectionName(section), page_no, internal::kDataFile, val.mv_size,
                          at - s.map_addr, s.file_bytes));
    }
    if (val.mv_size > s.meta.page_size || val.mv_size < sizeof(PageHeader)) {
      return absl::DataLossError(absl::StrFormat(
          "store %s: %s page %d is corrupt: stored size %d bytes, the store's page size is %d",
          s.path, SectionName(section), page_no, val.mv_size, s.meta.page_size));
    }
    if (impl_->buffer == nullptr) impl_->buffer.reset(new uint64_t[(s.meta.page_size + 7) / 8]);
    PBGI_RETURN_IF_ERROR(internal::ReadFully(s.fd, impl_->buffer.get(), val.mv_size,
                                             static_cast<uint64_t>(at - s.map_addr), s.data_path));
    data = impl_->buffer.get();
    const uint32_t every = s.options.trim_map_every;
    if (every != 0 && (s.copied_reads.fetch_add(1, std::memory_order_relaxed) + 1) % every == 0) {
      // Clean, shared file pages: dropping them from the map loses nothing, and is safe while
      // other threads read through it (they fault the pages back in from the page cache).
      madvise(const_cast<uint8_t*>(s.map_addr), s.map_size, MADV_DONTNEED);
    }
  }
  PBGI_RETURN_IF_ERROR(internal::CheckPage(s.path, section, page_no, data, val.mv_size,
                                           s.meta.page_size, s.options.verify_checksums));
  if (static_cast<const PageHeader*>(data)->codec == kPageCodecZstd) {
    if (impl_->whole == nullptr) impl_->whole.reset(new uint64_t[(s.meta.page_size + 7) / 8]);
    uint8_t* out = reinterpret_cast<uint8_t*>(impl_->whole.get());
    PBGI_RETURN_IF_ERROR(internal::DecompressPage(
        s.path, section, page_no, static_cast<const uint8_t*>(data), out, &impl_->dctx));
    data = out;
  }
  PageView v;
  v.header = static_cast<const PageHeader*>(data);
  v.payload = absl::Span<const uint8_t>(static_cast<const uint8_t*>(data) + sizeof(PageHeader),
                                        v.header->payload_bytes);
  return v;
}

void ReadTxn::Reset() {
  if (impl_ != nullptr && impl_->active) {
    mdb_txn_reset(impl_->txn);
    impl_->active = false;
  }
}

absl::Status ReadTxn::Renew() {
  if (impl_ == nullptr) return absl::FailedPreconditionError("ReadTxn::Renew on a moved-from txn");
  if (impl_->active) return absl::OkStatus();
  PBGI_RETURN_IF_ERROR(impl_->store->CheckUnchanged());
  PBGI_RETURN_IF_ERROR(internal::LmdbStatus(
      mdb_txn_renew(impl_->txn), absl::StrCat("store ", impl_->store->path, ": renewing a read")));
  impl_->active = true;
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// PageStore

PageStore::PageStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
PageStore::~PageStore() = default;
const StoreMeta& PageStore::meta() const { return impl_->meta; }
const std::string& PageStore::path() const { return impl_->path; }
uint64_t PageStore::FileBytes() const { return impl_->file_bytes; }
const StoreOptions& PageStore::options() const { return impl_->options; }
absl::StatusOr<uint64_t> PageStore::MapResidentBytes() const {
  return internal::MappingRssBytes(impl_->map_addr);
}

absl::StatusOr<ReadTxn> PageStore::BeginRead() const {
  // A file truncated under the map faults (SIGBUS) on the next read of a page past its new
  // end; catch what can be caught before a reader starts (store.h, "Caveats").
  PBGI_RETURN_IF_ERROR(impl_->CheckUnchanged());
  auto t = std::make_unique<ReadTxn::Impl>();
  t->store = impl_.get();
  PBGI_RETURN_IF_ERROR(
      internal::LmdbStatus(mdb_txn_begin(impl_->env, nullptr, MDB_RDONLY, &t->txn),
                           absl::StrCat("store ", impl_->path, ": beginning a read")));
  t->active = true;
  return ReadTxn(std::move(t));
}

// `*replaced` is set when data.mdb was swapped for another file between the structural check
// and LMDB's own open (a build finishing): the caller tries again.
absl::StatusOr<std::unique_ptr<PageStore::Impl>> PageStore::Impl::OpenOnce(
    const std::string& path, const StoreOptions& options, bool* replaced) {
  using internal::LmdbStatus;
  *replaced = false;
  struct stat st;
  if (stat(path.c_str(), &st) != 0) {
    const int err = errno;
    if (err == ENOENT) {
      return absl::NotFoundError(absl::StrFormat("store %s does not exist", path));
    }
    return LmdbStatus(err, absl::StrFormat("store %s", path));
  }
  if (!S_ISDIR(st.st_mode)) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s is not a store: a store is a directory holding %s", path, internal::kDataFile));
  }
  auto impl = std::make_unique<PageStore::Impl>();
  impl->path = path;
  impl->data_path = absl::StrCat(path, "/", internal::kDataFile);
  impl->options = options;
  const std::string& data_path = impl->data_path;
  const int check_fd = open(data_path.c_str(), O_RDONLY | O_CLOEXEC);
  if (check_fd < 0) {
    const int err = errno;
    const std::string building = absl::StrCat(path, "/", internal::kBuildingFile);
    struct stat bst;
    if (err == ENOENT && stat(building.c_str(), &bst) == 0) {
      const std::optional<std::string> writer = internal::WriterLockHolder(path);
      if (writer.has_value()) {
        return absl::FailedPreconditionError(absl::StrFormat(
            "store %s is not built yet: a build (pid %s) is writing %s now", path, *writer,
            internal::kBuildingFile));
      }
      return absl::FailedPreconditionError(absl::StrFormat(
          "store %s is incomplete: the build did not finish (only %s exists; rebuild it)", path,
          internal::kBuildingFile));
    }
    if (err == ENOENT) {
      return absl::NotFoundError(
          absl::StrFormat("%s is not a store: it has no %s", path, internal::kDataFile));
    }
    return LmdbStatus(err, absl::StrFormat("store %s: %s", path, internal::kDataFile));
  }
  struct CloseFd {
    int fd;
    ~CloseFd() { close(fd); }
  } close_check{check_fd};
  if (fstat(check_fd, &st) != 0) {
    return LmdbStatus(errno, absl::StrFormat("store %s: %s", path, internal::kDataFile));
  }
  impl->file_bytes = static_cast<uint64_t>(st.st_size);
  impl->identity = internal::FileIdentity::Of(st);
  if (impl->file_bytes == 0) {
    // LMDB would take an empty file for a new environment and try to initialize it.
    return absl::DataLossError(
        absl::StrFormat("store %s: %s is empty (0 bytes): truncated, or not an LMDB file", path,
                        internal::kDataFile));
  }
  const std::string where = absl::StrCat("store ", path);

  // LMDB trusts its own pages blindly; check them (lmdb_check.h) before LMDB sees the file.
  PBGI_ASSIGN_OR_RETURN(impl->lmdb, internal::CheckLmdbFile(check_fd, impl->file_bytes, where));
  if (!impl->lmdb.meta.present) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "store %s has no meta section: not a pbgi store, or its build did not finish", path));
  }
  if (!impl->lmdb.has_meta_record) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "store %s is incomplete: the build did not finish (no meta record)", path));
  }
  PBGI_ASSIGN_OR_RETURN(internal::DecodedMeta decoded,
                        internal::DecodeMeta(impl->lmdb.meta_record, where));
  if (!decoded.complete) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "store %s is incomplete: the build did not finish (meta record not marked complete)",
        path));
  }
  impl->meta = std::move(decoded.meta);
  if (!impl->lmdb.nodes.present || !impl->lmdb.points.present) {
    return absl::DataLossError(
        absl::StrFormat("store %s: the nodes or points section is missing", path));
  }
  for (Section section : {Section::kNodes, Section::kPoints}) {
    PBGI_RETURN_IF_ERROR(internal::CheckLmdbSection(check_fd, impl->lmdb, section,
                                                    impl->meta.page_size,
                                                    /*overflow_headers=*/false, where));
  }

  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_create(&impl->env), where));
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_set_maxdbs(impl->env, 4), where));
  // The store is immutable once finished (the writer works on a separate file and renames it),
  // so readers need no lock table: MDB_NOLOCK. MDB_NOTLS lets a thread hold several ReadTxns
  // and move them between threads.
  unsigned flags = MDB_NOSUBDIR | MDB_RDONLY | MDB_NOLOCK | MDB_NOTLS;
  if (!options.read_ahead) flags |= MDB_NORDAHEAD;
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_open(impl->env, data_path.c_str(), flags, 0644),
                                  absl::StrCat(where, ": opening ", internal::kDataFile)));
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_get_fd(impl->env, &impl->fd), where));
  // LMDB opened the path again: it must be the file that was checked.
  struct stat lst;
  if (fstat(impl->fd, &lst) != 0) return LmdbStatus(errno, where);
  if (!(internal::FileIdentity::Of(lst) == impl->identity)) {
    *replaced = true;
    return absl::UnavailableError(absl::StrFormat(
        "store %s: %s was replaced or modified while it was being opened", path,
        internal::kDataFile));
  }

  // A file cut short still has valid LMDB meta pages; reading a page past its end would fault.
  MDB_envinfo info;
  MDB_stat est;
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_info(impl->env, &info), where));
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_env_stat(impl->env, &est), where));
  const uint64_t needed = (static_cast<uint64_t>(info.me_last_pgno) + 1) * est.ms_psize;
  if (impl->file_bytes < needed) {
    return absl::DataLossError(absl::StrFormat(
        "store %s: %s is truncated: it has %d bytes but its last page ends at byte %d", path,
        internal::kDataFile, impl->file_bytes, needed));
  }

  MDB_txn* txn = nullptr;
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_txn_begin(impl->env, nullptr, MDB_RDONLY, &txn), where));
  auto abort = [&](absl::Status s) {
    mdb_txn_abort(txn);
    return s;
  };
  MDB_dbi meta_dbi;
  int rc = mdb_dbi_open(txn, internal::kMetaDb, 0, &meta_dbi);
  if (rc != MDB_SUCCESS) return abort(LmdbStatus(rc, absl::StrCat(where, ": meta section")));
  MDB_val key{sizeof(internal::kMetaKey) - 1, const_cast<char*>(internal::kMetaKey)};
  MDB_val val;
  rc = mdb_get(txn, meta_dbi, &key, &val);
  if (rc != MDB_SUCCESS) return abort(LmdbStatus(rc, absl::StrCat(where, ": meta record")));
  if (absl::string_view(static_cast<const char*>(val.mv_data), val.mv_size) !=
      impl->lmdb.meta_record) {
    // Not damage that got past the check: the file LMDB reads changed since.
    *replaced = true;
    return abort(absl::UnavailableError(
        absl::StrFormat("store %s: the meta record changed while the store was being opened",
                        path)));
  }
  rc = mdb_dbi_open(txn, internal::kNodesDb, 0, &impl->nodes);
  if (rc == MDB_SUCCESS) rc = mdb_dbi_open(txn, internal::kPointsDb, 0, &impl->points);
  if (rc != MDB_SUCCESS) return abort(LmdbStatus(rc, absl::StrCat(where, ": sections")));
  // Any value LMDB hands out points into its map; the meta record does, so it finds the map.
  // (Only the map's address is needed: copy_pages turns pointers into file offsets with it.)
  absl::StatusOr<internal::FileMapping> map = internal::FindFileMapping(lst, val.mv_data, data_path);
  if (!map.ok()) return abort(map.status());
  impl->map_addr = map->start;
  impl->map_size = map->bytes;
  // Committing (not aborting) a read transaction keeps the opened section handles.
  PBGI_RETURN_IF_ERROR(LmdbStatus(mdb_txn_commit(txn), where));
  return impl;
}

absl::StatusOr<std::unique_ptr<PageStore>> PageStore::Open(const std::string& path,
                                                           const StoreOptions& options) {
  // A build that finishes renames its file over data.mdb; the few microseconds between the
  // check and LMDB's open can see both. Each attempt either opens one file or fails for good.
  for (int attempt = 0;; ++attempt) {
    bool replaced = false;
    absl::StatusOr<std::unique_ptr<Impl>> impl = Impl::OpenOnce(path, options, &replaced);
    if (impl.ok()) return std::unique_ptr<PageStore>(new PageStore(std::move(*impl)));
    if (!replaced || attempt == 3) return impl.status();
  }
}

absl::Status PageStore::Impl::CheckUnchanged() const {
  struct stat st;
  if (fstat(fd, &st) != 0) return internal::LmdbStatus(errno, absl::StrCat("store ", path));
  const internal::FileIdentity now = internal::FileIdentity::Of(st);
  if (now == identity) return absl::OkStatus();
  return absl::DataLossError(absl::StrFormat(
      "store %s: %s was modified in place after it was opened (size %d -> %d bytes, mtime "
      "changed: %s): a finished store must never be written, only replaced by a new build; "
      "reopen it",
      path, internal::kDataFile, identity.size, now.size,
      now.mtime_ns == identity.mtime_ns ? "no" : "yes"));
}

}  // namespace pbgi
