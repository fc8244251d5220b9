// The record formats inside node and point pages: the contract between build/ (which writes
// them) and query/ (which reads them). Internal: not part of the public API.
//
// Point pages: a PageHeader, then `record_count` point records, fixed size, in Morton order.
// Global point index i lives in page i / PointsPerPage(), slot i % PointsPerPage(); every point
// page but the last is full. So a node's points, a contiguous range of global indices, can be
// found without any per-page table.
//
// Node pages: a PageHeader, then `record_count` node records, fixed size. Siblings (the children
// of one node) are always stored contiguously in one page, so an interior node refers to its
// children with one NodeRef and a count. In the coherent layout a page holds a treelet: a group
// of siblings and as many levels of their descendants as fit, in depth-first order.
#ifndef PBGI_TREE_FORMAT_H_
#define PBGI_TREE_FORMAT_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "pbgi/store.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// std::llround (half away from zero) inline and without branches: the libm call was a visible
// share of the sort thread's record encoding (docs/design.md, "Build"). The truncation's
// remainder x - q is exact for |x| < 2^52; other values (and NaN) go to std::llround.
inline int64_t RoundHalfAway(double x) {
  if (!(std::fabs(x) < 4503599627370496.0)) return std::llround(x);
  const int64_t q = static_cast<int64_t>(x);
  const double f = x - static_cast<double>(q);
  return q + static_cast<int64_t>(f >= 0.5) - static_cast<int64_t>(f <= -0.5);
}

// Where a node lives: page number (high 48 bits) and slot in the page (low 16 bits).
using NodeRef = uint64_t;
inline constexpr NodeRef MakeNodeRef(uint64_t page_no, uint32_t slot) {
  return (page_no << 16) | slot;
}
inline constexpr uint64_t RefPage(NodeRef r) { return r >> 16; }
inline constexpr uint32_t RefSlot(NodeRef r) { return static_cast<uint32_t>(r & 0xffff); }
inline constexpr NodeRef kNoNodeRef = ~uint64_t{0};

inline constexpr uint32_t kNodeFlagLeaf = 1u;

// A node record as the builder makes it and the query layer decodes it (plain floats). Stored
// compactly since format version 3 (EncodeNodeRecord below); the radiance part only in radiance
// databases.
struct NodeRecordCommon {
  float lo[3];
  float hi[3];
  uint32_t flags;        // kNodeFlagLeaf
  uint32_t child_count;  // interior: number of children (1..8), stored contiguously; leaf: 0
  uint64_t children;     // interior: NodeRef of the first child; leaf: kNoNodeRef
  uint64_t first_point;  // the subtree's points are [first_point, first_point + point_count)
  uint64_t point_count;
  float area;        // total surfel area
  uint32_t depth;    // root = 0
  float sh_area[9];  // projected area SH
  uint32_t pad;
};
static_assert(sizeof(NodeRecordCommon) == 104);

struct NodeRecordRadiance {
  NodeRecordCommon common;
  float sh_power[3][9];  // power SH per colour
  // Radiance databases: how far the radiance of the node's parts strays from its own, relative
  // to it (NodeContrast), as stored (ContrastValue of its code); 0 in occlusion databases.
  float contrast;
};
static_assert(sizeof(NodeRecordRadiance) == 216);

// ---- Format version 3: compact records (docs/format.md, "Format version 3") ----
//
// The builder and the query layer call the same decoders, and the builder aggregates what
// DecodePoint returns, so a node's area and SH are sums over exactly the surfels that a gather
// emits, and node bounds hold exactly the decoded positions (the grid is shared).

// The position grid of a store: 2^21 cells per axis.
inline constexpr int kGridBits = 21;
inline constexpr uint32_t kGridMax = (1u << kGridBits) - 1;

struct PositionGrid {
  float origin[3] = {0.0f, 0.0f, 0.0f};
  float step = 0.0f;

  static PositionGrid Of(const StoreMeta& m) {
    PositionGrid g;
    for (int a = 0; a < 3; ++a) g.origin[a] = m.grid_origin[a];
    g.step = m.grid_step;
    return g;
  }
  // The centre of cell q. Monotone in q (float addition and multiplication round monotonically),
  // which is what makes a node's grid bounds contain its points' decoded positions.
  float Coord(int axis, uint32_t q) const {
    return origin[axis] + (static_cast<float>(q) + 0.5f) * step;
  }
  // The cell whose centre is nearest to v (clamped to the grid).
  uint32_t Nearest(int axis, float v) const {
    if (!(step > 0.0f)) return 0;
    const double t = (double{v} - double{origin[axis]}) / double{step} - 0.5;
    if (!(t > 0.0)) return 0;
    if (t >= double{kGridMax}) return kGridMax;
    return static_cast<uint32_t>(RoundHalfAway(t));
  }
  // The largest q with Coord(q) <= v (0 when none is): a lower bound rounded down.
  uint32_t Floor(int axis, float v) const {
    uint32_t q = Nearest(axis, v);
    while (q > 0 && Coord(axis, q) > v) --q;
    while (q < kGridMax && Coord(axis, q + 1) <= v) ++q;
    return q;
  }
  // The smallest q with Coord(q) >= v (kGridMax when none is): an upper bound rounded up.
  uint32_t Ceil(int axis, float v) const {
    uint32_t q = Nearest(axis, v);
    while (q < kGridMax && Coord(axis, q) < v) ++q;
    while (q > 0 && Coord(axis, q - 1) >= v) --q;
    return q;
  }
};

inline uint64_t PackCell(uint32_t x, uint32_t y, uint32_t z) {
  return uint64_t{x} | (uint64_t{y} << kGridBits) | (uint64_t{z} << (2 * kGridBits));
}
inline uint32_t CellAxis(uint64_t packed, int axis) {
  return static_cast<uint32_t>(packed >> (axis * kGridBits)) & kGridMax;
}

// Unsigned small floats: `e` exponent bits (bias 2^(e-1)), `m` mantissa bits, no denormals;
// rounded to nearest. Encoding 0 is zero; what is too small for the smallest normal becomes
// zero (flush_to_min: the smallest normal instead); what is too large, the largest.
template <int E, int M>
inline uint32_t EncodeSmallFloat(float v, bool flush_to_min) {
  constexpr int kBias = 1 << (E - 1);
  constexpr uint32_t kMaxE = (1u << E) - 1;
  if (!(v > 0.0f)) return flush_to_min ? (1u << M) : 0u;
  uint32_t bits;
  std::memcpy(&bits, &v, 4);
  int exp = static_cast<int>((bits >> 23) & 0xff) - 127;
  uint32_t mant = bits & 0x7fffff;
  if (exp == -127) return flush_to_min ? (1u << M) : 0u;  // a float denormal
  mant += 1u << (23 - M - 1);
  if (mant >= (1u << 23)) {
    mant = 0;
    ++exp;
  }
  const int e = exp + kBias;
  if (e < 1) return flush_to_min ? (1u << M) : 0u;
  if (e > static_cast<int>(kMaxE) || exp > 127) return (kMaxE << M) | ((1u << M) - 1);
  return (static_cast<uint32_t>(e) << M) | (mant >> (23 - M));
}
template <int E, int M>
inline float DecodeSmallFloat(uint32_t code) {
  constexpr int kBias = 1 << (E - 1);
  const uint32_t e = (code >> M) & ((1u << E) - 1);
  if (e == 0) return 0.0f;
  const uint32_t bits = (static_cast<uint32_t>(static_cast<int>(e) - kBias + 127) << 23) |
                        ((code & ((1u << M) - 1)) << (23 - M));
  float v;
  std::memcpy(&v, &bits, 4);
  return v;
}
// Radius: 6 exponent bits, 10 mantissa bits: 2^-31 .. 2^32, relative error <= 2^-11.
inline uint16_t EncodeRadius16(float r) {
  return static_cast<uint16_t>(EncodeSmallFloat<6, 10>(std::fabs(r), /*flush_to_min=*/true));
}
inline float DecodeRadius16(uint16_t c) { return DecodeSmallFloat<6, 10>(c); }

// The builder's two-sided flag travels in the radius's sign bit of its sort records
// (build/sort_record.h): a radius is always > 0 otherwise (the builder refuses the rest). A
// two-sided surfel's radius is its stored value (DecodeRadius16(EncodeRadius16(r)), whose 13
// low mantissa bits are zero) with its sheet tag (Surfel::sheet) in the 8 lowest, so the tag
// rides along without a field of its own and the stored radius is the same.
inline float EncodeRadius(float radius, bool two_sided, uint8_t sheet = 0) {
  if (!two_sided) return std::fabs(radius);
  uint32_t bits;
  const float stored = DecodeRadius16(EncodeRadius16(radius));
  std::memcpy(&bits, &stored, 4);
  bits |= 0x80000000u | sheet;
  float out;
  std::memcpy(&out, &bits, 4);
  return out;
}
inline bool RadiusTwoSided(float stored) { return std::signbit(stored); }
// The radius itself (> 0), without the sign and, on a two-sided radius, the tag's bits.
inline float RadiusValue(float stored) {
  uint32_t bits;
  std::memcpy(&bits, &stored, 4);
  bits = std::signbit(stored) ? (bits & 0x7fffff00u) : bits;
  float out;
  std::memcpy(&out, &bits, 4);
  return out;
}
inline uint8_t RadiusSheet(float stored) {
  if (!std::signbit(stored)) return 0;
  uint32_t bits;
  std::memcpy(&bits, &stored, 4);
  return static_cast<uint8_t>(bits & 0xffu);
}
// Radiance: a sign bit, 6 exponent bits, 9 mantissa bits: |v| in 2^-31 .. 2^32 (smaller is 0),
// relative error <= 2^-10.
inline uint16_t EncodeRadiance16(float v) {
  const uint32_t mag = EncodeSmallFloat<6, 9>(std::fabs(v), /*flush_to_min=*/false);
  return static_cast<uint16_t>(mag | (std::signbit(v) && mag != 0 ? 0x8000u : 0u));
}
inline float DecodeRadiance16(uint16_t c) {
  const float mag = DecodeSmallFloat<6, 9>(c & 0x7fffu);
  return (c & 0x8000u) ? -mag : mag;
}

// Octahedral unit vectors (Meyer et al. 2010, "On Floating-Point Normal Vectors"), two signed
// 16-bit coordinates: angular error below 1e-4 rad.
inline void OctahedralCoords(const float n[3], float* ox, float* oy) {
  const float l1 = std::fabs(n[0]) + std::fabs(n[1]) + std::fabs(n[2]);
  float x = l1 > 0.0f ? n[0] / l1 : 0.0f;
  float y = l1 > 0.0f ? n[1] / l1 : 0.0f;
  if (n[2] < 0.0f) {
    const float fx = (1.0f - std::fabs(y)) * (x >= 0.0f ? 1.0f : -1.0f);
    const float fy = (1.0f - std::fabs(x)) * (y >= 0.0f ? 1.0f : -1.0f);
    x = fx;
    y = fy;
  }
  *ox = std::clamp(x, -1.0f, 1.0f);
  *oy = std::clamp(y, -1.0f, 1.0f);
}
inline glm::vec3 OctahedralVector(float x, float y) {
  const float z = 1.0f - std::fabs(x) - std::fabs(y);
  if (z < 0.0f) {
    const float ox = (1.0f - std::fabs(y)) * (x >= 0.0f ? 1.0f : -1.0f);
    const float oy = (1.0f - std::fabs(x)) * (y >= 0.0f ? 1.0f : -1.0f);
    x = ox;
    y = oy;
  }
  const float inv = 1.0f / std::sqrt(x * x + y * y + z * z);
  return {x * inv, y * inv, z * inv};
}
inline void EncodeOctahedral(const float n[3], int16_t out[2]) {
  float x, y;
  OctahedralCoords(n, &x, &y);
  out[0] = static_cast<int16_t>(RoundHalfAway(x * 32767.0f));
  out[1] = static_cast<int16_t>(RoundHalfAway(y * 32767.0f));
}
inline glm::vec3 DecodeOctahedral(const int16_t in[2]) {
  return OctahedralVector(static_cast<float>(in[0]) * (1.0f / 32767.0f),
                          static_cast<float>(in[1]) * (1.0f / 32767.0f));
}
// A two-sided point record's normal (format version 4): 12-bit octahedral coordinates (angular
// error up to about 1.0e-3 rad) in the high bits of each i16, the sheet tag's high and low nibbles
// in their low 4 bits.
inline void EncodeOctahedralSheet(const float n[3], uint8_t sheet, int16_t out[2]) {
  float x, y;
  OctahedralCoords(n, &x, &y);
  const int qx = static_cast<int>(RoundHalfAway(x * 2047.0f));
  const int qy = static_cast<int>(RoundHalfAway(y * 2047.0f));
  out[0] = static_cast<int16_t>(qx * 16 + (sheet >> 4));
  out[1] = static_cast<int16_t>(qy * 16 + (sheet & 15));
}
inline glm::vec3 DecodeOctahedralSheet(const int16_t in[2], uint8_t* sheet) {
  *sheet = static_cast<uint8_t>(((in[0] & 15) << 4) | (in[1] & 15));
  return OctahedralVector(static_cast<float>(in[0] >> 4) * (1.0f / 2047.0f),
                          static_cast<float>(in[1] >> 4) * (1.0f / 2047.0f));
}

// Point records, version 4 (version 6 adds the back radiance). Little-endian, packed, no
// alignment:
//   0  u64    cell (x | y << 21 | z << 42) of the position; bit 63: two-sided
//   8  i16[2] octahedral normal (two-sided: EncodeOctahedralSheet, the sheet tag in its low bits)
//   12 u16    radius (EncodeRadius16)
//   14 u16[3] radiance (EncodeRadiance16), radiance databases only
//   20 u16[3] back radiance (EncodeRadiance16), Channels::kRadianceBothSides only: a two-sided
//             surfel's (Surfel::back_radiance), 0 on one-sided ones. Without it a two-sided
//             surfel's back radiance is its front's.
inline constexpr uint32_t kPointRecordOcclusionBytes = 14;
inline constexpr uint32_t kPointRecordRadianceBytes = 20;
inline constexpr uint32_t kPointRecordBothSidesBytes = 26;

inline uint32_t PointRecordSize(Channels c) {
  switch (c) {
    case Channels::kOcclusion:
      return kPointRecordOcclusionBytes;
    case Channels::kRadianceBothSides:
      return kPointRecordBothSidesBytes;
    default:
      return kPointRecordRadianceBytes;
  }
}

// The builder's sort records (build/sort_record.h) carry a two-sided surfel's two radiances as
// their stored codes, front << 16 | back, in the bits of each radiance float (the stored values
// are those codes' anyway), as the radius carries the flag and the tag.
inline float PackSidesRadiance(float front, float back) {
  const uint32_t bits = (uint32_t{EncodeRadiance16(front)} << 16) | EncodeRadiance16(back);
  float out;
  std::memcpy(&out, &bits, 4);
  return out;
}
inline uint16_t FrontCode(float packed) {
  uint32_t bits;
  std::memcpy(&bits, &packed, 4);
  return static_cast<uint16_t>(bits >> 16);
}
inline uint16_t BackCode(float packed) {
  uint32_t bits;
  std::memcpy(&bits, &packed, 4);
  return static_cast<uint16_t>(bits & 0xffffu);
}
// A sort record's front and back radiance (`radius` its stored radius: two-sided or not).
inline void RecordRadiances(float radius, const float radiance[3], float front[3], float back[3]) {
  for (int k = 0; k < 3; ++k) {
    if (RadiusTwoSided(radius)) {
      front[k] = DecodeRadiance16(FrontCode(radiance[k]));
      back[k] = DecodeRadiance16(BackCode(radiance[k]));
    } else {
      front[k] = back[k] = radiance[k];
    }
  }
}

// Encodes one surfel (radius sign = two-sided, as in the builder's sort records, and the sheet
// tag in a two-sided radius's low bits: EncodeRadius) at `dst`. `radiance` as in a sort record:
// a two-sided surfel's floats are PackSidesRadiance codes.
inline void EncodePointRecord(const float position[3], const float normal[3], float radius,
                              const float radiance[3], Channels c, const PositionGrid& grid,
                              uint8_t* dst) {
  uint64_t cell = PackCell(grid.Nearest(0, position[0]), grid.Nearest(1, position[1]),
                           grid.Nearest(2, position[2]));
  int16_t oct[2];
  const bool two_sided = RadiusTwoSided(radius);
  if (two_sided) {
    cell |= uint64_t{1} << 63;
    EncodeOctahedralSheet(normal, RadiusSheet(radius), oct);
  } else {
    EncodeOctahedral(normal, oct);
  }
  std::memcpy(dst, &cell, 8);
  std::memcpy(dst + 8, oct, 4);
  const uint16_t r = EncodeRadius16(radius);
  std::memcpy(dst + 12, &r, 2);
  if (HasRadiance(c)) {
    uint16_t l[3], b[3] = {0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      if (two_sided) {
        l[k] = FrontCode(radiance[k]);
        b[k] = BackCode(radiance[k]);
      } else {
        l[k] = EncodeRadiance16(radiance[k]);
      }
    }
    std::memcpy(dst + 14, l, 6);
    if (c == Channels::kRadianceBothSides) std::memcpy(dst + 20, b, 6);
  }
}

// One surfel's record, as the builder stores it from its sort record.
inline void EncodeSurfelRecord(const Surfel& s, Channels c, const PositionGrid& grid,
                               uint8_t* dst) {
  const float pos[3] = {s.position.x, s.position.y, s.position.z};
  const float nrm[3] = {s.normal.x, s.normal.y, s.normal.z};
  float rad[3] = {s.radiance.x, s.radiance.y, s.radiance.z};
  if (s.two_sided) {
    for (int k = 0; k < 3; ++k) rad[k] = PackSidesRadiance(s.radiance[k], s.back_radiance[k]);
  }
  EncodePointRecord(pos, nrm, EncodeRadius(s.radius, s.two_sided, s.sheet), rad, c, grid, dst);
}

inline Surfel DecodePointRecord(const uint8_t* src, Channels c, const PositionGrid& grid) {
  Surfel s;
  uint64_t cell;
  std::memcpy(&cell, src, 8);
  s.position = {grid.Coord(0, CellAxis(cell, 0)), grid.Coord(1, CellAxis(cell, 1)),
                grid.Coord(2, CellAxis(cell, 2))};
  s.two_sided = (cell >> 63) != 0;
  int16_t oct[2];
  std::memcpy(oct, src + 8, 4);
  s.normal = s.two_sided ? DecodeOctahedralSheet(oct, &s.sheet) : DecodeOctahedral(oct);
  uint16_t r;
  std::memcpy(&r, src + 12, 2);
  s.radius = DecodeRadius16(r);
  if (HasRadiance(c)) {
    uint16_t l[3];
    std::memcpy(l, src + 14, 6);
    s.radiance = {DecodeRadiance16(l[0]), DecodeRadiance16(l[1]), DecodeRadiance16(l[2])};
    if (!s.two_sided) {
      s.back_radiance = glm::vec3(0.0f);
    } else if (c == Channels::kRadianceBothSides) {
      std::memcpy(l, src + 20, 6);
      s.back_radiance = {DecodeRadiance16(l[0]), DecodeRadiance16(l[1]), DecodeRadiance16(l[2])};
    } else {
      s.back_radiance = s.radiance;
    }
  } else {
    s.radiance = glm::vec3(0.0f);
    s.back_radiance = glm::vec3(0.0f);
  }
  return s;
}

// Decodes point record `slot` of a point page payload.
inline Surfel DecodePoint(const uint8_t* payload, uint32_t slot, Channels c,
                          const PositionGrid& grid) {
  return DecodePointRecord(payload + size_t{slot} * PointRecordSize(c), c, grid);
}

// Node records, version 3. Little-endian, packed, no alignment:
//   0  u64    lo: cell of each axis rounded down (PositionGrid::Floor), packed as a point's
//   8  u64    hi: rounded up (PositionGrid::Ceil); so the decoded box holds every point below
//   16 u40    first_point
//   21 u40    point_count
//   26 u32    children: page (leaf: ~0)
//   30 u16    children: slot (leaf: ~0)
//   32 u8     depth
//   33 u8     bit 0: leaf; bits 4-7: child_count
//   34 f32    area
//   38 f32    s: the largest |sh_area[k]|
//   42 i16[9] sh_area[k] = s * q / 32767
//   radiance databases, per colour (3x):
//   60 f32    s_c: the largest |sh_power[c][k]|
//   64 i8[9]  sh_power[c][k] = s_c * q / 127
//   99 u8     (version 5) contrast: ContrastCode(contrast)
inline constexpr uint32_t kNodeRecordOcclusionBytes = 60;
inline constexpr uint32_t kNodeRecordRadianceBytes = 60 + 3 * 13 + 1;
inline constexpr uint32_t kNodeContrastOffset = 60 + 3 * 13;

// The luminance of a node record's mean radiance, in double: band 0 of its power SH over band 0
// of its projected-area SH, the mean of the channels (0 without area). The builder's contrast
// over a node's children and `pbgi verify`'s check of it.
inline double RecordLuminance(const NodeRecordRadiance& r) {
  const double a0 = r.common.sh_area[0];
  return a0 > 0.0 ? (double{r.sh_power[0][0]} + r.sh_power[1][0] + r.sh_power[2][0]) / (3.0 * a0)
                  : 0.0;
}

// A node's radiance contrast (format version 5; docs/design.md, "A cut that sees radiance"):
// the largest |L_i - L| / L over its children i (a leaf: over its surfels), L the luminance
// (the mean of the three channels) of the mean radiance, band 0 of the power SH over band 0
// of the projected-area SH (a surfel: its radiance). Stored in one byte on a log scale,
// rounded up: code = ceil(16 log2(1 + c)), at most 255; ContrastValue(code) = 2^(code / 16) - 1
// >= c (up to 2^15.9 - 1, about 62,000).
inline uint8_t ContrastCode(double c) {
  if (!(c > 1e-6)) return 0;  // 0 (or the rounding of equal means), or NaN
  const double code = std::ceil(16.0 * std::log2(1.0 + c) - 1e-9);
  return static_cast<uint8_t>(std::clamp(code, 0.0, 255.0));
}
inline float ContrastValue(uint8_t code) {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int k = 0; k < 256; ++k) t[k] = static_cast<float>(std::exp2(k / 16.0) - 1.0);
    return t;
  }();
  return table[code];
}
inline constexpr uint64_t kMaxStoredPointIndex = (uint64_t{1} << 40) - 1;

inline uint32_t NodeRecordSize(Channels c) {
  return HasRadiance(c) ? kNodeRecordRadianceBytes : kNodeRecordOcclusionBytes;
}

// The scalar formula of EncodeScaled's code for c / s (|c| <= s, or NaN), in double: near kMax
// a float has too few fraction bits to round to the nearest step.
template <typename Int, int kMax>
inline Int ScaledCode(float c, float s) {
  return static_cast<Int>(
      std::clamp<int64_t>(RoundHalfAway(double{c} / double{s} * kMax), -kMax, kMax));
}

// Fixed point, scaled by the largest magnitude: |error| <= scale / (2 * kMax) per coefficient.
// Two codes at a time where SSE2 is (the x86-64 baseline), the same codes as ScaledCode: a
// finite c has |c / s| <= 1, so |c / s * kMax| <= kMax < 2^31 needs no clamp and truncates
// exactly to int32, and the remainder and the half-away step are those of RoundHalfAway. A pair
// with a NaN (std::max skipped it, so s is finite) goes to the scalar formula.
template <typename Int, int kMax>
inline float EncodeScaled(const float* c, int n, Int* q) {
  float s = 0.0f;
  for (int k = 0; k < n; ++k) s = std::max(s, std::fabs(c[k]));
  if (!(s > 0.0f) || !std::isfinite(s)) {
    for (int k = 0; k < n; ++k) q[k] = 0;
    return std::isfinite(s) ? 0.0f : s;
  }
  int k = 0;
#if defined(__SSE2__)
  const __m128d sd = _mm_set1_pd(s), scale = _mm_set1_pd(kMax);
  const __m128d half = _mm_set1_pd(0.5), minus_half = _mm_set1_pd(-0.5), one = _mm_set1_pd(1.0);
  for (; k + 2 <= n; k += 2) {
    const __m128d x = _mm_mul_pd(_mm_div_pd(_mm_set_pd(c[k + 1], c[k]), sd), scale);
    if (_mm_movemask_pd(_mm_cmpunord_pd(x, x)) != 0) {
      q[k] = ScaledCode<Int, kMax>(c[k], s);
      q[k + 1] = ScaledCode<Int, kMax>(c[k + 1], s);
      continue;
    }
    const __m128d t = _mm_cvtepi32_pd(_mm_cvttpd_epi32(x));
    const __m128d f = _mm_sub_pd(x, t);
    const __m128d r = _mm_sub_pd(_mm_add_pd(t, _mm_and_pd(_mm_cmpge_pd(f, half), one)),
                                 _mm_and_pd(_mm_cmple_pd(f, minus_half), one));
    const __m128i qi = _mm_cvttpd_epi32(r);
    q[k] = static_cast<Int>(_mm_cvtsi128_si32(qi));
    q[k + 1] = static_cast<Int>(_mm_cvtsi128_si32(_mm_srli_si128(qi, 4)));
  }
#endif
  for (; k < n; ++k) q[k] = ScaledCode<Int, kMax>(c[k], s);
  return s;
}
template <typename Int, int kMax>
inline void DecodeScaled(float s, const Int* q, int n, float* c) {
  const float unit = s * (1.0f / kMax);
  for (int k = 0; k < n; ++k) c[k] = static_cast<float>(q[k]) * unit;
}

inline void EncodeNodeRecord(const NodeRecordRadiance& r, Channels ch, const PositionGrid& grid,
                             uint8_t* dst) {
  const NodeRecordCommon& c = r.common;
  const uint64_t lo =
      PackCell(grid.Floor(0, c.lo[0]), grid.Floor(1, c.lo[1]), grid.Floor(2, c.lo[2]));
  const uint64_t hi = PackCell(grid.Ceil(0, c.hi[0]), grid.Ceil(1, c.hi[1]), grid.Ceil(2, c.hi[2]));
  std::memcpy(dst, &lo, 8);
  std::memcpy(dst + 8, &hi, 8);
  const uint64_t first = std::min(c.first_point, kMaxStoredPointIndex);
  const uint64_t count = std::min(c.point_count, kMaxStoredPointIndex);
  std::memcpy(dst + 16, &first, 5);
  std::memcpy(dst + 21, &count, 5);
  const uint32_t page = c.children == kNoNodeRef ? ~0u : static_cast<uint32_t>(RefPage(c.children));
  const uint16_t slot =
      c.children == kNoNodeRef ? uint16_t{0xffff} : static_cast<uint16_t>(RefSlot(c.children));
  std::memcpy(dst + 26, &page, 4);
  std::memcpy(dst + 30, &slot, 2);
  dst[32] = static_cast<uint8_t>(std::min<uint32_t>(c.depth, 255));
  dst[33] = static_cast<uint8_t>(((c.flags & kNodeFlagLeaf) ? 1u : 0u) |
                                 (std::min<uint32_t>(c.child_count, 15) << 4));
  std::memcpy(dst + 34, &c.area, 4);
  int16_t qa[9];
  const float sa = EncodeScaled<int16_t, 32767>(c.sh_area, 9, qa);
  std::memcpy(dst + 38, &sa, 4);
  std::memcpy(dst + 42, qa, 18);
  if (HasRadiance(ch)) {
    for (int k = 0; k < 3; ++k) {
      int8_t qp[9];
      const float sp = EncodeScaled<int8_t, 127>(r.sh_power[k], 9, qp);
      std::memcpy(dst + 60 + 13 * k, &sp, 4);
      std::memcpy(dst + 64 + 13 * k, qp, 9);
    }
    dst[kNodeContrastOffset] = ContrastCode(r.contrast);
  }
}

// The node as the query layer sees it (sh_power zero in occlusion databases).
inline NodeRecordRadiance DecodeNodeRecord(const uint8_t* src, Channels ch,
                                           const PositionGrid& grid) {
  // Every field is written below: zero-initialising the 216 bytes first (`r{}`) stalled the
  // stores that follow and made up a third of a page's decode.
  NodeRecordRadiance r;
  NodeRecordCommon& c = r.common;
  c.pad = 0;
  r.contrast = 0.0f;
  uint64_t lo, hi;
  std::memcpy(&lo, src, 8);
  std::memcpy(&hi, src + 8, 8);
  for (int a = 0; a < 3; ++a) {
    c.lo[a] = grid.Coord(a, CellAxis(lo, a));
    c.hi[a] = grid.Coord(a, CellAxis(hi, a));
  }
  // The two u40 as 8-byte loads, masked (the record goes on past byte 29): 5-byte copies into
  // a zeroed word stalled on store forwarding.
  uint64_t first, count;
  std::memcpy(&first, src + 16, 8);
  std::memcpy(&count, src + 21, 8);
  c.first_point = first & kMaxStoredPointIndex;
  c.point_count = count & kMaxStoredPointIndex;
  uint32_t page;
  uint16_t slot;
  std::memcpy(&page, src + 26, 4);
  std::memcpy(&slot, src + 30, 2);
  c.children = page == ~0u && slot == 0xffff ? kNoNodeRef : MakeNodeRef(page, slot);
  c.depth = src[32];
  c.flags = (src[33] & 1u) ? kNodeFlagLeaf : 0u;
  c.child_count = src[33] >> 4;
  std::memcpy(&c.area, src + 34, 4);
  float sa;
  int16_t qa[9];
  std::memcpy(&sa, src + 38, 4);
  std::memcpy(qa, src + 42, 18);
  DecodeScaled<int16_t, 32767>(sa, qa, 9, c.sh_area);
  if (HasRadiance(ch)) {
    for (int k = 0; k < 3; ++k) {
      float sp;
      int8_t qp[9];
      std::memcpy(&sp, src + 60 + 13 * k, 4);
      std::memcpy(qp, src + 64 + 13 * k, 9);
      DecodeScaled<int8_t, 127>(sp, qp, 9, r.sh_power[k]);
    }
    r.contrast = ContrastValue(src[kNodeContrastOffset]);
  } else {
    std::fill(&r.sh_power[0][0], &r.sh_power[0][0] + 27, 0.0f);
  }
  return r;
}

inline uint32_t NodesPerPage(uint32_t page_size, Channels c) {
  return (page_size - sizeof(PageHeader)) / NodeRecordSize(c);
}
inline uint32_t PointsPerPage(uint32_t page_size, Channels c) {
  return (page_size - sizeof(PageHeader)) / PointRecordSize(c);
}

}  // namespace pbgi::internal

#endif  // PBGI_TREE_FORMAT_H_
