// PLY reader (binary little- and big-endian, and ASCII) and writer. See pbgi/ply.h.
#include "pbgi/ply.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "absl/strings/strip.h"
#include "pbgi/status.h"

namespace pbgi {
namespace {

enum class PType { kI8, kU8, kI16, kU16, kI32, kU32, kF32, kF64 };

bool ParseType(absl::string_view s, PType* t, int* size) {
  struct E {
    const char* a;
    const char* b;
    PType t;
    int size;
  };
  static const E kTypes[] = {
      {"char", "int8", PType::kI8, 1},      {"uchar", "uint8", PType::kU8, 1},
      {"short", "int16", PType::kI16, 2},   {"ushort", "uint16", PType::kU16, 2},
      {"int", "int32", PType::kI32, 4},     {"uint", "uint32", PType::kU32, 4},
      {"float", "float32", PType::kF32, 4}, {"double", "float64", PType::kF64, 8}};
  for (const E& e : kTypes) {
    if (s == e.a || s == e.b) {
      *t = e.t;
      *size = e.size;
      return true;
    }
  }
  return false;
}

int TypeSize(PType t) {
  switch (t) {
    case PType::kI8:
    case PType::kU8:
      return 1;
    case PType::kI16:
    case PType::kU16:
      return 2;
    case PType::kF64:
      return 8;
    default:
      return 4;
  }
}

// Integer colour types are scaled to 0..1 by their maximum.
double TypeScale(PType t) {
  switch (t) {
    case PType::kU8:
      return 1.0 / 255.0;
    case PType::kU16:
      return 1.0 / 65535.0;
    default:
      return 1.0;
  }
}

const char* TypeName(PType t) {
  static const char* kNames[] = {"char", "uchar", "short", "ushort",
                                 "int",  "uint",  "float", "double"};
  return kNames[static_cast<int>(t)];
}

// Whether an ASCII value is one of the declared type: integers whole and in range (uchar 300 is
// not a colour), floats within float's range (NaN and infinities pass through; the builder
// refuses them).
bool FitsType(double v, PType t) {
  auto whole_in = [&](double lo, double hi) { return v >= lo && v <= hi && std::floor(v) == v; };
  switch (t) {
    case PType::kI8:
      return whole_in(-128, 127);
    case PType::kU8:
      return whole_in(0, 255);
    case PType::kI16:
      return whole_in(-32768, 32767);
    case PType::kU16:
      return whole_in(0, 65535);
    case PType::kI32:
      return whole_in(-2147483648.0, 2147483647.0);
    case PType::kU32:
      return whole_in(0, 4294967295.0);
    case PType::kF32:
      return !std::isfinite(v) || std::abs(v) <= double(std::numeric_limits<float>::max());
    case PType::kF64:
      return true;
  }
  return false;
}

// A value of type `t` at p, its bytes reversed first when `swap` (a big-endian file).
double Decode(const uint8_t* in, PType t, bool swap) {
  uint8_t tmp[8];
  const uint8_t* p = in;
  if (swap) {
    const int n = TypeSize(t);
    for (int i = 0; i < n; ++i) tmp[i] = in[n - 1 - i];
    p = tmp;
  }
  switch (t) {
    case PType::kI8: {
      int8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case PType::kU8:
      return *p;
    case PType::kI16: {
      int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PType::kU16: {
      uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PType::kI32: {
      int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PType::kU32: {
      uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PType::kF32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PType::kF64: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
  }
  return 0;
}

// Surfel fields a property can feed.
enum Field {
  kX,
  kY,
  kZ,
  kNx,
  kNy,
  kNz,
  kRadius,
  kR,
  kG,
  kB,
  kRx,
  kRy,
  kRz,
  kTwoSided,
  kSheet,
  kBackR,
  kBackG,
  kBackB,
  kNumFields,
  kSkip = -1
};

int FieldOf(absl::string_view name) {
  static const std::pair<const char*, int> kNames[] = {{"x", kX},
                                                       {"y", kY},
                                                       {"z", kZ},
                                                       {"nx", kNx},
                                                       {"ny", kNy},
                                                       {"nz", kNz},
                                                       {"radius", kRadius},
                                                       {"r", kR},
                                                       {"g", kG},
                                                       {"b", kB},
                                                       {"red", kR},
                                                       {"green", kG},
                                                       {"blue", kB},
                                                       {"diffuse_red", kR},
                                                       {"diffuse_green", kG},
                                                       {"diffuse_blue", kB},
                                                       {"rx", kRx},
                                                       {"ry", kRy},
                                                       {"rz", kRz},
                                                       {"two_sided", kTwoSided},
                                                       {"sheet", kSheet},
                                                       {"back_r", kBackR},
                                                       {"back_g", kBackG},
                                                       {"back_b", kBackB}};
  for (const auto& [n, f] : kNames) {
    if (name == n) return f;
  }
  return kSkip;
}

struct Property {
  PType type;
  int size;
  int offset;  // binary: byte offset in the record
  int field;   // Field or kSkip
  double scale;
};

// Whether a line's first word is one that a PLY header may hold.
bool IsHeaderKeyword(absl::string_view w) {
  return w == "format" || w == "element" || w == "property" || w == "comment" || w == "obj_info" ||
         w == "end_header";
}

class PlyFileReader final : public PlySource {
 public:
  ~PlyFileReader() override {
    if (file_ != nullptr && file_ != stdin) std::fclose(file_);
  }

  static absl::StatusOr<std::unique_ptr<PlyFileReader>> Open(const std::string& path,
                                                             const PlyReadOptions& options,
                                                             bool header_only) {
    auto src = std::unique_ptr<PlyFileReader>(new PlyFileReader());
    src->path_ = path;
    src->options_ = options;
    src->header_.path = path;
    if (path == "-") {
      // Standard input: read once, front to back (see PlyReadOptions::spill_dir).
      src->path_ = "standard input";
      src->file_ = stdin;
      struct stat st;
      src->seekable_ = fstat(fileno(stdin), &st) == 0 && S_ISREG(st.st_mode);
    } else {
      src->file_ = std::fopen(path.c_str(), "rb");
      if (src->file_ == nullptr) {
        return absl::NotFoundError(
            absl::StrFormat("%s: cannot open: %s", path, std::strerror(errno)));
      }
    }
    PBGI_RETURN_IF_ERROR(src->ReadHeader(header_only));
    if (!header_only && !src->seekable_ && src->KnownBounds().Empty() &&
        !options.spill_dir.empty()) {
      PBGI_RETURN_IF_ERROR(src->SpillBody(options.spill_dir));
    }
    return src;
  }

  const PlyHeader& header() const override { return header_; }

  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    return NextWithReflections(out, {});
  }

  absl::StatusOr<size_t> NextWithReflections(absl::Span<Surfel> out,
                                             absl::Span<glm::vec3> reflections) override {
    if (record_ >= count_ && !end_checked_) {
      end_checked_ = true;
      PBGI_RETURN_IF_ERROR(CheckAsciiEnd());
      PBGI_RETURN_IF_ERROR(CheckStreamEnd());
    }
    if (!ascii_ && all_float_in_order_ && reflections.empty()) return NextBinaryFloats(out);
    size_t n = 0;
    glm::vec3 unused;
    while (n < out.size() && record_ < count_) {
      glm::vec3* r = reflections.empty() ? &unused : &reflections[n];
      if (ascii_) {
        PBGI_RETURN_IF_ERROR(ReadAsciiRecord(&out[n], r));
      } else {
        PBGI_RETURN_IF_ERROR(ReadBinaryRecord(&out[n], r));
      }
      ++record_;
      ++n;
    }
    return n;
  }

  absl::Status Rewind() override {
    if (!seekable_) {
      // A pipe can be "rewound" only to where it already is: its first record.
      if (record_ == 0 && file_pos_ == body_offset_ && buf_len_ == 0) return absl::OkStatus();
      return absl::FailedPreconditionError(absl::StrFormat(
          "%s: cannot read a stream twice: the build needs the bounds of the points first; "
          "give them as `comment pbgi bounds XMIN YMIN ZMIN XMAX YMAX ZMAX` in the header "
          "(pbgi generate and pbgi import write it), or --bounds, or spill the stream to --tmp",
          path_));
    }
    if (std::fseek(file_, body_offset_, SEEK_SET) != 0) {
      return absl::InternalError(
          absl::StrFormat("%s: cannot seek: %s", path_, std::strerror(errno)));
    }
    record_ = 0;
    end_checked_ = false;
    line_ = header_lines_;
    buf_pos_ = buf_len_ = 0;
    file_pos_ = body_offset_;
    return absl::OkStatus();
  }

  int64_t KnownCount() const override { return static_cast<int64_t>(count_); }
  bool HasRadiance() const override { return has_color_; }
  Bounds KnownBounds() const override {
    return options_.bounds.Empty() ? header_.bounds : options_.bounds;
  }

 private:
  PlyFileReader() = default;

  // Copies the rest of a stream (the body and anything after it) to an unlinked file in `dir`
  // and reads from there, so that the builder can read the records twice (docs/format.md,
  // "Streamed input").
  absl::Status SpillBody(const std::string& dir) {
    int fd = open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
    if (fd < 0) {
      std::string tmpl = dir + "/pbgi-stdin-XXXXXX";
      fd = mkostemp(tmpl.data(), O_CLOEXEC);
      if (fd < 0) {
        return absl::InternalError(absl::StrFormat("cannot create a file in '%s' to spill %s: %s",
                                                   dir, path_, std::strerror(errno)));
      }
      unlink(tmpl.c_str());
    }
    std::FILE* spill = fdopen(fd, "w+b");
    if (spill == nullptr) {
      close(fd);
      return absl::InternalError(absl::StrFormat("fdopen: %s", std::strerror(errno)));
    }
    // The body keeps its stream offset (a hole before it), so errors name the stream's offsets.
    if (std::fseek(spill, body_offset_, SEEK_SET) != 0) {
      std::fclose(spill);
      return absl::InternalError(absl::StrFormat("seek in a spill file: %s", std::strerror(errno)));
    }
    std::vector<char> chunk(size_t{1} << 20);
    uint64_t copied = 0;
    for (;;) {
      const size_t r = std::fread(chunk.data(), 1, chunk.size(), file_);
      if (r == 0) break;
      if (std::fwrite(chunk.data(), 1, r, spill) != r) {
        const std::string why = std::strerror(errno);
        std::fclose(spill);
        return absl::InternalError(absl::StrFormat("spilling %s to '%s' failed after %d bytes: %s",
                                                   path_, dir, copied, why));
      }
      copied += r;
    }
    if (std::ferror(file_) || std::fflush(spill) != 0 ||
        std::fseek(spill, body_offset_, SEEK_SET) != 0) {
      const std::string why = std::strerror(errno);
      std::fclose(spill);
      return absl::InternalError(absl::StrFormat("spilling %s: %s", path_, why));
    }
    file_ = spill;
    seekable_ = true;
    header_.spilled_bytes = copied;
    if (!ascii_) PBGI_RETURN_IF_ERROR(CheckBinaryBodySize());
    return absl::OkStatus();
  }

  absl::Status HeaderError(const std::string& what) const {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: PLY header line %d: %s", path_, line_, what));
  }

  // One header line of any length up to kMaxHeaderLine (comments can be long). False at the
  // end of the file before any character.
  bool ReadHeaderLine(std::string* line, bool* too_long) {
    line->clear();
    *too_long = false;
    int c;
    bool any = false;
    while ((c = std::fgetc(file_)) != EOF) {
      any = true;
      ++header_bytes_;
      if (c == '\n') break;
      if (line->size() >= kMaxHeaderLine) {
        *too_long = true;
        return true;
      }
      line->push_back(static_cast<char>(c));
    }
    return any;
  }

  absl::Status ReadHeader(bool header_only) {
    bool in_vertex = false, seen_vertex = false, seen_format = false;
    int elements = 0;
    std::string line;
    std::vector<std::string> names;  // of the vertex properties, parallel to props_
    for (;;) {
      bool too_long = false;
      if (!ReadHeaderLine(&line, &too_long)) {
        line_ = line_ == 0 ? 1 : line_;
        return HeaderError(line_ <= 1 ? "empty file, not a PLY file"
                                      : "the header has no end_header line");
      }
      ++line_;
      if (too_long) {
        return HeaderError(absl::StrFormat(
            "longer than %d bytes (not a PLY header, or a header line without its newline)",
            kMaxHeaderLine));
      }
      while (!line.empty() && (line.back() == '\n' || line.back() == '\r')) line.pop_back();
      std::vector<absl::string_view> tok =
          absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
      if (line_ == 1) {
        if (line != "ply") return HeaderError("not a PLY file (no 'ply' magic)");
        continue;
      }
      if (tok.empty()) continue;
      if (tok[0] == "comment" || tok[0] == "obj_info") {
        const size_t at = line.find(std::string(tok[0])) + tok[0].size();
        header_.comments.push_back(std::string(absl::StripAsciiWhitespace(line.substr(at))));
        if (tok.size() >= 3 && tok[1] == "pbgi" && tok[2] == "bounds") {
          PBGI_RETURN_IF_ERROR(ParseBoundsComment(tok));
        }
        continue;
      }
      if (tok[0] == "end_header") break;
      if (tok[0] == "format") {
        if (tok.size() < 2) return HeaderError("malformed format line");
        if (tok[1] == "ascii") {
          ascii_ = true;
        } else if (tok[1] == "binary_little_endian") {
          ascii_ = false;
        } else if (tok[1] == "binary_big_endian") {
          ascii_ = false;
          swap_ = true;
        } else {
          return HeaderError(absl::StrFormat(
              "unsupported format '%s' (ascii, binary_little_endian or binary_big_endian)",
              tok[1]));
        }
        header_.format = std::string(tok[1]);
        seen_format = true;
      } else if (tok[0] == "element") {
        if (tok.size() != 3) return HeaderError("malformed element line");
        ++elements;
        in_vertex = tok[1] == "vertex";
        if (in_vertex) {
          if (elements != 1) return HeaderError("the vertex element must come first");
          if (!absl::SimpleAtoi(tok[2], &count_)) {
            return HeaderError(absl::StrFormat("bad vertex count '%s'", tok[2]));
          }
          header_.vertex_count = count_;
          seen_vertex = true;
        } else {
          uint64_t n = 0;
          if (!absl::SimpleAtoi(tok[2], &n)) {
            return HeaderError(absl::StrFormat("bad count '%s' of element '%s'", tok[2], tok[1]));
          }
          // Records of later elements follow the vertices: the body may then be longer.
          if (n > 0) later_records_ = true;
          header_.other_elements.push_back({std::string(tok[1]), n});
        }
      } else if (tok[0] == "property") {
        if (!in_vertex) continue;  // properties of later elements: ignored
        if (tok.size() >= 2 && tok[1] == "list") {
          return HeaderError("list properties on vertices are not supported");
        }
        if (tok.size() != 3) return HeaderError("malformed property line");
        Property p;
        if (!ParseType(tok[1], &p.type, &p.size)) {
          return HeaderError(absl::StrFormat("unknown property type '%s'", tok[1]));
        }
        if (props_.size() >= kMaxProperties) {
          return HeaderError(
              absl::StrFormat("more than %d properties on vertices", kMaxProperties));
        }
        p.offset = stride_;
        stride_ += p.size;
        p.field = FieldOf(tok[2]);
        p.scale = (p.field >= kR && p.field <= kB) ? TypeScale(p.type) : 1.0;
        for (const std::string& n : names) {
          if (n == tok[2]) {
            return HeaderError(absl::StrFormat("property '%s' given twice", tok[2]));
          }
        }
        names.push_back(std::string(tok[2]));
        props_.push_back(p);
        header_.vertex_properties.push_back({std::string(tok[2]), std::string(tok[1])});
      } else if (!seen_vertex && !IsHeaderKeyword(tok[0])) {
        // Free text before the elements (e.g. "Created by Blender3D 247 - www.blender.org,
        // source file: ..." without `comment`): nothing a PLY header can mean, so a comment.
        header_.comments.push_back(line);
        header_.notes.push_back(absl::StrFormat(
            "header line %d is free text without the 'comment' keyword; read as a comment", line_));
      } else {
        return HeaderError(absl::StrFormat(
            "unexpected keyword '%s' (a header line is format, element, property, comment, "
            "obj_info or end_header)",
            tok[0]));
      }
    }
    if (!seen_format) return HeaderError("no format line");
    if (!seen_vertex) return HeaderError("no vertex element");
    // Colour: float r g b win over integer red green blue (pbgi's outputs carry both).
    int colour_props[3][2] = {{-1, -1}, {-1, -1}, {-1, -1}};  // [channel][float name?]
    for (size_t i = 0; i < props_.size(); ++i) {
      const int f = props_[i].field;
      if (f >= kR && f <= kB) {
        const bool short_name = names[i].size() == 1;
        int& slot = colour_props[f - kR][short_name ? 1 : 0];
        if (slot >= 0) {
          return HeaderError(absl::StrFormat("colour property '%s' given twice (also '%s')",
                                             names[i], names[size_t(slot)]));
        }
        slot = static_cast<int>(i);
      } else if (f != kSkip) {
        if (have_[f]) {
          return HeaderError(absl::StrFormat("property '%s' given twice", names[i]));
        }
        have_[f] = true;
      }
    }
    const bool short_rgb =
        colour_props[0][1] >= 0 || colour_props[1][1] >= 0 || colour_props[2][1] >= 0;
    for (int c = 0; c < 3; ++c) {
      const int use = colour_props[c][short_rgb ? 1 : 0];
      const int other = colour_props[c][short_rgb ? 0 : 1];
      if (other >= 0) props_[size_t(other)].field = kSkip;
      if (use >= 0) have_[kR + c] = true;
    }
    has_color_ = have_[kR] && have_[kG] && have_[kB];
    if ((have_[kR] || have_[kG] || have_[kB]) && !has_color_) {
      return HeaderError("colour needs all three of r g b (or red green blue)");
    }
    header_.has_color = has_color_;
    header_.has_normals = have_[kNx] && have_[kNy] && have_[kNz];
    header_.has_radius = have_[kRadius];
    header_.has_reflection = have_[kRx] && have_[kRy] && have_[kRz];
    header_.has_two_sided = have_[kTwoSided];
    has_back_ = have_[kBackR] && have_[kBackG] && have_[kBackB];
    if ((have_[kBackR] || have_[kBackG] || have_[kBackB]) && !has_back_) {
      return HeaderError("a back radiance needs all three of back_r back_g back_b");
    }
    header_.has_back_radiance = has_back_;
    if (!header_only) {
      static const char* kRequired[] = {"x", "y", "z", "nx", "ny", "nz", "radius"};
      for (int f = kX; f <= kRadius; ++f) {
        if (have_[f]) continue;
        if (f == kRadius && options_.allow_missing_radius) continue;
        if (f >= kNx && f <= kNz && options_.allow_missing_normals && !have_[kNx] && !have_[kNy] &&
            !have_[kNz]) {
          continue;
        }
        return HeaderError(
            absl::StrFormat("the vertex element has no '%s' property", kRequired[f]));
      }
    }
    // The common layout (PlyWriter's): float x y z nx ny nz radius [r g b] first, in order,
    // anything after them skipped.
    const size_t prefix = has_color_ ? 10 : 7;
    all_float_in_order_ = !swap_ && props_.size() >= prefix && have_[kRadius];
    for (size_t i = 0; i < props_.size() && all_float_in_order_; ++i) {
      all_float_in_order_ =
          i < prefix ? props_[i].type == PType::kF32 && props_[i].field == static_cast<int>(i)
                     : props_[i].field == kSkip;
    }
    float_prefix_bytes_ = prefix * sizeof(float);
    header_lines_ = line_;
    // Counted rather than asked (ftell), which a pipe cannot answer.
    body_offset_ = static_cast<long>(header_bytes_);
    file_pos_ = body_offset_;
    if (!header_only) {
      // Room for at least two records, whatever their size.
      buf_.resize(std::max<size_t>(size_t{1} << 20, 2 * static_cast<size_t>(stride_)));
      if (!ascii_) PBGI_RETURN_IF_ERROR(CheckBinaryBodySize());
    }
    return absl::OkStatus();
  }

  // A binary body is exactly count x stride bytes when the vertices are all the file holds:
  // anything else means a wrong count (records silently dropped, or read past) or a body that
  // is not binary at all (an ASCII body under a binary header read as floats).
  absl::Status CheckBinaryBodySize() const {
    struct stat st;
    if (fstat(fileno(file_), &st) != 0 || !S_ISREG(st.st_mode)) return absl::OkStatus();
    const uint64_t body = static_cast<uint64_t>(st.st_size) - static_cast<uint64_t>(body_offset_);
    const uint64_t want = count_ * static_cast<uint64_t>(stride_);
    // Numbers, signs, points, exponents and white space only: text, not floats.
    char peek[64];
    const ssize_t got = pread(fileno(file_), peek, sizeof(peek), body_offset_);
    bool text = got > 0;
    for (ssize_t i = 0; i < got && text; ++i) {
      text = std::strchr("0123456789+-.eE \t\r\n", peek[i]) != nullptr && peek[i] != '\0';
    }
    const std::string hint =
        text ? absl::StrFormat(" (the body looks like ASCII text: it is not %s)", header_.format)
             : std::string();
    if (stride_ > 0 && count_ > body / static_cast<uint64_t>(stride_)) {
      return absl::DataLossError(absl::StrFormat(
          "%s: truncated at byte offset %d, in record %d of %d (each record is %d bytes)%s", path_,
          st.st_size, body / static_cast<uint64_t>(stride_), count_, stride_, hint));
    }
    if (body != want && !later_records_) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: the header says %d vertices of %d bytes (%d bytes), but the body after byte offset "
          "%d holds %d bytes%s: a wrong vertex count, or a body that is not %s%s",
          path_, count_, stride_, want, body_offset_, body,
          body > want ? absl::StrFormat(" (%d more)", body - want) : std::string(), header_.format,
          hint));
    }
    return absl::OkStatus();
  }

  // A binary stream cannot be measured up front (CheckBinaryBodySize): after its last vertex,
  // nothing may follow when the header declares nothing else.
  absl::Status CheckStreamEnd() {
    if (ascii_ || seekable_ || later_records_) return absl::OkStatus();
    if (buf_len_ - buf_pos_ > 0 || Fill(1) > 0) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: the header says %d vertices of %d bytes, but more bytes follow at byte offset %d: "
          "a wrong vertex count, or a body that is not %s",
          path_, count_, stride_, file_pos_, header_.format));
    }
    return absl::OkStatus();
  }

  // After the last vertex of an ASCII file that holds nothing else, only blank lines may
  // follow: more records mean the header's count is too small.
  absl::Status CheckAsciiEnd() {
    if (!ascii_ || later_records_) return absl::OkStatus();
    for (;;) {
      if (buf_pos_ == buf_len_ && Fill(1) == 0) return absl::OkStatus();
      const char c = buf_[buf_pos_];
      if (c != ' ' && c != '\t' && c != '\r' && c != '\n') {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s: the header says %d vertices but more records follow at byte offset %d (line "
            "%d): the vertex count is wrong",
            path_, count_, file_pos_, line_ + 1));
      }
      if (c == '\n') ++line_;
      ++buf_pos_;
      ++file_pos_;
    }
  }

  // `comment pbgi bounds XMIN YMIN ZMIN XMAX YMAX ZMAX` (PlyHeader::bounds).
  absl::Status ParseBoundsComment(const std::vector<absl::string_view>& tok) {
    float v[6];
    bool ok = tok.size() == 9;
    for (int i = 0; ok && i < 6; ++i)
      ok = absl::SimpleAtof(tok[size_t(3 + i)], &v[i]) && std::isfinite(v[i]);
    Bounds b;
    if (ok) {
      b.lo = glm::vec3(v[0], v[1], v[2]);
      b.hi = glm::vec3(v[3], v[4], v[5]);
      ok = !b.Empty();
    }
    if (!ok) {
      return HeaderError(
          "malformed bounds comment (want `comment pbgi bounds XMIN YMIN ZMIN XMAX YMAX ZMAX`, "
          "six finite numbers, each minimum at most its maximum)");
    }
    header_.bounds = b;
    return absl::OkStatus();
  }

  // Ensures `want` bytes are buffered; returns how many are.
  size_t Fill(size_t want) {
    if (buf_len_ - buf_pos_ >= want) return buf_len_ - buf_pos_;
    std::memmove(buf_.data(), buf_.data() + buf_pos_, buf_len_ - buf_pos_);
    buf_len_ -= buf_pos_;
    buf_pos_ = 0;
    while (buf_len_ < want) {
      size_t r = std::fread(buf_.data() + buf_len_, 1, buf_.size() - buf_len_, file_);
      if (r == 0) break;
      buf_len_ += r;
    }
    return buf_len_;
  }

  void Assign(Surfel* s, glm::vec3* reflection, const double v[kNumFields]) {
    s->position = glm::vec3(v[kX], v[kY], v[kZ]);
    s->normal = glm::vec3(v[kNx], v[kNy], v[kNz]);
    s->radius = have_[kRadius] ? static_cast<float>(v[kRadius]) : options_.uniform_radius;
    s->radiance = has_color_ ? glm::vec3(v[kR], v[kG], v[kB]) : glm::vec3(0.0f);
    *reflection = glm::vec3(v[kRx], v[kRy], v[kRz]);
    s->two_sided = v[kTwoSided] != 0.0;
    // A sheet tag means something on a two-sided surfel only (Surfel::sheet).
    s->sheet = s->two_sided && v[kSheet] >= 1.0 && v[kSheet] <= 255.0
                   ? static_cast<uint8_t>(v[kSheet])
                   : uint8_t{0};
    // Without back_r back_g back_b a two-sided surfel shows its radiance on both sides.
    s->back_radiance = !s->two_sided ? glm::vec3(0.0f)
                       : has_back_   ? glm::vec3(v[kBackR], v[kBackG], v[kBackB])
                                     : s->radiance;
  }

  absl::Status ReadBinaryRecord(Surfel* s, glm::vec3* reflection) {
    if (Fill(stride_) < static_cast<size_t>(stride_)) {
      const long offset = file_pos_ + static_cast<long>(buf_len_);
      return absl::DataLossError(absl::StrFormat(
          "%s: truncated at byte offset %d, in record %d of %d (each record is %d bytes)", path_,
          offset, record_, count_, stride_));
    }
    const uint8_t* p = reinterpret_cast<const uint8_t*>(buf_.data() + buf_pos_);
    double v[kNumFields] = {};
    for (const Property& q : props_) {
      if (q.field != kSkip) v[q.field] = Decode(p + q.offset, q.type, swap_) * q.scale;
    }
    Assign(s, reflection, v);
    buf_pos_ += stride_;
    file_pos_ += stride_;
    return absl::OkStatus();
  }

  // The common layout (PlyWriter's, float x y z nx ny nz radius [r g b], then anything but
  // two_sided): whole buffered runs of records at a time, one copy per surfel. A Surfel starts
  // with 10 packed floats in file order.
  absl::StatusOr<size_t> NextBinaryFloats(absl::Span<Surfel> out) {
    static_assert(offsetof(Surfel, radiance) + sizeof(glm::vec3) == 10 * sizeof(float));
    const size_t stride = static_cast<size_t>(stride_);
    size_t n = 0;
    while (n < out.size() && record_ < count_) {
      if (Fill(stride) < stride) {
        glm::vec3 unused;
        PBGI_RETURN_IF_ERROR(ReadBinaryRecord(&out[n], &unused));  // names the truncation
      }
      const size_t k = static_cast<size_t>(
          std::min<uint64_t>({out.size() - n, count_ - record_, (buf_len_ - buf_pos_) / stride}));
      const char* p = buf_.data() + buf_pos_;
      for (size_t j = 0; j < k; ++j) {
        Surfel& s = out[n + j];
        std::memcpy(static_cast<void*>(&s), p + j * stride, float_prefix_bytes_);
        if (!has_color_) s.radiance = glm::vec3(0.0f);
        s.two_sided = false;
        s.sheet = 0;
        s.back_radiance = glm::vec3(0.0f);
      }
      buf_pos_ += k * stride;
      file_pos_ += static_cast<long>(k * stride);
      record_ += k;
      n += k;
    }
    return n;
  }

  absl::Status ReadAsciiRecord(Surfel* s, glm::vec3* reflection) {
    // One record per line; blank lines are skipped.
    std::string line;
    for (;;) {
      line.clear();
      bool got = false;
      for (;;) {
        if (buf_pos_ == buf_len_ && Fill(1) == 0) break;
        const char* start = buf_.data() + buf_pos_;
        const char* nl = static_cast<const char*>(std::memchr(start, '\n', buf_len_ - buf_pos_));
        size_t n = nl ? static_cast<size_t>(nl - start) : buf_len_ - buf_pos_;
        line.append(start, n);
        got = true;
        buf_pos_ += n + (nl ? 1 : 0);
        file_pos_ += static_cast<long>(n + (nl ? 1 : 0));
        if (nl) break;
      }
      if (!got) {
        return absl::DataLossError(
            absl::StrFormat("%s: the file ends at byte offset %d after %d of %d records", path_,
                            file_pos_, record_, count_));
      }
      ++line_;
      if (line.find_first_not_of(" \t\r") != std::string::npos) break;
    }
    std::vector<absl::string_view> tok =
        absl::StrSplit(line, absl::ByAnyChar(" \t\r"), absl::SkipEmpty());
    if (tok.size() != props_.size()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: line %d (record %d): expected %d values, found %d", path_, line_,
                          record_, props_.size(), tok.size()));
    }
    double v[kNumFields] = {};
    for (size_t i = 0; i < props_.size(); ++i) {
      const Property& q = props_[i];
      double d;
      if (!absl::SimpleAtod(tok[i], &d)) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s: line %d (record %d): '%s' is not a number", path_, line_, record_, tok[i]));
      }
      if (!FitsType(d, q.type)) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s: line %d (record %d): '%s' is not a value of the property's type %s", path_, line_,
            record_, tok[i], TypeName(q.type)));
      }
      if (q.field != kSkip) v[q.field] = d * q.scale;
    }
    Assign(s, reflection, v);
    return absl::OkStatus();
  }

  static constexpr size_t kMaxHeaderLine = size_t{1} << 20;
  static constexpr size_t kMaxProperties = 4096;

  std::string path_;
  PlyReadOptions options_;
  PlyHeader header_;
  std::FILE* file_ = nullptr;
  bool ascii_ = false;
  bool swap_ = false;           // binary_big_endian
  bool later_records_ = false;  // elements after the vertices hold records
  bool end_checked_ = false;
  bool has_color_ = false;
  bool all_float_in_order_ = false;
  size_t float_prefix_bytes_ = 0;
  bool have_[kNumFields] = {};
  bool has_back_ = false;
  std::vector<Property> props_;
  int stride_ = 0;
  uint64_t count_ = 0;
  uint64_t record_ = 0;
  int line_ = 0;
  int header_lines_ = 0;
  long body_offset_ = 0;
  uint64_t header_bytes_ = 0;  // bytes of the header read so far
  bool seekable_ = true;       // false for a pipe (until spilled)
  long file_pos_ = 0;          // file offset of buf_[buf_pos_]
  std::vector<char> buf_;
  size_t buf_pos_ = 0, buf_len_ = 0;
};
constexpr int kCountDigits = 20;

float Srgb(float v) {
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

}  // namespace

uint8_t ToneMap8(float linear) {
  float v = std::isfinite(linear) ? std::max(0.0f, linear) : 0.0f;
  v = v / (1.0f + v);
  return static_cast<uint8_t>(std::lround(std::clamp(Srgb(v), 0.0f, 1.0f) * 255.0f));
}

std::map<std::string, std::string> PlyHeader::Provenance() const {
  std::map<std::string, std::string> out;
  for (const std::string& c : comments) {
    std::vector<absl::string_view> tok =
        absl::StrSplit(c, absl::MaxSplits(' ', 2), absl::SkipEmpty());
    if (tok.size() == 3 && tok[0] == "pbgi") out[std::string(tok[1])] = std::string(tok[2]);
  }
  return out;
}

uint64_t PlyHeader::FaceCount() const {
  uint64_t n = 0;
  for (const auto& [name, count] : other_elements) {
    if (name == "face") n += count;
  }
  return n;
}

absl::StatusOr<std::unique_ptr<PlySource>> OpenPlyFile(const std::string& path,
                                                       const PlyReadOptions& options) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyFileReader> r,
                        PlyFileReader::Open(path, options, /*header_only=*/false));
  return std::unique_ptr<PlySource>(std::move(r));
}

absl::StatusOr<std::unique_ptr<SurfelSource>> OpenPly(const std::string& path) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyFileReader> r,
                        PlyFileReader::Open(path, PlyReadOptions{}, /*header_only=*/false));
  return std::unique_ptr<SurfelSource>(std::move(r));
}

absl::StatusOr<PlyHeader> ReadPlyHeader(const std::string& path) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyFileReader> r,
                        PlyFileReader::Open(path, PlyReadOptions{}, /*header_only=*/true));
  return r->header();
}

absl::StatusOr<std::unique_ptr<PlyWriter>> PlyWriter::Create(const std::string& path,
                                                             const PlyWriterOptions& options) {
  auto w = std::unique_ptr<PlyWriter>(new PlyWriter());
  w->path_ = path;
  w->options_ = options;
  if (path == "-") {
    if (options.vertex_count < 0) {
      return absl::InvalidArgumentError(
          "a PLY written to standard output needs its vertex count in advance");
    }
    w->tmp_path_ = "standard output";
    w->file_ = stdout;
  } else {
    // Written beside the output and renamed over it by Close(): a failed or interrupted write
    // leaves the previous file as it was.
    w->tmp_path_ = absl::StrFormat("%s.tmp-%d", path, getpid());
    w->file_ = std::fopen(w->tmp_path_.c_str(), "wb");
    if (w->file_ == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: cannot create: %s", w->tmp_path_, std::strerror(errno)));
    }
  }
  std::string h = absl::StrFormat("ply\nformat %s 1.0\ncomment pbgi surfels\n",
                                  options.ascii ? "ascii" : "binary_little_endian");
  if (!options.bounds.Empty()) {
    // %.9g round-trips every float.
    const Bounds& b = options.bounds;
    absl::StrAppendFormat(&h, "comment pbgi bounds %.9g %.9g %.9g %.9g %.9g %.9g\n", b.lo.x, b.lo.y,
                          b.lo.z, b.hi.x, b.hi.y, b.hi.z);
  }
  for (const std::string& c : options.comments) {
    // One line each: a newline would end the comment and start a header line of its own.
    std::string line = c;
    std::replace(line.begin(), line.end(), '\n', ' ');
    std::replace(line.begin(), line.end(), '\r', ' ');
    absl::StrAppend(&h, "comment ", line, "\n");
  }
  h += "element vertex ";
  w->count_offset_ = static_cast<long>(h.size());
  h += options.vertex_count >= 0 ? absl::StrFormat("%0*d\n", kCountDigits, options.vertex_count)
                                 : std::string(kCountDigits, '0') + "\n";
  for (const char* p : {"x", "y", "z", "nx", "ny", "nz", "radius"}) {
    absl::StrAppend(&h, "property float ", p, "\n");
  }
  if (options.radiance) h += "property float r\nproperty float g\nproperty float b\n";
  for (const std::string& e : options.extra) absl::StrAppend(&h, "property float ", e, "\n");
  w->colors_ = options.colors == PlyColors::kGiven ||
               (options.colors == PlyColors::kRadiance && options.radiance);
  if (w->colors_) h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (options.two_sided) h += "property uchar two_sided\nproperty uchar sheet\n";
  if (options.two_sided && options.radiance) {
    h += "property float back_r\nproperty float back_g\nproperty float back_b\n";
  }
  h += "end_header\n";
  if (std::fwrite(h.data(), 1, h.size(), w->file_) != h.size()) {
    return absl::InternalError(
        absl::StrFormat("%s: write failed: %s", w->tmp_path_, std::strerror(errno)));
  }
  return w;
}

PlyWriter::~PlyWriter() {
  if (file_ == stdout) {
    std::fflush(stdout);  // a short stream: the reader's count check names it
  } else if (file_ != nullptr) {
    std::fclose(file_);
    std::remove(tmp_path_.c_str());
  }
}

absl::Status PlyWriter::Write(absl::Span<const Surfel> surfels, absl::Span<const float> extra,
                              absl::Span<const uint8_t> rgb8) {
  if (file_ == nullptr) return absl::FailedPreconditionError(path_ + ": writer is closed");
  const size_t ne = options_.extra.size();
  const bool given = options_.colors == PlyColors::kGiven;
  if (extra.size() != ne * surfels.size() || rgb8.size() != (given ? 3 * surfels.size() : 0)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: %d surfels need %d extra values and %d colour bytes, got %d and %d",
                        path_, surfels.size(), ne * surfels.size(), given ? 3 * surfels.size() : 0,
                        extra.size(), rgb8.size()));
  }
  buf_.clear();
  std::vector<float> v;
  for (size_t i = 0; i < surfels.size(); ++i) {
    const Surfel& s = surfels[i];
    v.assign(
        {s.position.x, s.position.y, s.position.z, s.normal.x, s.normal.y, s.normal.z, s.radius});
    if (options_.radiance) v.insert(v.end(), {s.radiance.x, s.radiance.y, s.radiance.z});
    v.insert(v.end(), extra.begin() + i * ne, extra.begin() + (i + 1) * ne);
    uint8_t c[3] = {0, 0, 0};
    if (colors_) {
      for (int k = 0; k < 3; ++k) c[k] = given ? rgb8[3 * i + k] : ToneMap8(s.radiance[k]);
    }
    if (options_.ascii) {
      for (size_t k = 0; k < v.size(); ++k) {
        // %.9g round-trips every float exactly.
        if (k > 0) buf_ += ' ';
        absl::StrAppendFormat(&buf_, "%.9g", v[k]);
      }
      if (colors_) absl::StrAppendFormat(&buf_, " %d %d %d", c[0], c[1], c[2]);
      if (options_.two_sided) absl::StrAppend(&buf_, s.two_sided ? " 1 " : " 0 ", s.sheet);
      if (options_.two_sided && options_.radiance) {
        const glm::vec3 b = s.two_sided ? s.back_radiance : glm::vec3(0.0f);
        absl::StrAppendFormat(&buf_, " %.9g %.9g %.9g", b.x, b.y, b.z);
      }
      buf_ += '\n';
    } else {
      buf_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(float));
      if (colors_) buf_.append(reinterpret_cast<const char*>(c), 3);
      if (options_.two_sided) {
        buf_ += static_cast<char>(s.two_sided ? 1 : 0);
        buf_ += static_cast<char>(s.sheet);
        if (options_.radiance) {
          const glm::vec3 b = s.two_sided ? s.back_radiance : glm::vec3(0.0f);
          buf_.append(reinterpret_cast<const char*>(&b), sizeof b);
        }
      }
    }
  }
  if (std::fwrite(buf_.data(), 1, buf_.size(), file_) != buf_.size()) {
    return absl::InternalError(absl::StrFormat("%s: write failed after %d surfels: %s", tmp_path_,
                                               count_, std::strerror(errno)));
  }
  count_ += surfels.size();
  return absl::OkStatus();
}

absl::Status PlyWriter::Close() {
  if (file_ == nullptr) return absl::OkStatus();
  std::FILE* f = file_;
  file_ = nullptr;
  if (options_.vertex_count >= 0 && count_ != uint64_t(options_.vertex_count)) {
    if (f != stdout) {
      std::fclose(f);
      std::remove(tmp_path_.c_str());
    }
    return absl::InternalError(absl::StrFormat("%s: %d surfels written, the header promised %d",
                                               tmp_path_, count_, options_.vertex_count));
  }
  if (f == stdout) {
    if (std::fflush(f) != 0) {
      return absl::InternalError(
          absl::StrFormat("writing standard output failed: %s", std::strerror(errno)));
    }
    return absl::OkStatus();
  }
  const std::string digits = absl::StrFormat("%0*d", kCountDigits, count_);
  bool ok = std::fflush(f) == 0 && std::fseek(f, count_offset_, SEEK_SET) == 0 &&
            std::fwrite(digits.data(), 1, digits.size(), f) == digits.size() &&
            std::fflush(f) == 0 && fsync(fileno(f)) == 0;
  ok = (std::fclose(f) == 0) && ok;
  if (!ok) {
    const std::string why = std::strerror(errno);
    std::remove(tmp_path_.c_str());
    return absl::InternalError(
        absl::StrFormat("%s: finishing the file failed: %s", tmp_path_, why));
  }
  if (std::rename(tmp_path_.c_str(), path_.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    std::remove(tmp_path_.c_str());
    return absl::InternalError(
        absl::StrFormat("cannot rename %s to %s: %s", tmp_path_, path_, why));
  }
  return absl::OkStatus();
}

}  // namespace pbgi
