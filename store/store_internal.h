// Shared by the store's .cc files: file names, key encoding, the per-page check and the
// PageStore's private state. Internal.
#ifndef PBGI_STORE_STORE_INTERNAL_H_
#define PBGI_STORE_STORE_INTERNAL_H_

#include <lmdb.h>
#include <sys/stat.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "base/proc.h"
#include "pbgi/store.h"
#include "store/lmdb_check.h"

namespace pbgi::internal {

// A store directory holds data.mdb (LMDB, opened with MDB_NOSUBDIR) once it is complete. The
// writer builds data.mdb.tmp (and its lock file data.mdb.tmp-lock) and renames it at the end.
inline constexpr char kDataFile[] = "data.mdb";
inline constexpr char kBuildingFile[] = "data.mdb.tmp";
inline constexpr char kLockSuffix[] = "-lock";

inline constexpr char kMetaDb[] = "meta";
inline constexpr char kNodesDb[] = "nodes";
inline constexpr char kPointsDb[] = "points";
inline constexpr char kMetaKey[] = "meta";

// Keys are 8-byte big-endian page numbers: LMDB's default memcmp order is then page order, which
// MDB_APPEND requires.
inline void EncodeKey(uint64_t page_no, uint8_t out[8]) {
  for (int i = 7; i >= 0; --i) {
    out[i] = static_cast<uint8_t>(page_no);
    page_no >>= 8;
  }
}
inline uint64_t DecodeKey(const uint8_t in[8]) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | in[i];
  return v;
}

inline PageKind KindOf(Section s) {
  return s == Section::kNodes ? PageKind::kNode : PageKind::kPoint;
}

// A compressed page (PageHeader::codec kPageCodecZstd) is stored in at least this many bytes,
// one LMDB overflow page, so that LMDB never keeps it inside a leaf page (2-byte aligned).
inline constexpr uint32_t kMinCompressedPage = 4096 - 16;

// Checks one stored page. The structural checks (size, kind, number, payload size, codec)
// always run; the checksum only when `verify_checksum`. DataLoss names the store, the section
// and the page. A stored page is page_size bytes, or (compressed) from kMinCompressedPage to
// page_size bytes holding the header and stored_payload_bytes of zstd frame.
absl::Status CheckPage(const std::string& path, Section section, uint64_t page_no, const void* data,
                       size_t size, uint32_t page_size, bool verify_checksum);

// Decompresses the payload of a checked, compressed page `stored` into `out` (capacity
// page_size bytes, 8-byte aligned): the header (codec cleared) and payload_bytes of payload.
// `dctx` is the caller's zstd context (created when null). DataLoss naming the page when the
// payload does not decompress to exactly payload_bytes.
absl::Status DecompressPage(const std::string& path, Section section, uint64_t page_no,
                            const uint8_t* stored, uint8_t* out, void** dctx);
void FreeDecompressContext(void* dctx);

// pread()s exactly `size` bytes at `offset` (retrying short reads); errors name `file`.
absl::Status ReadFully(int fd, void* out, size_t size, uint64_t offset, const std::string& file);

// CRC-32C of a page as stored in its header: bytes [4, stored size).
uint32_t PageChecksum(const void* page, uint32_t page_size);

// What identifies the contents of a file cheaply: which file, its size and its last change.
// A finished store never changes; a reader compares this with the file now (fstat) to catch a
// store written in place under it before its map faults.
struct FileIdentity {
  uint64_t dev = 0, ino = 0, size = 0;
  int64_t mtime_ns = 0;
  static FileIdentity Of(const struct stat& st) {
    return {static_cast<uint64_t>(st.st_dev), static_cast<uint64_t>(st.st_ino),
            static_cast<uint64_t>(st.st_size),
            int64_t{st.st_mtim.tv_sec} * 1000000000 + st.st_mtim.tv_nsec};
  }
  bool operator==(const FileIdentity& o) const {
    return dev == o.dev && ino == o.ino && size == o.size && mtime_ns == o.mtime_ns;
  }
};

}  // namespace pbgi::internal

namespace pbgi {

struct PageStore::Impl {
  std::string path;       // the store directory
  std::string data_path;  // path/data.mdb
  StoreOptions options;
  StoreMeta meta;
  MDB_env* env = nullptr;
  MDB_dbi nodes = 0;
  MDB_dbi points = 0;
  uint64_t file_bytes = 0;
  const uint8_t* map_addr = nullptr;  // LMDB's read-only map of data.mdb
  uint64_t map_size = 0;              // its length
  // copy_pages: reads since open, for StoreOptions::trim_map_every.
  mutable std::atomic<uint64_t> copied_reads{0};
  int fd = -1;  // LMDB's descriptor of data.mdb (copy_pages reads through it)
  internal::FileIdentity identity;  // data.mdb when it was opened
  internal::LmdbFile lmdb;          // LMDB's structure as checked at open

  // DataLoss when data.mdb is no longer the file that was opened and checked.
  absl::Status CheckUnchanged() const;
  // One attempt of PageStore::Open (see page_store.cc).
  static absl::StatusOr<std::unique_ptr<Impl>> OpenOnce(const std::string& path,
                                                        const StoreOptions& options,
                                                        bool* replaced);

  MDB_dbi Dbi(Section s) const { return s == Section::kNodes ? nodes : points; }
  ~Impl() {
    if (env != nullptr) mdb_env_close(env);
  }
};

}  // namespace pbgi

#endif  // PBGI_STORE_STORE_INTERNAL_H_
