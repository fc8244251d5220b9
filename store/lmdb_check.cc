// The structural check of LMDB's pages (see lmdb_check.h). The on-disk layout below is LMDB's
// (liblmdb 0.9, 64-bit, little-endian hosts), as its mdb.c defines it:
//   page header (16 bytes): u64 pgno, u16 pad, u16 flags, u16 lower, u16 upper (overflow
//     pages: u32 page count instead of lower/upper), then u16 node offsets (branch, leaf);
//   node (8 bytes + key + data): u16 lo, u16 hi, u16 flags, u16 key size. Leaf: data size
//     lo | hi << 16, the data inline or (F_BIGDATA) a u64 overflow page number. Branch: child
//     page number lo | hi << 16 | flags << 32;
//   meta page: header, then u32 magic, u32 version, u64 address, u64 map size, two tree
//     records (free pages, main; 48 bytes each: u32 pad (the free record's pad is the page
//     size), u16 flags, u16 depth, u64 branch, leaf, overflow pages, u64 entries, u64 root),
//     u64 last page, u64 txnid.
#include "store/lmdb_check.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <string>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/string_view.h"
#include "pbgi/status.h"
#include "store/lmdb_status.h"
#include "store/store_internal.h"

namespace pbgi::internal {
namespace {

constexpr uint32_t kPageHeader = 16;
constexpr uint32_t kNodeHeader = 8;
constexpr uint32_t kTreeRecord = 48;
constexpr uint32_t kMetaBytes = kPageHeader + 136;  // what LMDB reads of a meta page
constexpr uint32_t kLmdbMagic = 0xBEEFC0DEu;
constexpr uint32_t kLmdbDataVersion = 1;
constexpr uint16_t kBranch = 0x01, kLeaf = 0x02, kOverflow = 0x04, kMeta = 0x08;
constexpr uint16_t kBigData = 0x01, kSubData = 0x02;
constexpr uint64_t kInvalidPage = ~uint64_t{0};
constexpr uint32_t kMaxKeySize = 511;  // MDB_MAXKEYSIZE
constexpr int kMaxDepth = 32;          // LMDB's cursor stack
// x86-64 user space is 2^47 bytes: a larger map can never be made.
constexpr uint64_t kMaxMapSize = uint64_t{1} << 47;

template <typename T>
T Load(const uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}

LmdbTree ParseTree(const uint8_t* p) {
  LmdbTree t;
  t.present = true;
  t.flags = Load<uint16_t>(p + 4);
  t.depth = Load<uint16_t>(p + 6);
  t.branch_pages = Load<uint64_t>(p + 8);
  t.leaf_pages = Load<uint64_t>(p + 16);
  t.overflow_pages = Load<uint64_t>(p + 24);
  t.entries = Load<uint64_t>(p + 32);
  t.root = Load<uint64_t>(p + 40);
  return t;
}

// LMDB's default key order (mdb_cmp_memn): bytes, then the shorter key first.
int CompareKeys(absl::string_view a, absl::string_view b) {
  const int c = std::memcmp(a.data(), b.data(), std::min(a.size(), b.size()));
  if (c != 0) return c;
  return a.size() < b.size() ? -1 : (a.size() > b.size() ? 1 : 0);
}

std::string ShowKey(absl::string_view k) {
  if (k.size() == 8) return absl::StrCat("page ", DecodeKey(reinterpret_cast<const uint8_t*>(k.data())));
  return absl::StrCat("'", absl::CHexEscape(k.substr(0, 32)), "'");
}

// One tree walk. Every page is read into a buffer of its own (the recursion keeps one per
// level, at most kMaxDepth), so nothing is ever read through a map.
class Walker {
 public:
  // What a leaf entry may be, per tree.
  enum class Kind { kMain, kMeta, kPages };

  Walker(int fd, LmdbFile& file, const std::string& where, const char* tree_name, Kind kind)
      : fd_(fd), f_(file), where_(where), tree_(tree_name), kind_(kind) {}

  uint32_t value_size = 0;        // kPages: every value's size
  bool overflow_headers = false;  // also read each overflow run's header

  absl::Status Walk(const LmdbTree& t) {
    if (t.flags != 0) {
      return Bad(absl::StrFormat("the %s tree's record has flags 0x%x (pbgi uses none)", tree_,
                                 t.flags));
    }
    if (t.root == kInvalidPage) {
      if (t.depth != 0 || t.entries != 0 || t.branch_pages != 0 || t.leaf_pages != 0 ||
          t.overflow_pages != 0) {
        return Bad(absl::StrFormat("the %s tree is empty but its record says depth %d, %d entries",
                                   tree_, t.depth, t.entries));
      }
      return absl::OkStatus();
    }
    if (t.depth < 1 || t.depth >= kMaxDepth) {
      return Bad(absl::StrFormat("the %s tree's record says depth %d", tree_, t.depth));
    }
    depth_ = t.depth;
    PBGI_RETURN_IF_ERROR(CheckPageNo(t.root, "its root"));
    PBGI_RETURN_IF_ERROR(Visit(t.root, 1, absl::string_view(), false, absl::string_view(), false));
    auto count = [&](const char* what, uint64_t recorded, uint64_t found) -> absl::Status {
      if (recorded == found) return absl::OkStatus();
      return Bad(absl::StrFormat("the %s tree's record counts %d %s but the tree has %d", tree_,
                                 recorded, what, found));
    };
    PBGI_RETURN_IF_ERROR(count("branch pages", t.branch_pages, branch_));
    PBGI_RETURN_IF_ERROR(count("leaf pages", t.leaf_pages, leaf_));
    PBGI_RETURN_IF_ERROR(count("overflow pages", t.overflow_pages, overflow_));
    PBGI_RETURN_IF_ERROR(count("entries", t.entries, entries_));
    return absl::OkStatus();
  }

 private:
  absl::Status Bad(const std::string& what) const {
    return absl::DataLossError(
        absl::StrFormat("%s: %s is corrupt: %s", where_, internal::kDataFile, what));
  }
  absl::Status BadPage(uint64_t pgno, const std::string& what) const {
    return Bad(absl::StrFormat("LMDB page %d (%s tree): %s", pgno, tree_, what));
  }

  absl::Status CheckPageNo(uint64_t pgno, const char* what) const {
    if (pgno < 2 || pgno > f_.last_pgno) {
      return Bad(absl::StrFormat("the %s tree: %s is page %d, outside pages 2 to %d", tree_, what,
                                 pgno, f_.last_pgno));
    }
    return absl::OkStatus();
  }

  absl::Status Read(uint64_t pgno, uint8_t* out, uint32_t bytes) const {
    const uint64_t offset = pgno * f_.psize;
    size_t done = 0;
    while (done < bytes) {
      const ssize_t n = pread(fd_, out + done, bytes - done, static_cast<off_t>(offset + done));
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) {
        return LmdbStatus(errno, absl::StrFormat("%s: reading LMDB page %d of %s", where_, pgno,
                                                 internal::kDataFile));
      }
      if (n == 0) return BadPage(pgno, "lies past the end of the file (truncated?)");
      done += static_cast<size_t>(n);
    }
    return absl::OkStatus();
  }

  // Checks the overflow run of `dsize` bytes at `pgno` (a leaf entry's value).
  absl::Status CheckOverflow(uint64_t leaf, int index, uint64_t pgno, uint32_t dsize) {
    if (pgno < 2 || pgno > f_.last_pgno) {
      return BadPage(leaf, absl::StrFormat("entry %d: its overflow run starts at page %d, outside "
                                           "pages 2 to %d",
                                           index, pgno, f_.last_pgno));
    }
    const uint64_t pages = (kPageHeader - 1 + uint64_t{dsize}) / f_.psize + 1;  // OVPAGES
    if (pages - 1 > f_.last_pgno - pgno) {
      return BadPage(leaf, absl::StrFormat("entry %d: its overflow run of %d pages from page %d "
                                           "ends past the last page %d",
                                           index, pages, pgno, f_.last_pgno));
    }
    overflow_ += pages;
    if (overflow_headers) {
      uint8_t h[kPageHeader];
      PBGI_RETURN_IF_ERROR(Read(pgno, h, kPageHeader));
      const uint64_t own = Load<uint64_t>(h);
      const uint16_t flags = Load<uint16_t>(h + 10);
      const uint32_t count = Load<uint32_t>(h + 12);
      if (own != pgno || flags != kOverflow || count != pages) {
        return Bad(absl::StrFormat(
            "LMDB overflow page %d (%s tree, entry %d of leaf page %d): its header says page %d, "
            "flags 0x%x, %d pages (expected page %d, flags 0x%x, %d pages)",
            pgno, tree_, index, leaf, own, flags, count, pgno, kOverflow, pages));
      }
    }
    return absl::OkStatus();
  }

  // The page `pgno` at `level` (root = 1); its keys must lie in [lo, hi) where given.
  absl::Status Visit(uint64_t pgno, int level, absl::string_view lo, bool has_lo,
                     absl::string_view hi, bool has_hi) {
    std::vector<uint8_t> page(f_.psize);
    PBGI_RETURN_IF_ERROR(Read(pgno, page.data(), f_.psize));
    ++f_.tree_pages_read;
    const uint8_t* p = page.data();
    const uint64_t own = Load<uint64_t>(p);
    const uint16_t flags = Load<uint16_t>(p + 10);
    const uint16_t lower = Load<uint16_t>(p + 12);
    const uint16_t upper = Load<uint16_t>(p + 14);
    if (own != pgno) return BadPage(pgno, absl::StrFormat("its header says page %d", own));
    const bool branch = flags == kBranch;
    if (!branch && flags != kLeaf) {
      return BadPage(pgno, absl::StrFormat("flags 0x%x: neither a branch nor a leaf page", flags));
    }
    if (branch != (level < depth_)) {
      return BadPage(pgno, absl::StrFormat("a %s page at level %d of a tree %d deep",
                                           branch ? "branch" : "leaf", level, depth_));
    }
    if (lower < kPageHeader || lower > upper || upper > f_.psize || (lower - kPageHeader) % 2) {
      return BadPage(pgno, absl::StrFormat("free space [%d, %d) is not inside the page", lower,
                                           upper));
    }
    const int n = (lower - kPageHeader) / 2;
    if (n < (branch ? 2 : 1)) {
      return BadPage(pgno, absl::StrFormat("a %s page with %d keys", branch ? "branch" : "leaf", n));
    }
    (branch ? branch_ : leaf_) += 1;

    struct Entry {
      absl::string_view key;
      uint16_t flags;
      uint64_t value;  // branch: child page; leaf: data size
      uint32_t data_offset;
    };
    std::vector<Entry> entries(static_cast<size_t>(n));
    for (int i = 0; i < n; ++i) {
      const uint16_t off = Load<uint16_t>(p + kPageHeader + 2 * i);
      if (off < upper || off % 2 != 0 || uint32_t{off} + kNodeHeader > f_.psize) {
        return BadPage(pgno, absl::StrFormat("node %d at offset %d is outside the node area "
                                             "[%d, %d)",
                                             i, off, upper, f_.psize));
      }
      const uint8_t* node = p + off;
      const uint16_t lo16 = Load<uint16_t>(node), hi16 = Load<uint16_t>(node + 2);
      const uint16_t nflags = Load<uint16_t>(node + 4), ksize = Load<uint16_t>(node + 6);
      if (ksize > kMaxKeySize || uint32_t{off} + kNodeHeader + ksize > f_.psize) {
        return BadPage(pgno, absl::StrFormat("node %d: a key of %d bytes at offset %d does not "
                                             "fit",
                                             i, ksize, off));
      }
      Entry& e = entries[static_cast<size_t>(i)];
      e.key = absl::string_view(reinterpret_cast<const char*>(node + kNodeHeader), ksize);
      e.flags = nflags;
      e.data_offset = off + kNodeHeader + ksize;
      if (branch) {
        e.value = uint64_t{lo16} | uint64_t{hi16} << 16 | uint64_t{nflags} << 32;
      } else {
        e.value = uint64_t{lo16} | uint64_t{hi16} << 16;
        const uint32_t stored = (nflags & kBigData) ? 8 : static_cast<uint32_t>(e.value);
        if (uint64_t{e.data_offset} + stored > f_.psize) {
          return BadPage(pgno, absl::StrFormat("node %d: %d bytes of data at offset %d do not fit",
                                               i, stored, e.data_offset));
        }
      }
    }
    // Keys: strictly increasing, inside [lo, hi). A branch page's first key is not used.
    absl::string_view prev;
    bool has_prev = false;
    for (int i = branch ? 1 : 0; i < n; ++i) {
      const absl::string_view k = entries[static_cast<size_t>(i)].key;
      if ((has_prev && CompareKeys(prev, k) >= 0) || (has_lo && CompareKeys(k, lo) < 0) ||
          (has_hi && CompareKeys(k, hi) >= 0)) {
        return BadPage(pgno, absl::StrFormat("key %d (%s) is out of order", i, ShowKey(k)));
      }
      prev = k;
      has_prev = true;
    }
    if (branch) {
      for (int i = 0; i < n; ++i) {
        const Entry& e = entries[static_cast<size_t>(i)];
        if (e.value < 2 || e.value > f_.last_pgno) {
          return BadPage(pgno, absl::StrFormat("node %d points at page %d, outside pages 2 to %d",
                                               i, e.value, f_.last_pgno));
        }
        const bool child_has_lo = i > 0 || has_lo;
        const absl::string_view child_lo = i > 0 ? e.key : lo;
        const bool child_has_hi = i + 1 < n || has_hi;
        const absl::string_view child_hi = i + 1 < n ? entries[static_cast<size_t>(i + 1)].key : hi;
        PBGI_RETURN_IF_ERROR(
            Visit(e.value, level + 1, child_lo, child_has_lo, child_hi, child_has_hi));
      }
      return absl::OkStatus();
    }
    for (int i = 0; i < n; ++i) {
      const Entry& e = entries[static_cast<size_t>(i)];
      ++entries_;
      PBGI_RETURN_IF_ERROR(Leaf(pgno, i, e.key, e.flags, static_cast<uint32_t>(e.value),
                                p + e.data_offset));
    }
    return absl::OkStatus();
  }

  absl::Status Leaf(uint64_t pgno, int i, absl::string_view key, uint16_t flags, uint32_t dsize,
                    const uint8_t* data) {
    switch (kind_) {
      case Kind::kMain: {
        if (flags != kSubData || dsize != kTreeRecord) {
          return BadPage(pgno, absl::StrFormat("entry %d (%s): flags 0x%x, %d bytes: not a "
                                               "section record",
                                               i, ShowKey(key), flags, dsize));
        }
        LmdbTree t = ParseTree(data);
        LmdbTree* slot = key == kMetaDb    ? &f_.meta
                         : key == kNodesDb ? &f_.nodes
                         : key == kPointsDb ? &f_.points
                                            : nullptr;
        if (slot != nullptr) *slot = t;
        return absl::OkStatus();
      }
      case Kind::kMeta:
      case Kind::kPages: {
        if ((flags & ~kBigData) != 0) {
          return BadPage(pgno, absl::StrFormat("entry %d (%s): flags 0x%x", i, ShowKey(key), flags));
        }
        if (kind_ == Kind::kPages) {
          if (key.size() != 8) {
            return BadPage(pgno, absl::StrFormat("entry %d: a key of %d bytes (page numbers have "
                                                 "8)",
                                                 i, key.size()));
          }
          // A page is stored whole (value_size bytes) or compressed, in one overflow page or
          // more (store_internal.h, kMinCompressedPage).
          if (dsize != value_size && (dsize > value_size || dsize < kMinCompressedPage)) {
            return BadPage(pgno, absl::StrFormat("entry %d (%s): %d bytes stored, pages have %d", i,
                                                 ShowKey(key), dsize, value_size));
          }
        }
        uint64_t run = 0;
        if (flags & kBigData) {
          run = Load<uint64_t>(data);
          PBGI_RETURN_IF_ERROR(CheckOverflow(pgno, i, run, dsize));
        }
        if (kind_ == Kind::kMeta && key == kMetaKey) {
          f_.has_meta_record = true;
          if (flags & kBigData) {
            f_.meta_record.resize(dsize);
            PBGI_RETURN_IF_ERROR(ReadFully(fd_, f_.meta_record.data(), dsize,
                                           run * f_.psize + kPageHeader, internal::kDataFile));
          } else {
            f_.meta_record.assign(reinterpret_cast<const char*>(data), dsize);
          }
        }
        return absl::OkStatus();
      }
    }
    return absl::OkStatus();
  }

  int fd_;
  LmdbFile& f_;
  const std::string& where_;
  const char* tree_;
  Kind kind_;
  int depth_ = 0;
  uint64_t branch_ = 0, leaf_ = 0, overflow_ = 0, entries_ = 0;
};

struct MetaPage {
  uint64_t pgno;
  uint16_t flags;
  uint32_t magic, version, psize;
  uint64_t address, mapsize, last_pgno, txnid;
  LmdbTree free, main;
};

MetaPage ParseMeta(const uint8_t* b) {
  MetaPage m;
  m.pgno = Load<uint64_t>(b);
  m.flags = Load<uint16_t>(b + 10);
  const uint8_t* d = b + kPageHeader;
  m.magic = Load<uint32_t>(d);
  m.version = Load<uint32_t>(d + 4);
  m.address = Load<uint64_t>(d + 8);
  m.mapsize = Load<uint64_t>(d + 16);
  m.free = ParseTree(d + 24);
  m.psize = Load<uint32_t>(d + 24);
  m.main = ParseTree(d + 24 + kTreeRecord);
  m.last_pgno = Load<uint64_t>(d + 24 + 2 * kTreeRecord);
  m.txnid = Load<uint64_t>(d + 24 + 2 * kTreeRecord + 8);
  return m;
}

}  // namespace

absl::StatusOr<LmdbFile> CheckLmdbFile(int fd, uint64_t file_bytes, const std::string& where) {
  auto bad = [&](const std::string& what) {
    return absl::DataLossError(
        absl::StrFormat("%s: %s is corrupt: %s", where, internal::kDataFile, what));
  };
  MetaPage metas[2];
  uint64_t offset = 0;
  for (int i = 0; i < 2; ++i) {
    uint8_t buf[kMetaBytes];
    if (offset > file_bytes || file_bytes - offset < kMetaBytes) {
      return absl::DataLossError(absl::StrFormat(
          "%s: %s is truncated, or not an LMDB file: %d bytes cannot hold LMDB meta page %d", where,
          internal::kDataFile, file_bytes, i));
    }
    PBGI_RETURN_IF_ERROR(ReadFully(fd, buf, kMetaBytes, offset, internal::kDataFile));
    metas[i] = ParseMeta(buf);
    const MetaPage& m = metas[i];
    if ((m.flags & kMeta) == 0 || m.magic != kLmdbMagic) {
      return absl::DataLossError(absl::StrFormat(
          "%s: %s is not an LMDB file, or its header is damaged (meta page %d: flags 0x%x, magic "
          "0x%08x)",
          where, internal::kDataFile, i, m.flags, m.magic));
    }
    if (m.version != kLmdbDataVersion) {
      return absl::DataLossError(absl::StrFormat(
          "%s: %s has LMDB data version %d in meta page %d (this LMDB writes version %d): damaged, "
          "or written by an incompatible LMDB",
          where, internal::kDataFile, m.version, i, kLmdbDataVersion));
    }
    if (m.pgno != uint64_t(i) || m.flags != kMeta) {
      return bad(absl::StrFormat("LMDB meta page %d says it is page %d with flags 0x%x", i, m.pgno,
                                 m.flags));
    }
    if (m.psize < 256 || m.psize > 32768 || (m.psize & (m.psize - 1)) != 0) {
      return bad(absl::StrFormat("LMDB meta page %d gives a page size of %d bytes", i, m.psize));
    }
    offset = m.psize;  // LMDB reads meta page 1 at page 0's page size
  }
  if (metas[0].psize != metas[1].psize) {
    return bad(absl::StrFormat("LMDB's meta pages disagree on the page size (%d and %d)",
                               metas[0].psize, metas[1].psize));
  }
  LmdbFile f;
  // mdb_env_pick_meta: the later transaction, page 0 on a tie.
  f.meta_page = metas[0].txnid < metas[1].txnid ? 1 : 0;
  const MetaPage& m = metas[f.meta_page];
  f.psize = m.psize;
  f.last_pgno = m.last_pgno;
  f.txnid = m.txnid;
  const std::string which = absl::StrFormat("LMDB meta page %d (transaction %d)", f.meta_page,
                                            m.txnid);
  if (m.last_pgno < 1 || m.last_pgno >= (uint64_t{1} << 48) ||
      (m.last_pgno + 1) * m.psize > file_bytes) {
    if (m.last_pgno >= 1 && m.last_pgno < (uint64_t{1} << 48)) {
      return absl::DataLossError(absl::StrFormat(
          "%s: %s is truncated: it has %d bytes but its last page ends at byte %d", where,
          internal::kDataFile, file_bytes, (m.last_pgno + 1) * m.psize));
    }
    return bad(absl::StrFormat("%s: last page %d", which, m.last_pgno));
  }
  if (m.address != 0 || m.mapsize > kMaxMapSize) {
    return bad(absl::StrFormat("%s: map address 0x%x, map size %d", which, m.address, m.mapsize));
  }
  if (m.free.root != kInvalidPage && (m.free.root < 2 || m.free.root > m.last_pgno)) {
    return bad(absl::StrFormat("%s: the free-page tree's root is page %d", which, m.free.root));
  }
  f.main = m.main;
  Walker main(fd, f, where, "main", Walker::Kind::kMain);
  PBGI_RETURN_IF_ERROR(main.Walk(f.main));
  if (f.meta.present) {
    Walker meta(fd, f, where, "meta", Walker::Kind::kMeta);
    PBGI_RETURN_IF_ERROR(meta.Walk(f.meta));
  }
  return f;
}

absl::Status CheckLmdbSection(int fd, LmdbFile& file, Section section, uint32_t value_size,
                              bool overflow_headers, const std::string& where) {
  const LmdbTree& t = section == Section::kNodes ? file.nodes : file.points;
  if (!t.present) return absl::OkStatus();
  Walker w(fd, file, where, SectionName(section), Walker::Kind::kPages);
  w.value_size = value_size;
  w.overflow_headers = overflow_headers;
  return w.Walk(t);
}

}  // namespace pbgi::internal
