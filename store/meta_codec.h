// Serialization of the meta record (StoreMeta), versioned and checksummed. Internal; the format
// is described in docs/store.md.
//
//   offset  size  field
//   0       8     magic (kStoreMagic, little-endian: "PPBGDB01")
//   8       4     format version (kStoreFormatVersion)
//   12      4     flags: bit 0 = complete (set only by PageWriter::Finish)
//   16      4     record length in bytes, header included
//   20      4     CRC-32C of bytes [24, length)
//   24      ...   body (see meta_codec.cc), little-endian, strings as u32 length + bytes
//
// The magic and version come first so that a record from a future version is refused with both
// version numbers before anything else in it is interpreted.
#ifndef PBGI_STORE_META_CODEC_H_
#define PBGI_STORE_META_CODEC_H_

#include <cstdint>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "pbgi/store.h"

namespace pbgi::internal {

inline constexpr uint32_t kMetaFlagComplete = 1u;
// Node depths are below this (the query layer's per-level tables have this many entries).
inline constexpr uint32_t kMaxStoredDepth = 32;
inline constexpr size_t kMetaHeaderBytes = 24;

std::string EncodeMeta(const StoreMeta& meta, bool complete);

struct DecodedMeta {
  StoreMeta meta;
  bool complete = false;
};
// `where` names the store in error messages. Wrong magic -> InvalidArgument, future version ->
// FailedPrecondition with both numbers, damaged record -> DataLoss, and so is a record that no
// store can hold (SH order other than 2, NaN, inverted or infinite bounds other than the empty
// box, a depth of 32 or more) even with a valid checksum. What only a pbgi database must hold
// (points, nodes, counts that fit the pages) is CheckDatabaseMeta's (tree/verify.h).
absl::StatusOr<DecodedMeta> DecodeMeta(absl::string_view bytes, absl::string_view where);

}  // namespace pbgi::internal

#endif  // PBGI_STORE_META_CODEC_H_
