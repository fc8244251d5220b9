#include "store/meta_codec.h"

#include <cmath>
#include <cstring>

#include "absl/strings/str_format.h"
#include "store/crc32c.h"

namespace pbgi::internal {
namespace {

class Writer {
 public:
  template <typename T>
  void Put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    out_.append(b, sizeof(T));
  }
  void PutString(const std::string& s) {
    Put<uint32_t>(static_cast<uint32_t>(s.size()));
    out_.append(s);
  }
  std::string& out() { return out_; }

 private:
  std::string out_;
};

class Reader {
 public:
  explicit Reader(absl::string_view in) : in_(in) {}
  template <typename T>
  bool Get(T* v) {
    if (in_.size() < sizeof(T)) return false;
    std::memcpy(v, in_.data(), sizeof(T));
    in_.remove_prefix(sizeof(T));
    return true;
  }
  bool GetString(std::string* s) {
    uint32_t n;
    if (!Get(&n) || in_.size() < n) return false;
    s->assign(in_.data(), n);
    in_.remove_prefix(n);
    return true;
  }

 private:
  absl::string_view in_;
};

}  // namespace

std::string EncodeMeta(const StoreMeta& meta, bool complete) {
  Writer w;
  w.Put<uint64_t>(kStoreMagic);
  w.Put<uint32_t>(meta.version);
  w.Put<uint32_t>(complete ? kMetaFlagComplete : 0u);
  w.Put<uint32_t>(0);  // length, patched below
  w.Put<uint32_t>(0);  // checksum, patched below
  // Body, format version 1.
  w.Put<uint32_t>(meta.page_size);
  w.Put<uint32_t>(static_cast<uint32_t>(meta.channels));
  w.Put<uint32_t>(meta.sh_order);
  w.Put<uint32_t>(meta.leaf_size);
  for (int i = 0; i < 3; ++i) w.Put<float>(meta.bounds.lo[i]);
  for (int i = 0; i < 3; ++i) w.Put<float>(meta.bounds.hi[i]);
  w.Put<uint64_t>(meta.point_count);
  w.Put<uint64_t>(meta.node_count);
  w.Put<uint64_t>(meta.node_pages);
  w.Put<uint64_t>(meta.point_pages);
  w.Put<uint64_t>(meta.root);
  w.Put<uint32_t>(meta.max_depth);
  w.PutString(meta.layout);
  w.Put<uint32_t>(static_cast<uint32_t>(meta.stats.size()));
  for (const auto& [k, v] : meta.stats) {
    w.PutString(k);
    w.PutString(v);
  }
  // Appended in version 3: the position grid.
  for (int i = 0; i < 3; ++i) w.Put<float>(meta.grid_origin[i]);
  w.Put<float>(meta.grid_step);
  std::string& out = w.out();
  const uint32_t length = static_cast<uint32_t>(out.size());
  std::memcpy(&out[16], &length, 4);
  const uint32_t crc = Crc32c(0, out.data() + kMetaHeaderBytes, out.size() - kMetaHeaderBytes);
  std::memcpy(&out[20], &crc, 4);
  return out;
}

absl::StatusOr<DecodedMeta> DecodeMeta(absl::string_view bytes, absl::string_view where) {
  if (bytes.size() < 12) {
    return absl::DataLossError(absl::StrFormat(
        "%s: meta record is %d bytes, too short to hold a magic and version", where, bytes.size()));
  }
  uint64_t magic;
  uint32_t version;
  std::memcpy(&magic, bytes.data(), 8);
  std::memcpy(&version, bytes.data() + 8, 4);
  if (magic != kStoreMagic) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: wrong magic in the meta record (0x%016x, expected 0x%016x): not a pbgi store", where,
        magic, kStoreMagic));
  }
  if (version > kStoreFormatVersion) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s: store format version %d is from the future: this library reads versions up to %d",
        where, version, kStoreFormatVersion));
  }
  if (version == 0) {
    return absl::DataLossError(
        absl::StrFormat("%s: meta record has format version 0, which never existed", where));
  }
  if (version < kOldestReadableStoreFormatVersion) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s: store format version %d is too old: this library reads versions %d to %d (compact "
        "pages, sheet tags, radiance contrast) only; rebuild the database from its points with "
        "this version of pbgi",
        where, version, kOldestReadableStoreFormatVersion, kStoreFormatVersion));
  }
  if (bytes.size() < kMetaHeaderBytes) {
    return absl::DataLossError(
        absl::StrFormat("%s: meta record is truncated (%d bytes)", where, bytes.size()));
  }
  uint32_t flags, length, crc;
  std::memcpy(&flags, bytes.data() + 12, 4);
  std::memcpy(&length, bytes.data() + 16, 4);
  std::memcpy(&crc, bytes.data() + 20, 4);
  if (length != bytes.size()) {
    return absl::DataLossError(absl::StrFormat(
        "%s: meta record says it is %d bytes but %d are stored", where, length, bytes.size()));
  }
  const uint32_t actual =
      Crc32c(0, bytes.data() + kMetaHeaderBytes, bytes.size() - kMetaHeaderBytes);
  if (actual != crc) {
    return absl::DataLossError(absl::StrFormat(
        "%s: meta record checksum mismatch (stored 0x%08x, computed 0x%08x)", where, crc, actual));
  }
  DecodedMeta d;
  d.complete = (flags & kMetaFlagComplete) != 0;
  StoreMeta& m = d.meta;
  m.magic = magic;
  m.version = version;
  Reader r(bytes.substr(kMetaHeaderBytes));
  uint32_t channels = 0, nstats = 0;
  bool ok = r.Get(&m.page_size) && r.Get(&channels) && r.Get(&m.sh_order) && r.Get(&m.leaf_size);
  for (int i = 0; ok && i < 3; ++i) ok = r.Get(&m.bounds.lo[i]);
  for (int i = 0; ok && i < 3; ++i) ok = r.Get(&m.bounds.hi[i]);
  ok = ok && r.Get(&m.point_count) && r.Get(&m.node_count) && r.Get(&m.node_pages) &&
       r.Get(&m.point_pages) && r.Get(&m.root) && r.Get(&m.max_depth) && r.GetString(&m.layout) &&
       r.Get(&nstats);
  for (uint32_t i = 0; ok && i < nstats; ++i) {
    std::string k, v;
    ok = r.GetString(&k) && r.GetString(&v);
    if (ok) m.stats[k] = v;
  }
  for (int i = 0; ok && i < 3; ++i) ok = r.Get(&m.grid_origin[i]);
  ok = ok && r.Get(&m.grid_step);
  if (!ok) {
    return absl::DataLossError(
        absl::StrFormat("%s: meta record body is truncated or malformed", where));
  }
  if (channels > static_cast<uint32_t>(Channels::kRadianceBothSides) ||
      (channels == static_cast<uint32_t>(Channels::kRadianceBothSides) && m.version < 6)) {
    return absl::DataLossError(
        absl::StrFormat("%s: meta record names unknown channels %d", where, channels));
  }
  m.channels = static_cast<Channels>(channels);
  if (m.page_size <= sizeof(PageHeader) || m.page_size % alignof(PageHeader) != 0) {
    return absl::DataLossError(absl::StrFormat(
        "%s: meta record has page size %d: not a multiple of 8 above the header size", where,
        m.page_size));
  }
  // What no store ever holds, whatever its pages are (a record can be crafted with a valid
  // checksum): refused here, so that no reader starts on it.
  if (m.sh_order != 2) {
    return absl::DataLossError(absl::StrFormat(
        "%s: meta record has SH order %d: this library reads order 2 only", where, m.sh_order));
  }
  for (int i = 0; i < 3; ++i) {
    if (std::isnan(m.bounds.lo[i]) || std::isnan(m.bounds.hi[i])) {
      return absl::DataLossError(absl::StrFormat("%s: meta record has NaN in its bounds", where));
    }
  }
  const bool empty_box = m.bounds.lo == Bounds{}.lo && m.bounds.hi == Bounds{}.hi;
  if (!empty_box) {
    for (int i = 0; i < 3; ++i) {
      if (!(m.bounds.lo[i] <= m.bounds.hi[i]) || !std::isfinite(m.bounds.lo[i]) ||
          !std::isfinite(m.bounds.hi[i])) {
        return absl::DataLossError(absl::StrFormat(
            "%s: meta record has bounds (%g, %g, %g) .. (%g, %g, %g): inverted or not finite",
            where, m.bounds.lo.x, m.bounds.lo.y, m.bounds.lo.z, m.bounds.hi.x, m.bounds.hi.y,
            m.bounds.hi.z));
      }
    }
  }
  if (!std::isfinite(m.grid_origin.x) || !std::isfinite(m.grid_origin.y) ||
      !std::isfinite(m.grid_origin.z) || !std::isfinite(m.grid_step) || !(m.grid_step >= 0)) {
    return absl::DataLossError(absl::StrFormat(
        "%s: meta record has position grid origin (%g, %g, %g) step %g: not finite or negative",
        where, m.grid_origin.x, m.grid_origin.y, m.grid_origin.z, m.grid_step));
  }
  if (m.max_depth >= kMaxStoredDepth) {
    return absl::DataLossError(
        absl::StrFormat("%s: meta record says the tree is %d levels deep (at most %d)", where,
                        m.max_depth, kMaxStoredDepth - 1));
  }
  // Bytes after the known fields are ignored: a later minor revision of version 3 may append.
  return d;
}

}  // namespace pbgi::internal
