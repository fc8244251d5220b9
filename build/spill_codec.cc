#include "build/spill_codec.h"

#include <cstring>

#include "absl/strings/str_format.h"
#include "zstd.h"

namespace pbgi::internal {
namespace {

// Offsets of the field columns in a block of n records (see the header).
struct Columns {
  size_t keys, cells, normals, radii, radiance, end;
  Columns(size_t n, bool radiance_on) {
    keys = 0;
    cells = keys + 8 * n;
    normals = cells + 8 * n;
    radii = normals + 4 * n;
    radiance = radii + 2 * n;
    end = radiance + (radiance_on ? 6 * n : 0);
  }
};

// The inverse of SpreadBits3 (tree/morton.h): bits 0, 3, 6, ... of x into bits 0, 1, 2, ...
uint32_t GatherBits3(uint64_t x) {
  x &= 0x1249249249249249ull;
  x = (x | x >> 2) & 0x10c30c30c30c30c3ull;
  x = (x | x >> 4) & 0x100f00f00f00f00full;
  x = (x | x >> 8) & 0x1f0000ff0000ffull;
  x = (x | x >> 16) & 0x1f00000000ffffull;
  x = (x | x >> 32) & 0x1fffffull;
  return static_cast<uint32_t>(x);
}

// The position's grid cell is its key's depth-21 cell, give or take rounding (GridOfCube): the
// stored cell word is XORed with the key's cell, which leaves a column of mostly zeros.
uint64_t KeyCell(uint64_t key) {
  return PackCell(GatherBits3(key), GatherBits3(key >> 1), GatherBits3(key >> 2));
}

// A fast negative zstd level: a run is written once and read once, and on the sort thread the
// compression was the largest share of the pipelined build's input pass (docs/design.md,
// "Build"); the spilled bytes grow a little (docs/format.md, "Session 11: build throughput").
constexpr int kSpillZstdLevel = -3;

void PutU32(uint8_t* p, uint32_t v) { std::memcpy(p, &v, 4); }
uint32_t GetU32(const uint8_t* p) {
  uint32_t v;
  std::memcpy(&v, p, 4);
  return v;
}

}  // namespace

size_t SpillCodec::max_block_bytes() const {
  return kSpillBlockHeaderBytes +
         ZSTD_compressBound(size_t{kSpillBlockRecords} * raw_record_bytes());
}

SpillBlockWriter::SpillBlockWriter(const SpillCodec& codec) : codec_(codec) {}
SpillBlockWriter::~SpillBlockWriter() { ZSTD_freeCCtx(static_cast<ZSTD_CCtx*>(cctx_)); }

absl::Status SpillBlockWriter::Append(absl::Span<const SortRecord> recs, std::vector<uint8_t>* out,
                                      bool packed) {
  const size_t n = recs.size();
  if (n == 0 || n > kSpillBlockRecords) {
    return absl::InternalError(absl::StrFormat("a spill block of %d records", n));
  }
  if (cctx_ == nullptr) cctx_ = ZSTD_createCCtx();
  if (cctx_ == nullptr) return absl::ResourceExhaustedError("zstd: no memory for a context");
  const bool radiance = HasRadiance(codec_.channels);
  const Columns c(n, radiance);
  raw_.resize(c.end);
  uint8_t* raw = raw_.data();
  uint64_t prev = 0;
  uint8_t encoded[kPointRecordRadianceBytes];
  for (size_t i = 0; i < n; ++i) {
    const SortRecord& r = recs[i];
    const uint64_t delta = r.key - prev;
    prev = r.key;
    std::memcpy(raw + c.keys + 8 * i, &delta, 8);
    const uint8_t* rec = packed ? SpillCodec::PackedBytes(&r) : encoded;
    if (!packed) {
      EncodePointRecord(r.position, r.normal, r.radius, r.radiance, codec_.channels, codec_.grid,
                        encoded);
    }
    uint64_t cell;
    std::memcpy(&cell, rec, 8);
    cell ^= KeyCell(r.key);
    std::memcpy(raw + c.cells + 8 * i, &cell, 8);
    std::memcpy(raw + c.normals + 4 * i, rec + 8, 4);
    std::memcpy(raw + c.radii + 2 * i, rec + 12, 2);
    if (radiance) std::memcpy(raw + c.radiance + 6 * i, rec + 14, 6);
  }
  const size_t at = out->size();
  out->resize(at + kSpillBlockHeaderBytes + ZSTD_compressBound(c.end));
  const size_t z =
      ZSTD_compressCCtx(static_cast<ZSTD_CCtx*>(cctx_), out->data() + at + kSpillBlockHeaderBytes,
                        out->size() - at - kSpillBlockHeaderBytes, raw, c.end, kSpillZstdLevel);
  if (ZSTD_isError(z)) {
    out->resize(at);
    return absl::InternalError(
        absl::StrFormat("zstd cannot compress a sort run block: %s", ZSTD_getErrorName(z)));
  }
  PutU32(out->data() + at, static_cast<uint32_t>(z));
  PutU32(out->data() + at + 4, static_cast<uint32_t>(n));
  out->resize(at + kSpillBlockHeaderBytes + z);
  return absl::OkStatus();
}

SpillBlockReader::SpillBlockReader(const SpillCodec& codec) : codec_(codec) {}
SpillBlockReader::~SpillBlockReader() { ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(dctx_)); }

absl::Status SpillBlockReader::ParseHeader(const uint8_t* p, const SpillCodec& codec,
                                           const char* what, uint32_t* frame_bytes,
                                           uint32_t* records) {
  *frame_bytes = GetU32(p);
  *records = GetU32(p + 4);
  if (*records == 0 || *records > kSpillBlockRecords ||
      *frame_bytes + kSpillBlockHeaderBytes > codec.max_block_bytes() || *frame_bytes == 0) {
    return absl::DataLossError(absl::StrFormat(
        "%s: a block header says %d records in a %d-byte frame (at most %d records, %d bytes)",
        what, *records, *frame_bytes, kSpillBlockRecords,
        codec.max_block_bytes() - kSpillBlockHeaderBytes));
  }
  return absl::OkStatus();
}

absl::Status SpillBlockReader::Decode(absl::Span<const uint8_t> frame, uint32_t records,
                                      SortRecord* out, const char* what, bool packed) {
  if (dctx_ == nullptr) dctx_ = ZSTD_createDCtx();
  if (dctx_ == nullptr) return absl::ResourceExhaustedError("zstd: no memory for a context");
  const bool radiance = HasRadiance(codec_.channels);
  const Columns c(records, radiance);
  raw_.resize(c.end);
  const size_t got = ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(dctx_), raw_.data(), c.end,
                                         frame.data(), frame.size());
  if (ZSTD_isError(got) || got != c.end) {
    return absl::DataLossError(absl::StrFormat(
        "%s: a block of %d records does not decompress to %d bytes (%s)", what, records, c.end,
        ZSTD_isError(got) ? ZSTD_getErrorName(got) : absl::StrFormat("%d bytes", got).c_str()));
  }
  const uint8_t* raw = raw_.data();
  uint64_t key = 0;
  uint8_t plain[kPointRecordRadianceBytes];
  for (uint32_t i = 0; i < records; ++i) {
    uint8_t* rec = plain;
    if (packed) {
      // As SpillCodec::Pack leaves it: the bytes after the record are zero.
      rec = SpillCodec::PackedBytes(&out[i]);
      std::memset(rec, 0, sizeof(SortRecord) - sizeof(uint64_t));
    }
    uint64_t delta;
    std::memcpy(&delta, raw + c.keys + 8 * size_t{i}, 8);
    key += delta;
    uint64_t cell;
    std::memcpy(&cell, raw + c.cells + 8 * size_t{i}, 8);
    cell ^= KeyCell(key);
    std::memcpy(rec, &cell, 8);
    std::memcpy(rec + 8, raw + c.normals + 4 * size_t{i}, 4);
    std::memcpy(rec + 12, raw + c.radii + 2 * size_t{i}, 2);
    if (radiance) std::memcpy(rec + 14, raw + c.radiance + 6 * size_t{i}, 6);
    if (packed) {
      out[i].key = key;
    } else {
      out[i] = MakeSortRecord(key, DecodePointRecord(rec, codec_.channels, codec_.grid));
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
