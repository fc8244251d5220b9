// PLY reader (binary little-endian and ASCII) and writer. See pbgi/ply.h.
#include "pbgi/ply.h"

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
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
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
  static const char* kNames[] = {"char", "uchar", "short", "ushort", "int", "uint", "float",
                                 "double"};
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

double Decode(const uint8_t* p, PType t) {
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
enum Field { kX, kY, kZ, kNx, kNy, kNz, kRadius, kR, kG, kB, kNumFields, kSkip = -1 };

int FieldOf(absl::string_view name) {
  static const std::pair<const char*, int> kNames[] = {
      {"x", kX},           {"y", kY},           {"z", kZ},
      {"nx", kNx},         {"ny", kNy},         {"nz", kNz},
      {"radius", kRadius}, {"r", kR},           {"g", kG},
      {"b", kB},           {"red", kR},         {"green", kG},
      {"blue", kB},        {"diffuse_red", kR}, {"diffuse_green", kG},
      {"diffuse_blue", kB}};
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

class PlySource final : public SurfelSource {
 public:
  ~PlySource() override {
    if (file_ != nullptr) std::fclose(file_);
  }

  static absl::StatusOr<std::unique_ptr<SurfelSource>> Open(const std::string& path) {
    auto src = std::unique_ptr<PlySource>(new PlySource());
    src->path_ = path;
    src->file_ = std::fopen(path.c_str(), "rb");
    if (src->file_ == nullptr) {
      return absl::NotFoundError(
          absl::StrFormat("%s: cannot open: %s", path, std::strerror(errno)));
    }
    PBGI_RETURN_IF_ERROR(src->ReadHeader());
    return std::unique_ptr<SurfelSource>(std::move(src));
  }

  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    if (record_ >= count_ && !end_checked_) {
      end_checked_ = true;
      PBGI_RETURN_IF_ERROR(CheckAsciiEnd());
    }
    if (!ascii_ && all_float_in_order_) return NextBinaryFloats(out);
    size_t n = 0;
    while (n < out.size() && record_ < count_) {
      if (ascii_) {
        PBGI_RETURN_IF_ERROR(ReadAsciiRecord(&out[n]));
      } else {
        PBGI_RETURN_IF_ERROR(ReadBinaryRecord(&out[n]));
      }
      ++record_;
      ++n;
    }
    return n;
  }

  absl::Status Rewind() override {
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

 private:
  PlySource() = default;

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
      if (c == '\n') break;
      if (line->size() >= kMaxHeaderLine) {
        *too_long = true;
        return true;
      }
      line->push_back(static_cast<char>(c));
    }
    return any;
  }

  absl::Status ReadHeader() {
    bool in_vertex = false, seen_vertex = false, seen_format = false;
    int elements = 0;
    std::string line;
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
      if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
      if (tok[0] == "end_header") break;
      if (tok[0] == "format") {
        if (tok.size() < 2) return HeaderError("malformed format line");
        if (tok[1] == "ascii") {
          ascii_ = true;
        } else if (tok[1] == "binary_little_endian") {
          ascii_ = false;
        } else {
          return HeaderError(absl::StrFormat("unsupported format '%s'", tok[1]));
        }
        seen_format = true;
      } else if (tok[0] == "element") {
        if (tok.size() != 3) return HeaderError("malformed element line");
        ++elements;
        in_vertex = tok[1] == "vertex";
        if (!in_vertex) {
          uint64_t n = 0;
          // Records of later elements follow the vertices: the body may then be longer.
          if (!absl::SimpleAtoi(tok[2], &n) || n > 0) later_records_ = true;
        }
        if (in_vertex) {
          if (elements != 1) return HeaderError("the vertex element must come first");
          if (!absl::SimpleAtoi(tok[2], &count_)) {
            return HeaderError(absl::StrFormat("bad vertex count '%s'", tok[2]));
          }
          seen_vertex = true;
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
        p.scale = p.field >= kR ? TypeScale(p.type) : 1.0;
        if (p.field != kSkip) {
          if (have_[p.field]) {
            return HeaderError(absl::StrFormat("property '%s' given twice", tok[2]));
          }
          have_[p.field] = true;
        }
        props_.push_back(p);
      } else {
        return HeaderError(absl::StrFormat("unexpected keyword '%s'", tok[0]));
      }
    }
    if (!seen_format) return HeaderError("no format line");
    if (!seen_vertex) return HeaderError("no vertex element");
    static const char* kRequired[] = {"x", "y", "z", "nx", "ny", "nz", "radius"};
    for (int f = kX; f <= kRadius; ++f) {
      if (!have_[f]) {
        return HeaderError(
            absl::StrFormat("the vertex element has no '%s' property", kRequired[f]));
      }
    }
    has_color_ = have_[kR] && have_[kG] && have_[kB];
    if ((have_[kR] || have_[kG] || have_[kB]) && !has_color_) {
      return HeaderError("colour needs all three of r g b (or red green blue)");
    }
    all_float_in_order_ = props_.size() == 7 || props_.size() == 10;
    for (size_t i = 0; i < props_.size(); ++i) {
      all_float_in_order_ = all_float_in_order_ && props_[i].type == PType::kF32 &&
                            props_[i].field == static_cast<int>(i);
    }
    header_lines_ = line_;
    body_offset_ = std::ftell(file_);
    file_pos_ = body_offset_;
    // Room for at least two records, whatever their size.
    buf_.resize(std::max<size_t>(size_t{1} << 20, 2 * static_cast<size_t>(stride_)));
    if (!ascii_) PBGI_RETURN_IF_ERROR(CheckBinaryBodySize());
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
    const char* hint =
        text ? " (the body looks like ASCII text: it is not binary_little_endian)" : "";
    if (stride_ > 0 && count_ > body / static_cast<uint64_t>(stride_)) {
      return absl::DataLossError(absl::StrFormat(
          "%s: truncated at byte offset %d, in record %d of %d (each record is %d bytes)%s", path_,
          st.st_size, body / static_cast<uint64_t>(stride_), count_, stride_, hint));
    }
    if (body != want && !later_records_) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: the header says %d vertices of %d bytes (%d bytes), but the body after byte offset "
          "%d holds %d bytes%s: a wrong vertex count, or a body that is not "
          "binary_little_endian%s",
          path_, count_, stride_, want, body_offset_, body,
          body > want ? absl::StrFormat(" (%d more)", body - want) : std::string(), hint));
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

  void Assign(Surfel* s, const double v[kNumFields]) {
    s->position = glm::vec3(v[kX], v[kY], v[kZ]);
    s->normal = glm::vec3(v[kNx], v[kNy], v[kNz]);
    s->radius = static_cast<float>(v[kRadius]);
    s->radiance = has_color_ ? glm::vec3(v[kR], v[kG], v[kB]) : glm::vec3(0.0f);
  }

  absl::Status ReadBinaryRecord(Surfel* s) {
    if (Fill(stride_) < static_cast<size_t>(stride_)) {
      const long offset = file_pos_ + static_cast<long>(buf_len_);
      return absl::DataLossError(absl::StrFormat(
          "%s: truncated at byte offset %d, in record %d of %d (each record is %d bytes)", path_,
          offset, record_, count_, stride_));
    }
    const uint8_t* p = reinterpret_cast<const uint8_t*>(buf_.data() + buf_pos_);
    if (all_float_in_order_) {
      // The common layout (PlyWriter's): float x y z nx ny nz radius [r g b].
      float f[10] = {};
      std::memcpy(f, p, props_.size() * sizeof(float));
      s->position = glm::vec3(f[0], f[1], f[2]);
      s->normal = glm::vec3(f[3], f[4], f[5]);
      s->radius = f[6];
      s->radiance = glm::vec3(f[7], f[8], f[9]);
    } else {
      double v[kNumFields] = {};
      for (const Property& q : props_) {
        if (q.field != kSkip) v[q.field] = Decode(p + q.offset, q.type) * q.scale;
      }
      Assign(s, v);
    }
    buf_pos_ += stride_;
    file_pos_ += stride_;
    return absl::OkStatus();
  }

  // The common layout (PlyWriter's, float x y z nx ny nz radius [r g b]): whole buffered runs
  // of records at a time, one copy into the surfels. Surfel is 10 packed floats in file order.
  absl::StatusOr<size_t> NextBinaryFloats(absl::Span<Surfel> out) {
    static_assert(sizeof(Surfel) == 10 * sizeof(float));
    const size_t stride = static_cast<size_t>(stride_);
    size_t n = 0;
    while (n < out.size() && record_ < count_) {
      if (Fill(stride) < stride) {
        PBGI_RETURN_IF_ERROR(ReadBinaryRecord(&out[n]));  // names the truncation offset
      }
      const size_t k = static_cast<size_t>(
          std::min<uint64_t>({out.size() - n, count_ - record_, (buf_len_ - buf_pos_) / stride}));
      const char* p = buf_.data() + buf_pos_;
      if (stride == sizeof(Surfel)) {
        std::memcpy(static_cast<void*>(&out[n]), p, k * stride);
      } else {
        for (size_t j = 0; j < k; ++j) {
          Surfel& s = out[n + j];
          std::memcpy(static_cast<void*>(&s), p + j * stride, stride);
          s.radiance = glm::vec3(0.0f);
        }
      }
      buf_pos_ += k * stride;
      file_pos_ += static_cast<long>(k * stride);
      record_ += k;
      n += k;
    }
    return n;
  }

  absl::Status ReadAsciiRecord(Surfel* s) {
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
            "%s: line %d (record %d): '%s' is not a value of the property's type %s", path_,
            line_, record_, tok[i], TypeName(q.type)));
      }
      if (q.field != kSkip) v[q.field] = d * q.scale;
    }
    Assign(s, v);
    return absl::OkStatus();
  }

  static constexpr size_t kMaxHeaderLine = size_t{1} << 20;
  static constexpr size_t kMaxProperties = 4096;

  std::string path_;
  std::FILE* file_ = nullptr;
  bool ascii_ = false;
  bool later_records_ = false;  // elements after the vertices hold records
  bool end_checked_ = false;
  bool has_color_ = false;
  bool all_float_in_order_ = false;
  bool have_[kNumFields] = {};
  std::vector<Property> props_;
  int stride_ = 0;
  uint64_t count_ = 0;
  uint64_t record_ = 0;
  int line_ = 0;
  int header_lines_ = 0;
  long body_offset_ = 0;
  long file_pos_ = 0;  // file offset of buf_[buf_pos_]
  std::vector<char> buf_;
  size_t buf_pos_ = 0, buf_len_ = 0;
};

constexpr int kCountDigits = 20;

}  // namespace

absl::StatusOr<std::unique_ptr<SurfelSource>> OpenPly(const std::string& path) {
  return PlySource::Open(path);
}

absl::StatusOr<std::unique_ptr<PlyWriter>> PlyWriter::Create(const std::string& path,
                                                             const PlyWriterOptions& options) {
  auto w = std::unique_ptr<PlyWriter>(new PlyWriter());
  w->path_ = path;
  w->options_ = options;
  w->file_ = std::fopen(path.c_str(), "wb");
  if (w->file_ == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: cannot create: %s", path, std::strerror(errno)));
  }
  std::string h = absl::StrFormat("ply\nformat %s 1.0\ncomment pbgi surfels\nelement vertex ",
                                  options.ascii ? "ascii" : "binary_little_endian");
  w->count_offset_ = static_cast<long>(h.size());
  h += std::string(kCountDigits, '0') + "\n";
  for (const char* p : {"x", "y", "z", "nx", "ny", "nz", "radius"}) {
    h += absl::StrFormat("property float %s\n", p);
  }
  if (options.radiance) h += "property float r\nproperty float g\nproperty float b\n";
  h += "end_header\n";
  if (std::fwrite(h.data(), 1, h.size(), w->file_) != h.size()) {
    return absl::InternalError(absl::StrFormat("%s: write failed: %s", path, std::strerror(errno)));
  }
  return w;
}

PlyWriter::~PlyWriter() {
  if (file_ != nullptr) (void)Close();
}

absl::Status PlyWriter::Write(absl::Span<const Surfel> surfels) {
  if (file_ == nullptr) return absl::FailedPreconditionError(path_ + ": writer is closed");
  buf_.clear();
  for (const Surfel& s : surfels) {
    const float v[10] = {s.position.x, s.position.y, s.position.z, s.normal.x,   s.normal.y,
                         s.normal.z,   s.radius,     s.radiance.x, s.radiance.y, s.radiance.z};
    const int n = options_.radiance ? 10 : 7;
    if (options_.ascii) {
      for (int i = 0; i < n; ++i) {
        // %.9g round-trips every float exactly.
        // (One constant format: absl checks formats at compile time, which clang enforces.)
        absl::StrAppendFormat(&buf_, "%.9g", v[i]);
        buf_ += i + 1 < n ? ' ' : '\n';
      }
    } else {
      buf_.append(reinterpret_cast<const char*>(v), n * sizeof(float));
    }
  }
  if (std::fwrite(buf_.data(), 1, buf_.size(), file_) != buf_.size()) {
    return absl::InternalError(absl::StrFormat("%s: write failed after %d surfels: %s", path_,
                                               count_, std::strerror(errno)));
  }
  count_ += surfels.size();
  return absl::OkStatus();
}

absl::Status PlyWriter::Close() {
  if (file_ == nullptr) return absl::OkStatus();
  std::FILE* f = file_;
  file_ = nullptr;
  const std::string digits = absl::StrFormat("%0*d", kCountDigits, count_);
  bool ok = std::fflush(f) == 0 && std::fseek(f, count_offset_, SEEK_SET) == 0 &&
            std::fwrite(digits.data(), 1, digits.size(), f) == digits.size();
  ok = (std::fclose(f) == 0) && ok;
  if (!ok) {
    return absl::InternalError(
        absl::StrFormat("%s: finishing the file failed: %s", path_, std::strerror(errno)));
  }
  return absl::OkStatus();
}

}  // namespace pbgi
