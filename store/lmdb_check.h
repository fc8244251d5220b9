// A structural check of LMDB's own pages in a store file, run before LMDB is given the file.
// Internal.
//
// Our page checksums cover the store's pages, not LMDB's meta pages, B-tree branch and leaf
// pages, or the headers of its overflow runs, and LMDB trusts those blindly: a damaged page
// count or node offset makes it read outside a page (SIGSEGV) or fail an assertion (abort).
// So a store is opened only after these pages have been read (with pread, never through a map)
// and checked against everything LMDB's read path relies on:
//   - meta pages: LMDB's magic and version, page size, the choice of the newer meta page made
//     exactly as LMDB makes it, the last page inside the file, sane map size;
//   - every branch and leaf page of the main tree and of the meta, nodes and points trees: its
//     own page number, kind, free-space bounds, key count (branch pages at least 2, as LMDB
//     asserts), every node inside the page, key sizes, keys strictly increasing inside the
//     page and inside the range their parent gives them, every leaf at the tree's depth, child
//     page numbers inside the file, node flags, and the per-tree page and entry counts of the
//     tree's record;
//   - every overflow run inside the file; with `overflow_headers` (pbgi verify) also the
//     run's own header.
// Why a walk and not a checksum recorded at build time: a checksum of LMDB's tree cannot be
// stored inside the tree it covers, it would not say what is wrong or where, and it would
// have to be recomputed (reading every tree page) at every open anyway. The walk reads the
// tree pages only: about 1/2500 of the file at the default page size (one 4 KiB leaf page
// holds 156 entries of 64 KiB pages), docs/reliability.md has the figures.
//
// The free-page tree is not walked: read transactions never touch it.
#ifndef PBGI_STORE_LMDB_CHECK_H_
#define PBGI_STORE_LMDB_CHECK_H_

#include <cstdint>
#include <string>

#include "absl/status/statusor.h"
#include "pbgi/store.h"

namespace pbgi::internal {

// One B-tree as its record (LMDB's MDB_db) describes it.
struct LmdbTree {
  bool present = false;
  uint16_t flags = 0;
  uint16_t depth = 0;
  uint64_t branch_pages = 0;
  uint64_t leaf_pages = 0;
  uint64_t overflow_pages = 0;
  uint64_t entries = 0;
  uint64_t root = ~uint64_t{0};
};

// What CheckLmdbFile found: the meta page LMDB will use and the named trees.
struct LmdbFile {
  uint32_t psize = 0;      // LMDB's page size
  uint64_t last_pgno = 0;  // last page in use
  uint64_t txnid = 0;
  int meta_page = 0;  // 0 or 1: the one LMDB picks
  LmdbTree main;
  LmdbTree meta, nodes, points;  // the named sections ("meta", "nodes", "points")
  bool has_meta_record = false;  // the meta section holds the key "meta"
  std::string meta_record;       // its value
  uint64_t tree_pages_read = 0;  // branch and leaf pages checked so far
};

// Checks the meta pages, the main tree and the meta tree of the LMDB file open at `fd`
// (`file_bytes` long). DataLoss naming `where` (the store), LMDB's page and what is wrong;
// "not an LMDB file" when page 0 is not LMDB's; "truncated" when pages lie past the end.
absl::StatusOr<LmdbFile> CheckLmdbFile(int fd, uint64_t file_bytes, const std::string& where);

// Checks the nodes or points tree: page-number keys of 8 bytes, every value exactly
// `value_size` bytes. With `overflow_headers`, also reads the header of every overflow run.
absl::Status CheckLmdbSection(int fd, LmdbFile& file, Section section, uint32_t value_size,
                              bool overflow_headers, const std::string& where);

}  // namespace pbgi::internal

#endif  // PBGI_STORE_LMDB_CHECK_H_
