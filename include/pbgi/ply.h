// PLY point files in and out (binary little-endian and ASCII), streamed: never loaded whole.
//
// A surfel is one `vertex` element with properties x y z nx ny nz radius (any numeric type) and
// optionally radiance, either as floats `r g b` or as integers `red green blue` (0..255 for uchar,
// scaled to 0..1). Other properties are skipped; the vertex element must come first; elements
// after it are ignored. Big-endian files and list properties on vertices are refused.
//
// Errors name the file and the record number (counting from 0), the line (ASCII) or the byte
// offset (binary, truncated files). Values are not validated here: the builder refuses or skips
// NaN/Inf, zero normals and radii <= 0 (BuildOptions::skip_invalid).
//
// Thread safety: a PLY source or writer belongs to one thread.
#ifndef PBGI_PLY_H_
#define PBGI_PLY_H_

#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/surfel.h"

namespace pbgi {

// Opens `path` and reads its header. The source's KnownCount() is the header's vertex count and
// HasRadiance() tells whether the file has colour properties (surfels without get zero radiance).
absl::StatusOr<std::unique_ptr<SurfelSource>> OpenPly(const std::string& path);

struct PlyWriterOptions {
  bool ascii = false;    // default: binary little-endian
  bool radiance = true;  // write float r g b properties
};

// Streams surfels to a PLY file with float properties x y z nx ny nz radius [r g b]. The vertex
// count is patched into the header by Close(), so the count need not be known in advance.
// REQUIRES: Close() before destruction to learn about errors (the destructor closes silently).
class PlyWriter {
 public:
  static absl::StatusOr<std::unique_ptr<PlyWriter>> Create(const std::string& path,
                                                           const PlyWriterOptions& options = {});
  ~PlyWriter();
  PlyWriter(const PlyWriter&) = delete;
  PlyWriter& operator=(const PlyWriter&) = delete;

  absl::Status Write(absl::Span<const Surfel> surfels);
  absl::Status Write(const Surfel& s) { return Write(absl::Span<const Surfel>(&s, 1)); }
  // Writes the final vertex count into the header and closes the file.
  absl::Status Close();
  uint64_t count() const { return count_; }

 private:
  PlyWriter() = default;
  std::string path_;
  PlyWriterOptions options_;
  std::FILE* file_ = nullptr;
  long count_offset_ = 0;  // where the zero-padded vertex count sits in the header
  uint64_t count_ = 0;
  std::string buf_;
};

}  // namespace pbgi

#endif  // PBGI_PLY_H_
