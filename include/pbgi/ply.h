// PLY point files in and out (binary little- and big-endian, and ASCII), streamed: never loaded
// whole.
//
// A surfel is one `vertex` element with properties x y z nx ny nz radius (any numeric type) and
// optionally radiance, either as floats `r g b` or as integers `red green blue` (0..255 for uchar,
// scaled to 0..1; when a file has both, as pbgi's own outputs do, the floats are read). A
// receiver may also carry its reflection direction (the centre of the glossy lobe) as `rx ry rz`.
// A surfel is two-sided (Surfel::two_sided) when it has a nonzero `two_sided` property (any
// numeric type); files without one hold one-sided surfels. A two-sided surfel's `sheet`
// property (1-255) is its Surfel::sheet; absent, out of range or on a one-sided surfel, 0. Its
// `back_r back_g back_b` are its Surfel::back_radiance; absent, its radiance (both sides alike).
// Files from scanners and point tools (Open3D, PCL) often lack `radius`, or normals:
// PlyReadOptions says whether to accept them (the builder then estimates what is missing, see
// BuildOptions::estimate). Other properties are skipped; the vertex element must come first;
// elements after it are ignored; list properties on vertices are refused. A header line that
// starts with no PLY keyword (some exporters write free text without `comment`) is kept as a
// comment and noted in PlyHeader::notes.
//
// Errors name the file and the record number (counting from 0), the line (ASCII) or the byte
// offset (binary, truncated files). Values are not validated here: the builder refuses or skips
// NaN/Inf, zero normals and radii <= 0 (BuildOptions::skip_invalid).
//
// Outputs are written beside their path (`PATH.tmp-PID`) and renamed over it by Close(): a
// failed or interrupted write never replaces a previous file with a partial one.
//
// Thread safety: a PLY source or writer belongs to one thread.
#ifndef PBGI_PLY_H_
#define PBGI_PLY_H_

#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/surfel.h"

namespace pbgi {

// What a PLY file's header says.
struct PlyHeader {
  struct Property {
    std::string name;
    std::string type;  // as written: float, uchar, float32, ...
  };
  std::string path;
  std::string format;  // "ascii", "binary_little_endian" or "binary_big_endian"
  uint64_t vertex_count = 0;
  std::vector<Property> vertex_properties;
  // Elements after the vertices (faces, edges, ...) and their record counts.
  std::vector<std::pair<std::string, uint64_t>> other_elements;
  std::vector<std::string> comments;  // `comment` and `obj_info` lines, and free text
  std::vector<std::string> notes;     // what the reader tolerated, one line each
  bool has_normals = false;
  bool has_radius = false;
  bool has_color = false;
  bool has_reflection = false;     // rx ry rz
  bool has_two_sided = false;      // two_sided
  bool has_back_radiance = false;  // back_r back_g back_b
  // From a `comment pbgi bounds XMIN YMIN ZMIN XMAX YMAX ZMAX` line (what pbgi generate and
  // pbgi import write: the box of the sampled triangles, which holds every point); empty when
  // the header has none. The source's KnownBounds(), so the builder needs no bounds pass.
  Bounds bounds;
  // Standard input copied to PlyReadOptions::spill_dir (0: not spilled).
  uint64_t spilled_bytes = 0;
  // Comments of the form `pbgi KEY VALUE` (what pbgi's own writers record about where the
  // points came from: the scene, its seed, ...).
  std::map<std::string, std::string> Provenance() const;
  // Faces (an element "face" with records): a mesh, not a point cloud.
  uint64_t FaceCount() const;
};

struct PlyReadOptions {
  // Accept vertices without `radius` (the surfels then have radius `uniform_radius`, 0 when it
  // is 0: the builder estimates it) or without normals (zero normals: the builder estimates
  // them). Otherwise such a file is refused, naming the missing property.
  bool allow_missing_radius = false;
  bool allow_missing_normals = false;
  float uniform_radius = 0.0f;
  // When not empty: the source's KnownBounds() instead of the header's (`pbgi build --bounds`).
  // The builder refuses points outside them.
  Bounds bounds;
  // Path "-" reads standard input, which can be read only once. When the bounds are known (the
  // header's or `bounds`), the builder needs only one pass and nothing is spilled. Otherwise,
  // when this is a directory, the stream's body is first copied to an unlinked file there
  // (about the size of the PLY) and read from it; when empty, Rewind() after the first record
  // fails (naming the ways out).
  std::string spill_dir;
};

// A SurfelSource over a PLY file, with its header and the receivers' reflection directions.
class PlySource : public SurfelSource {
 public:
  virtual const PlyHeader& header() const = 0;
  // Like Next(), and also the reflection direction of each point (rx ry rz; zero when the file
  // has none). REQUIRES: reflections.size() >= out.size().
  virtual absl::StatusOr<size_t> NextWithReflections(absl::Span<Surfel> out,
                                                     absl::Span<glm::vec3> reflections) = 0;
};

// Opens `path` ("-": standard input, see PlyReadOptions::spill_dir) and reads its header. The
// source's KnownCount() is the header's vertex count and HasRadiance() tells whether the file has
// colour properties (surfels without get zero radiance).
absl::StatusOr<std::unique_ptr<PlySource>> OpenPlyFile(const std::string& path,
                                                       const PlyReadOptions& options = {});
// The same as a plain SurfelSource with the default options (x y z nx ny nz radius required).
absl::StatusOr<std::unique_ptr<SurfelSource>> OpenPly(const std::string& path);
// Reads only the header (any vertex properties: nothing is required).
absl::StatusOr<PlyHeader> ReadPlyHeader(const std::string& path);

// What the `red green blue` uchar properties that point viewers (Open3D, CloudCompare, MeshLab)
// show hold. A reader takes them as radiance when a file has no float r g b.
enum class PlyColors {
  kNone,
  kRadiance,  // the radiance tone-mapped (v / (1 + v), sRGB); none when radiance is not written
  kGiven,     // the colours given to Write() (e.g. shading results)
};

struct PlyWriterOptions {
  bool ascii = false;    // default: binary little-endian
  bool radiance = true;  // write float r g b properties
  PlyColors colors = PlyColors::kRadiance;
  // Float properties written after the surfel's own, one value each per surfel (Write's
  // `extra`): e.g. what shading computed.
  std::vector<std::string> extra;
  // Header comments, one line each (e.g. "pbgi scene.name cornell": see PlyHeader::Provenance).
  std::vector<std::string> comments;
  // Write each surfel's Surfel::two_sided and Surfel::sheet as properties `uchar two_sided` (0
  // or 1) and `uchar sheet`, and with `radiance` its Surfel::back_radiance as the last, `float
  // back_r back_g back_b` (0 on one-sided surfels).
  bool two_sided = false;
  // When not empty: a `comment pbgi bounds ...` line (PlyHeader::bounds), floats written exactly.
  // REQUIRES: every written position inside (the writer does not check; the builder does).
  Bounds bounds;
  // The number of surfels that will be written, when known in advance (>= 0): it goes into the
  // header at once and Close() checks it. Required for path "-" (standard output), which cannot
  // be patched afterwards.
  int64_t vertex_count = -1;
};

// Streams surfels to a PLY file with float properties x y z nx ny nz radius [r g b] [extra...]
// [uchar red green blue] [uchar two_sided sheet [float back_r back_g back_b]]. The vertex count is
// patched into the header by Close(), so the count need not be known in advance, except for path
// "-": standard output, written in place, with PlyWriterOptions::vertex_count. REQUIRES: Close() to
// finish the file; a writer destroyed without Close() removes its temporary file and leaves `path`
// as it was.
class PlyWriter {
 public:
  static absl::StatusOr<std::unique_ptr<PlyWriter>> Create(const std::string& path,
                                                           const PlyWriterOptions& options = {});
  ~PlyWriter();
  PlyWriter(const PlyWriter&) = delete;
  PlyWriter& operator=(const PlyWriter&) = delete;

  // `extra`: options.extra.size() values per surfel, surfel by surfel; `rgb8`: 3 bytes per
  // surfel with PlyColors::kGiven, else empty.
  absl::Status Write(absl::Span<const Surfel> surfels, absl::Span<const float> extra = {},
                     absl::Span<const uint8_t> rgb8 = {});
  absl::Status Write(const Surfel& s) { return Write(absl::Span<const Surfel>(&s, 1)); }
  // Writes the final vertex count into the header, closes the file and renames it over `path`.
  absl::Status Close();
  uint64_t count() const { return count_; }

 private:
  PlyWriter() = default;
  std::string path_;
  std::string tmp_path_;
  PlyWriterOptions options_;
  std::FILE* file_ = nullptr;
  long count_offset_ = 0;  // where the zero-padded vertex count sits in the header
  uint64_t count_ = 0;
  bool colors_ = false;  // red green blue are written
  std::string buf_;
};

// The 8-bit sRGB value of a linear radiance after the tone curve v / (1 + v) (what PNG outputs
// and the PLY writers' `red green blue` show).
uint8_t ToneMap8(float linear);

}  // namespace pbgi

#endif  // PBGI_PLY_H_
