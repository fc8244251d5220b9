// pbgi::PageStore: fixed-size pages in one LMDB environment (docs/design.md, "Store").
//
// A store has three named sections: `meta` (one meta record, committed last), `nodes` and
// `points` (key: page number, value: one fixed-size page, stored whole or, with
// StoreOptions::compress_pages, compressed and shorter; readers always see it whole). A PageWriter
// appends pages in page-number order with MDB_APPEND, commits them in bounded batches, and makes
// the store visible only when Finish() commits the meta record. A PageStore opens a finished store
// read-only; many threads (MDB_NOTLS, one ReadTxn each) and many processes may read it at once.
//
// Thread safety: a PageStore is safe to share between threads. A ReadTxn and a PageWriter belong
// to one thread at a time.
//
// Caveats (read these, as you would LMDB's):
// - A PageView points into the memory map and is valid only until its ReadTxn is reset, renewed
//   or destroyed; a compressed page's (and, with copy_pages, every page's) only until the next
//   Get() on that ReadTxn. Copy what you need to keep.
// - A long-lived read transaction pins the snapshot; on an immutable store that costs nothing,
//   but keep one ReadTxn per thread and Reset() it between bursts of work.
// - The map size grows while writing (the writer doubles it when LMDB reports MDB_MAP_FULL); a
//   reader maps the file as it is. Map size is virtual address space, not resident memory.
// - Verification of page checksums is on by default; turn it off only to measure.
// - A PageStore must outlive every ReadTxn it began.
// - One PageWriter per store directory at a time, enforced: PageWriter::Create takes the
//   directory's writer lock (`writer.lock`, an open-file-description lock the kernel drops when
//   the process dies) and refuses, naming the holder's pid, while another writer has it.
//   Readers of the previous store keep reading it undisturbed while a new one is built and
//   swapped in (the file is replaced by rename), and never touch the lock.
// - Never write, truncate or copy over data.mdb in place while it is open: LMDB maps the file,
//   and a page that no longer exists faults the reading process with SIGBUS, which no library
//   can turn into an error. What can be caught is: PageStore::BeginRead() and ReadTxn::Renew()
//   compare the file's identity, size and modification time with what Open() checked and
//   return DataLoss when it changed, and with copy_pages a short read is DataLoss. Replace a
//   store only by building a new one (or by renaming a finished copy over it).
// - LMDB's own pages (meta pages, B-tree pages) are not covered by the page checksums, so
//   Open() reads and checks all of its meta, branch and leaf pages before LMDB may touch them
//   (store/lmdb_check.h): a damaged file is DataLoss naming the LMDB page, never a crash.
// - A finished store is opened without LMDB's lock file (MDB_NOLOCK): it is never written
//   again, so readers need no coordination, and read-only media work.
#ifndef PBGI_STORE_H_
#define PBGI_STORE_H_

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/surfel.h"

namespace pbgi {

inline constexpr uint64_t kStoreMagic = 0x3130424447425050ull;  // "PPBGDB01" little-endian
// Version 3: compact pages (docs/format.md, "Format version 3"): point positions and node bounds
// are cells of a grid of 2^21 per axis (StoreMeta::grid_origin, grid_step), normals octahedral,
// radius and radiance small floats, node SH fixed point scaled per node (tree/format.h). The
// records of versions 1 and 2 (plain floats) are not read: open refuses them, naming both
// versions, and says to rebuild. Version 4: a two-sided point record carries its sheet tag
// (Surfel::sheet) in the low bits of its normal (tree/format.h); a version-3 store, whose
// two-sided normals have no tag there, is refused the same way.
// Version 5: a radiance database's node record ends with its radiance contrast (one byte,
// tree/format.h), which the cut reads (Cut::radiance_contrast); a version-4 store is refused.
// Version 6: Channels::kRadianceBothSides, whose point records add a two-sided surfel's back
// radiance (tree/format.h). A version-5 store is a version-6 store without it and is read.
inline constexpr uint32_t kStoreFormatVersion = 6;
inline constexpr uint32_t kOldestReadableStoreFormatVersion = 5;

// The efficient page sizes are k*4096 - 16: LMDB stores a large value in a run of 4 KiB overflow
// pages behind a 16-byte page header.
inline constexpr uint32_t EfficientPageSize(uint32_t pages_4k) { return pages_4k * 4096u - 16u; }
inline constexpr uint32_t kDefaultPageSize = EfficientPageSize(16);  // 65520 bytes

enum class Section : uint8_t { kNodes = 1, kPoints = 2 };
const char* SectionName(Section s);

// Kind of a page, stored in its header.
enum class PageKind : uint16_t { kNode = 1, kPoint = 2 };

// Every page starts with this header. The checksum is CRC-32C of the stored bytes after the
// checksum field (bytes [4, stored size)). A page is stored either whole (page_size bytes:
// header, payload, zero padding) or, with StoreOptions::compress_pages where that pays, as the
// header and its payload compressed with zstd (docs/format.md, "Format version 3"): then
// `codec` is kPageCodecZstd and `stored_payload_bytes` the compressed size, and the stored value
// is shorter than page_size. Readers always see the page whole (ReadTxn::Get decompresses).
inline constexpr uint16_t kPageCodecNone = 0;
inline constexpr uint16_t kPageCodecZstd = 1;
struct PageHeader {
  uint32_t checksum;
  uint16_t kind;                  // PageKind
  uint16_t format;                // kStoreFormatVersion
  uint32_t record_count;          // records in this page
  uint32_t payload_bytes;         // bytes used after the header (uncompressed)
  uint64_t page_no;               // the page's own number (key), to catch misplaced pages
  uint32_t stored_payload_bytes;  // kPageCodecZstd: bytes of the compressed payload; else 0
  uint16_t codec;                 // kPageCodecNone or kPageCodecZstd
  uint16_t pad;
};
static_assert(sizeof(PageHeader) == 32);

// What the meta record holds. Written last, by PageWriter::Finish().
struct StoreMeta {
  uint64_t magic = kStoreMagic;
  uint32_t version = kStoreFormatVersion;
  uint32_t page_size = kDefaultPageSize;
  Channels channels = Channels::kRadiance;
  uint32_t sh_order = 2;
  uint32_t leaf_size = 16;
  Bounds bounds;  // of all surfel positions
  uint64_t point_count = 0;
  uint64_t node_count = 0;
  uint64_t node_pages = 0;
  uint64_t point_pages = 0;
  uint64_t root = 0;  // NodeRef of the root node (see tree/format.h)
  uint32_t max_depth = 0;
  std::string layout = "coherent";
  // Version 3: the grid that point positions and node bounds are stored in (tree/format.h):
  // cell q (0 .. 2^21 - 1) of axis a is the float grid_origin[a] + (q + 0.5f) * grid_step.
  glm::vec3 grid_origin{0.0f};
  float grid_step = 0.0f;
  // Free-form build statistics (name -> value as text): timings, peak memory, ...
  std::map<std::string, std::string> stats;
};

struct StoreOptions {
  uint32_t page_size = kDefaultPageSize;  // bytes per page, header included; a multiple of 8
  uint64_t initial_map_size = uint64_t{64} << 20;
  uint64_t max_map_size = uint64_t{1} << 42;  // the writer grows the map up to this
  uint64_t batch_bytes = uint64_t{64} << 20;  // commit the write transaction every this many bytes
  bool verify_checksums = true;               // readers check every page they return
  // Writer: compress each page's payload with zstd and store it shorter than page_size where
  // that saves at least an eighth of the page (docs/format.md, "Format version 3"). Readers
  // decompress such pages whatever this says. pbgi::BuildDatabase turns it on.
  bool compress_pages = false;
  // Writer: Finish() flushes the pages to disk before and after the meta record (fsync), so a
  // finished store survives a power cut. Off for scratch stores and benchmarks: the store is
  // still complete-or-refused after a process crash, only not after a system crash.
  bool sync = true;
  // Readers: let the kernel read ahead around page faults (off: MDB_NORDAHEAD). Measured on a
  // cold cache (docs/store.md): off faults a multi-KiB page in 4 KiB reads and is ~10x slower
  // even in random page order, so it is on by default; turn it off only for pages of 4 KiB
  // read at random from a store much larger than RAM.
  bool read_ahead = true;
  // Readers: ReadTxn::Get() copies each page out of the file (pread) into a buffer that the
  // ReadTxn owns, instead of returning a view into the memory map. The page bytes then live in
  // the OS page cache only (shared, reclaimable) and never become resident memory of this
  // process: a reader that keeps what it needs in its own bounded cache (pbgi::Database does)
  // stays within that bound whatever the store's size. Only LMDB's B-tree pages are touched in
  // the map (with the kernel's fault-around, up to 16 OS pages per B-tree page touched: about
  // 9% of a store with 4 KiB pages), and those are dropped from the map again, see below.
  // Costs one copy per read.
  bool copy_pages = false;
  // Readers with copy_pages: after every `trim_map_every` reads (all ReadTxns together), the
  // whole map is madvise(MADV_DONTNEED)ed, so the B-tree pages that the reads faulted in stop
  // counting as this process's resident memory (they stay in the page cache; the next read
  // faults the hot ones back in from there). Bounds the map's resident bytes to what that many
  // reads touch, whatever the store's size. 0: never.
  uint32_t trim_map_every = 256;
};

// A zero-copy view of one page, valid until the ReadTxn that produced it is reset or destroyed.
struct PageView {
  const PageHeader* header = nullptr;
  absl::Span<const uint8_t> payload;  // header->payload_bytes bytes after the header
};

class PageStore;

// What a build that did not finish left in a store directory: its data.mdb.tmp (and LMDB's
// lock file beside it), up to a whole store's size after a kill. The next PageWriter for the
// directory removes them; `pbgi info` and `pbgi verify` mention them.
struct StoreLeftovers {
  std::vector<std::string> files;  // paths that exist
  uint64_t bytes = 0;              // their total size
  // Non-empty when a build holds the directory's writer lock now (its pid): the files are its
  // work in progress, not leftovers.
  std::string active_writer;
  bool empty() const { return files.empty() && active_writer.empty(); }
};
StoreLeftovers FindStoreLeftovers(const std::string& path);

// OK unless writing the file or directory `output` would put it inside a store directory or
// replace one (following symbolic links): a store directory belongs to its store and its
// builds, and `pbgi shade ... -o DB/data.mdb` destroyed a database. FailedPrecondition naming
// both. Every command of the pbgi tool checks its outputs with it.
absl::Status CheckOutsideStores(const std::string& output);

// What CheckAllPages() found: per-section counts, and the first inconsistency it can name.
struct StoreCheckReport {
  struct SectionCounts {
    uint64_t pages = 0;
    uint64_t records = 0;        // sum of the pages' record counts
    uint64_t payload_bytes = 0;  // sum of the pages' payload sizes
    uint64_t first_page_no = 0;  // valid when pages > 0
    uint64_t last_page_no = 0;
  };
  SectionCounts nodes;
  SectionCounts points;
  uint64_t bad_pages = 0;        // pages that failed their own check (checksum, kind, number, size)
  uint64_t lmdb_tree_pages = 0;  // LMDB's branch and leaf pages of both sections, checked again
  absl::Status first_error;      // OK when the store is consistent; else the first problem found
  bool ok() const { return first_error.ok(); }
};

// Reads every page of both sections (checksums are always verified here, whatever the store's
// options) and compares the page and record counts with the meta record; also checks LMDB's
// own structure again, with the header of every overflow run. Returns an error only
// when the check itself cannot run; inconsistencies go into the report.
absl::StatusOr<StoreCheckReport> CheckAllPages(const PageStore& store);

// One read transaction (one per thread). Move-only.
class ReadTxn {
 public:
  ReadTxn(ReadTxn&&) noexcept;
  ReadTxn& operator=(ReadTxn&&) noexcept;
  ReadTxn(const ReadTxn&) = delete;
  ReadTxn& operator=(const ReadTxn&) = delete;
  ~ReadTxn();

  // Reads one page. NotFound if absent; DataLoss naming the page if its checksum, kind or number
  // is wrong, or its compressed payload does not decompress to its size. With
  // StoreOptions::copy_pages, and for a compressed page always, the view points into this
  // ReadTxn's buffer and is valid only until the next Get() (or Reset()).
  absl::StatusOr<PageView> Get(Section section, uint64_t page_no);
  // Releases the snapshot (views become invalid) but keeps the handle for Renew().
  void Reset();
  absl::Status Renew();

 private:
  friend class PageStore;
  struct Impl;
  explicit ReadTxn(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// A finished store opened read-only. Safe to share between threads.
class PageStore {
 public:
  // Opens the store at `path` (a directory). Refuses a missing, garbage, truncated, incomplete
  // or foreign-version store with a message that names the path and what is wrong.
  static absl::StatusOr<std::unique_ptr<PageStore>> Open(const std::string& path,
                                                         const StoreOptions& options = {});
  ~PageStore();

  const StoreMeta& meta() const;
  const std::string& path() const;
  absl::StatusOr<ReadTxn> BeginRead() const;
  // Bytes of the data file on disk.
  uint64_t FileBytes() const;
  // Bytes of the store's memory map that are resident in this process now (the Rss of the
  // mapping in /proc/self/smaps): what reading through the map has cost in resident memory.
  // Unavailable (an error) where /proc is not mounted.
  absl::StatusOr<uint64_t> MapResidentBytes() const;
  const StoreOptions& options() const;

 private:
  friend absl::StatusOr<StoreCheckReport> CheckAllPages(const PageStore& store);
  friend class ReadTxn;
  struct Impl;
  explicit PageStore(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Writes a new store. One thread. Pages of each section must be appended with increasing page
// numbers. The store is invisible to Open() until Finish() succeeds; a writer that is destroyed
// or killed before Finish() never leaves a store that opens with missing pages.
//
// On disk: the writer builds `path`/data.mdb.tmp and Finish() renames it to `path`/data.mdb, so a
// build that dies (even by SIGKILL) leaves the previous complete store, if there was one, intact;
// without one, Open() reports the leftover data.mdb.tmp as an incomplete build. A writer
// destroyed without Finish() removes its data.mdb.tmp. Finish() records the writer's page size
// and the page counts that were actually written in the meta record (nonzero node_pages /
// point_pages that disagree with them are an InvalidArgument error).
//
// Errors: a map that cannot grow past StoreOptions::max_map_size, a full disk or a file size
// limit are ResourceExhausted; after any error the writer refuses further Append() calls.
class PageWriter {
 public:
  // Creates (or replaces) the store at `path`.
  static absl::StatusOr<std::unique_ptr<PageWriter>> Create(const std::string& path,
                                                            const StoreOptions& options = {});
  ~PageWriter();

  uint32_t page_size() const;
  uint32_t payload_capacity() const { return page_size() - sizeof(PageHeader); }

  // Appends one page; `payload` must fit in payload_capacity(). The header (with checksum) is
  // filled in here.
  absl::Status Append(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                      absl::Span<const uint8_t> payload);
  // Commits all pages and then the meta record, in that order.
  absl::Status Finish(const StoreMeta& meta);
  // Bytes written so far (pages, headers included).
  uint64_t bytes_written() const;
  // Batches written a second time because the map had to grow inside them. The writer grows
  // the map between batches, so this stays 0 unless max_map_size stops that growth; a replay
  // holds the batch twice in memory.
  uint64_t batch_replays() const;

 private:
  struct Impl;
  explicit PageWriter(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace pbgi

#endif  // PBGI_STORE_H_
