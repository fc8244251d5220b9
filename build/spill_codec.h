// Compact sort runs (docs/format.md, "Session 10"): the records of a spilled run stored as the
// point records they will become (tree/format.h, format version 3) plus their Morton key, in
// blocks compressed with zstd. A 48-byte SortRecord takes 8 + 14 (occlusion) or 8 + 20
// (radiance) bytes before zstd, so a billion-surfel build's runs fit next to its database.
//
// Why the output does not change: the builder stores each point as DecodePointRecord(Encode…)
// and aggregates exactly that (PointPageWriter::Add), and encoding a decoded record gives the
// same bytes again (tests/tree/compact_format_test: re-encoding is idempotent). So a record that
// went through a compact run yields the same page bytes and node aggregates as one that did not;
// tests/build/sort_test checks the pages of compact-spilled, raw-spilled and unspilled builds.
// Builds that estimate radii or normals keep raw runs: the estimate reads unquantized positions.
//
// A run is a sequence of blocks, each:
//   u32 frame_bytes, u32 records (1..kSpillBlockRecords), then a zstd frame of
//   records x u64 key deltas (key - previous key of the block, mod 2^64; the first from 0),
//   then the point records split by field (cells, normals, radii, radiance, back radiance),
//   records each; the cell word XORed with the key's own depth-21 cell (they differ only by
//   rounding).
//
// A SpillCodec is immutable and may be shared; a SpillBlockWriter or SpillBlockReader belongs
// to one thread.
#ifndef PBGI_BUILD_SPILL_CODEC_H_
#define PBGI_BUILD_SPILL_CODEC_H_

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "build/sort_record.h"
#include "tree/format.h"

namespace pbgi::internal {

inline constexpr uint32_t kSpillBlockRecords = 1024;
inline constexpr size_t kSpillBlockHeaderBytes = 8;

struct SpillCodec {
  Channels channels = Channels::kOcclusion;
  PositionGrid grid;

  // Bytes of one record before zstd.
  uint32_t raw_record_bytes() const { return 8 + PointRecordSize(channels); }
  // The largest stored block (header and frame) of kSpillBlockRecords records.
  size_t max_block_bytes() const;

  // A packed SortRecord holds its key and, where the floats were, its point record already
  // encoded (the rest zero). The builder packs records as it reads them, so that the sort
  // thread, which was the bottleneck of the pipelined input pass, only copies the encoded bytes
  // (docs/format.md, "Session 12"). Unpack(Pack(r)) is the record a compact run hands back.
  void Pack(const SortRecord& r, SortRecord* packed) const {
    packed->key = r.key;
    uint8_t* p = PackedBytes(packed);
    std::memset(p, 0, sizeof(SortRecord) - sizeof(uint64_t));
    EncodePointRecord(r.position, r.normal, r.radius, r.radiance, channels, grid, p);
  }
  // Pack(in[i], &out[i]) for i < n, bit for bit, four records at a time with SSE2 where their
  // fields are finite and their normals not zero (the builder's; the others go to Pack). `out`
  // may be `in` (packs in place) or not overlap it.
  void PackBlock(const SortRecord* in, size_t n, SortRecord* out) const;
  SortRecord Unpack(const SortRecord& packed) const {
    return MakeSortRecord(packed.key, DecodePointRecord(PackedBytes(&packed), channels, grid));
  }
  // out[i] = Unpack(packed[i]) for i < n, bit for bit, four records at a time with SSE2 (the
  // x86-64 baseline): the octahedral normal's branch on the lower hemisphere mispredicted on
  // walls, where z is near 0 (docs/format.md, "Session 17"). `out` may not overlap `packed`.
  void UnpackBlock(const SortRecord* packed, size_t n, SortRecord* out) const;
  static uint8_t* PackedBytes(SortRecord* r) { return reinterpret_cast<uint8_t*>(r->position); }
  static const uint8_t* PackedBytes(const SortRecord* r) {
    return reinterpret_cast<const uint8_t*>(r->position);
  }
};
static_assert(sizeof(SortRecord) - sizeof(uint64_t) >= kPointRecordBothSidesBytes);

// The depth-21 cell of a Morton key (tree/morton.h), packed as a point record's cell (PackCell):
// a stored cell is XORed with its key's cell, which leaves a column of mostly zeros (a position's
// grid cell is its key's cell give or take rounding, GridOfCube). Bit 63 of the key is ignored.
uint64_t KeyCell(uint64_t key);

class SpillBlockWriter {
 public:
  explicit SpillBlockWriter(const SpillCodec& codec);
  ~SpillBlockWriter();
  SpillBlockWriter(const SpillBlockWriter&) = delete;
  SpillBlockWriter& operator=(const SpillBlockWriter&) = delete;

  // Appends recs (1..kSpillBlockRecords records) as one block to `out`; `packed`: the records
  // are packed (SpillCodec::Pack), else plain.
  absl::Status Append(absl::Span<const SortRecord> recs, std::vector<uint8_t>* out,
                      bool packed = false);
  // The same block written at `dst`, which has room for SpillCodec::max_block_bytes(); returns
  // its size.
  absl::StatusOr<size_t> Encode(absl::Span<const SortRecord> recs, uint8_t* dst,
                                bool packed = false);
  // Encode of the records base[order[i].index], gathered from a run buffer in sorted order
  // without copying them first (docs/format.md, "Session 17").
  absl::StatusOr<size_t> EncodeGathered(const SortRecord* base, absl::Span<const KeyIndex> order,
                                        uint8_t* dst, bool packed = false);

 private:
  // Fills raw_ with the columns of n records, record(i) the i-th, then compresses it at dst.
  template <typename Record>
  absl::StatusOr<size_t> EncodeBlock(size_t n, const Record& record, uint8_t* dst, bool packed);

  SpillCodec codec_;
  void* cctx_ = nullptr;  // ZSTD_CCtx
  std::vector<uint8_t> raw_;
};

class SpillBlockReader {
 public:
  explicit SpillBlockReader(const SpillCodec& codec);
  ~SpillBlockReader();
  SpillBlockReader(const SpillBlockReader&) = delete;
  SpillBlockReader& operator=(const SpillBlockReader&) = delete;

  // Reads a block header: the frame's size and the record count (DataLoss when out of range;
  // `what` names the run for the message).
  static absl::Status ParseHeader(const uint8_t* p, const SpillCodec& codec, const char* what,
                                  uint32_t* frame_bytes, uint32_t* records);
  // Decodes a frame of `records` records into out[0, records); `packed`: as packed records
  // (SpillCodec::Pack: the key and the stored point record, not decoded), else plain.
  absl::Status Decode(absl::Span<const uint8_t> frame, uint32_t records, SortRecord* out,
                      const char* what, bool packed = false);

 private:
  SpillCodec codec_;
  void* dctx_ = nullptr;  // ZSTD_DCtx
  std::vector<uint8_t> raw_;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_SPILL_CODEC_H_
