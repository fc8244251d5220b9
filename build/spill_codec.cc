#include "build/spill_codec.h"

#include <array>
#include <cstddef>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "absl/strings/str_format.h"
#include "zstd.h"

namespace pbgi::internal {
namespace {

// Offsets of the field columns in a block of n records (see the header).
struct Columns {
  size_t keys, cells, normals, radii, radiance, back, end;
  Columns(size_t n, Channels ch) {
    keys = 0;
    cells = keys + 8 * n;
    normals = cells + 8 * n;
    radii = normals + 4 * n;
    radiance = radii + 2 * n;
    back = radiance + (HasRadiance(ch) ? 6 * n : 0);
    end = back + (ch == Channels::kRadianceBothSides ? 6 * n : 0);
  }
};

// KeyCell of the 9 key bits c (3 bits of each axis): x from bits 0, 3, 6, y from 1, 4, 7, z from
// 2, 5, 8, each into its 21-bit field of a packed cell.
constexpr std::array<uint64_t, 512> MakeKeyCellTable() {
  std::array<uint64_t, 512> t{};
  for (uint64_t c = 0; c < 512; ++c) {
    for (int b = 0; b < 3; ++b) {
      for (int axis = 0; axis < 3; ++axis) {
        t[c] |= ((c >> (3 * b + axis)) & 1) << (axis * kGridBits + b);
      }
    }
  }
  return t;
}
constexpr std::array<uint64_t, 512> kKeyCellTable = MakeKeyCellTable();

}  // namespace

uint64_t KeyCell(uint64_t key) {
  // Seven table look-ups of 9 bits, about half the instructions of three bit gathers, on both
  // the sort thread and the merge thread (docs/format.md, "Session 17").
  const uint64_t* t = kKeyCellTable.data();
  return t[key & 511] | t[(key >> 9) & 511] << 3 | t[(key >> 18) & 511] << 6 |
         t[(key >> 27) & 511] << 9 | t[(key >> 36) & 511] << 12 | t[(key >> 45) & 511] << 15 |
         t[(key >> 54) & 511] << 18;
}

namespace {

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

void SpillCodec::PackBlock(const SortRecord* in, size_t n, SortRecord* out) const {
  size_t i = 0;
#if defined(__SSE2__)
  // Each lane makes the IEEE operations of EncodePointRecord in the same order (the cells'
  // division in double, as Nearest; no FMA on the x86-64 baseline), and its integer steps as
  // masks, so the bytes are Pack's. A group of four with a field that is not finite or a zero
  // normal goes to Pack, and so does every record when the grid's step is not positive.
  if (grid.step > 0.0f) {
    const bool radiance = HasRadiance(channels);
    const __m128 sign = _mm_castsi128_ps(_mm_set1_epi32(static_cast<int>(0x80000000u)));
    const __m128 zero = _mm_setzero_ps(), one = _mm_set1_ps(1.0f);
    const __m128d half_d = _mm_set1_pd(0.5), one_d = _mm_set1_pd(1.0), zero_d = _mm_setzero_pd();
    const __m128d grid_max = _mm_set1_pd(double{kGridMax}), step = _mm_set1_pd(double{grid.step});
    // Nearest on two lanes: t = (v - origin) / step - 0.5, 0 unless t > 0, kGridMax from
    // kGridMax on, else RoundHalfAway(t) (t >= 0: truncate, plus one from a half up).
    auto nearest2 = [&](__m128d v, double origin) {
      const __m128d t = _mm_sub_pd(_mm_div_pd(_mm_sub_pd(v, _mm_set1_pd(origin)), step), half_d);
      const __m128d q = _mm_cvtepi32_pd(_mm_cvttpd_epi32(t));
      const __m128d r = _mm_add_pd(q, _mm_and_pd(_mm_cmpge_pd(_mm_sub_pd(t, q), half_d), one_d));
      const __m128d top = _mm_cmpge_pd(t, grid_max);
      const __m128d c = _mm_or_pd(_mm_and_pd(top, grid_max), _mm_andnot_pd(top, r));
      return _mm_cvttpd_epi32(_mm_and_pd(_mm_cmpgt_pd(t, zero_d), c));
    };
    auto nearest4 = [&](__m128 v, int axis) {
      const __m128i lo = nearest2(_mm_cvtps_pd(v), double{grid.origin[axis]});
      const __m128i hi = nearest2(_mm_cvtps_pd(_mm_movehl_ps(v, v)), double{grid.origin[axis]});
      return _mm_unpacklo_epi64(lo, hi);
    };
    // EncodeSmallFloat<6, M>(v) for v >= 0 finite: `flush` for zero, denormals and exponents
    // below the range, the largest code above it.
    auto small_float = [](__m128 v, int m, int flush) {
      const __m128i bits = _mm_castps_si128(v);
      const __m128i biased = _mm_srli_epi32(bits, 23);  // the float's exponent field
      const __m128i rounded = _mm_add_epi32(_mm_and_si128(bits, _mm_set1_epi32(0x7fffff)),
                                            _mm_set1_epi32(1 << (23 - m - 1)));
      const __m128i e = _mm_add_epi32(_mm_add_epi32(biased, _mm_srli_epi32(rounded, 23)),
                                      _mm_set1_epi32(32 - 127));
      const __m128i mant = _mm_srli_epi32(_mm_and_si128(rounded, _mm_set1_epi32(0x7fffff)), 23 - m);
      __m128i code = _mm_or_si128(_mm_slli_epi32(e, m), mant);
      const __m128i big = _mm_cmpgt_epi32(e, _mm_set1_epi32(63));
      code = _mm_or_si128(_mm_and_si128(big, _mm_set1_epi32((63 << m) | ((1 << m) - 1))),
                          _mm_andnot_si128(big, code));
      const __m128i small = _mm_or_si128(_mm_cmplt_epi32(e, _mm_set1_epi32(1)),
                                         _mm_cmpeq_epi32(biased, _mm_setzero_si128()));
      return _mm_or_si128(_mm_and_si128(small, _mm_set1_epi32(flush)),
                          _mm_andnot_si128(small, code));
    };
    auto radiance16 = [&](__m128 v) {
      const __m128i mag = small_float(_mm_andnot_ps(sign, v), 9, 0);
      const __m128i negative = _mm_srai_epi32(_mm_castps_si128(v), 31);
      const __m128i nonzero =
          _mm_xor_si128(_mm_cmpeq_epi32(mag, _mm_setzero_si128()), _mm_set1_epi32(-1));
      return _mm_or_si128(mag,
                          _mm_and_si128(_mm_and_si128(negative, nonzero), _mm_set1_epi32(0x8000)));
    };
    auto finite = [&](__m128 v) { return _mm_cmpeq_ps(_mm_sub_ps(v, v), zero); };
    for (; i + 4 <= n; i += 4) {
      const uint8_t* r[4];
      for (int k = 0; k < 4; ++k) r[k] = reinterpret_cast<const uint8_t*>(&in[i + k]);
      __m128 px = _mm_loadu_ps(reinterpret_cast<const float*>(r[0] + 8));
      __m128 py = _mm_loadu_ps(reinterpret_cast<const float*>(r[1] + 8));
      __m128 pz = _mm_loadu_ps(reinterpret_cast<const float*>(r[2] + 8));
      __m128 nx = _mm_loadu_ps(reinterpret_cast<const float*>(r[3] + 8));
      _MM_TRANSPOSE4_PS(px, py, pz, nx);
      __m128 ny = _mm_loadu_ps(reinterpret_cast<const float*>(r[0] + 24));
      __m128 nz = _mm_loadu_ps(reinterpret_cast<const float*>(r[1] + 24));
      __m128 rad = _mm_loadu_ps(reinterpret_cast<const float*>(r[2] + 24));
      __m128 l0 = _mm_loadu_ps(reinterpret_cast<const float*>(r[3] + 24));
      _MM_TRANSPOSE4_PS(ny, nz, rad, l0);
      __m128 c01 = _mm_loadl_pi(zero, reinterpret_cast<const __m64*>(r[0] + 40));
      c01 = _mm_loadh_pi(c01, reinterpret_cast<const __m64*>(r[1] + 40));
      __m128 c23 = _mm_loadl_pi(zero, reinterpret_cast<const __m64*>(r[2] + 40));
      c23 = _mm_loadh_pi(c23, reinterpret_cast<const __m64*>(r[3] + 40));
      const __m128 l1 = _mm_shuffle_ps(c01, c23, _MM_SHUFFLE(2, 0, 2, 0));
      const __m128 l2 = _mm_shuffle_ps(c01, c23, _MM_SHUFFLE(3, 1, 3, 1));
      const __m128 l1n = _mm_add_ps(_mm_add_ps(_mm_andnot_ps(sign, nx), _mm_andnot_ps(sign, ny)),
                                    _mm_andnot_ps(sign, nz));
      __m128 ok =
          _mm_and_ps(_mm_and_ps(finite(px), finite(py)), _mm_and_ps(finite(pz), finite(rad)));
      ok = _mm_and_ps(ok, _mm_and_ps(finite(l1n), _mm_cmpgt_ps(l1n, zero)));
      if (radiance) ok = _mm_and_ps(ok, _mm_and_ps(finite(l0), _mm_and_ps(finite(l1), finite(l2))));
      // Two-sided records (their normal holds the sheet tag: EncodeOctahedralSheet) go to Pack.
      if (_mm_movemask_ps(ok) != 0xf || _mm_movemask_ps(rad) != 0) {
        for (int k = 0; k < 4; ++k) {
          const SortRecord copy = in[i + k];
          Pack(copy, &out[i + k]);
        }
        continue;
      }
      const uint64_t keys[4] = {in[i].key, in[i + 1].key, in[i + 2].key, in[i + 3].key};
      // Cell: Nearest on each axis, bit 63 the two-sided flag (the radius's sign).
      const __m128i qx = nearest4(px, 0), qy = nearest4(py, 1), qz = nearest4(pz, 2);
      const __m128i cell_lo = _mm_or_si128(qx, _mm_slli_epi32(qy, 21));
      const __m128i cell_hi =
          _mm_or_si128(_mm_or_si128(_mm_srli_epi32(qy, 11), _mm_slli_epi32(qz, 10)),
                       _mm_and_si128(_mm_castps_si128(rad), _mm_castps_si128(sign)));
      // Normal: EncodeOctahedral. Times +-1 is a sign flip, exact; x and y are finite here.
      const __m128 x = _mm_div_ps(nx, l1n), y = _mm_div_ps(ny, l1n);
      const __m128 fold = _mm_cmplt_ps(nz, zero);
      const __m128 ox = _mm_xor_ps(_mm_sub_ps(one, _mm_andnot_ps(sign, y)),
                                   _mm_and_ps(_mm_cmplt_ps(x, zero), sign));
      const __m128 oy = _mm_xor_ps(_mm_sub_ps(one, _mm_andnot_ps(sign, x)),
                                   _mm_and_ps(_mm_cmplt_ps(y, zero), sign));
      // RoundHalfAway(clamp(v, -1, 1) * 32767) in float: |v * 32767| < 2^15, so the truncation
      // and its remainder are exact, as in double.
      auto octahedral = [&](__m128 v) {
        const __m128 c =
            _mm_mul_ps(_mm_min_ps(_mm_max_ps(v, _mm_set1_ps(-1.0f)), one), _mm_set1_ps(32767.0f));
        const __m128i q = _mm_cvttps_epi32(c);
        const __m128 f = _mm_sub_ps(c, _mm_cvtepi32_ps(q));
        return _mm_add_epi32(_mm_sub_epi32(q, _mm_castps_si128(_mm_cmpge_ps(f, _mm_set1_ps(0.5f)))),
                             _mm_castps_si128(_mm_cmple_ps(f, _mm_set1_ps(-0.5f))));
      };
      const __m128i o0 = octahedral(_mm_or_ps(_mm_and_ps(fold, ox), _mm_andnot_ps(fold, x)));
      const __m128i o1 = octahedral(_mm_or_ps(_mm_and_ps(fold, oy), _mm_andnot_ps(fold, y)));
      const __m128i w2 =
          _mm_or_si128(_mm_and_si128(o0, _mm_set1_epi32(0xffff)), _mm_slli_epi32(o1, 16));
      // Radius (EncodeRadius16, flushed to the smallest code) and radiance (EncodeRadiance16).
      const __m128i r16 = small_float(_mm_andnot_ps(sign, rad), 10, 1 << 10);
      __m128i w3 = r16, w4 = _mm_setzero_si128();
      if (radiance) {
        w3 = _mm_or_si128(r16, _mm_slli_epi32(radiance16(l0), 16));
        w4 = _mm_or_si128(radiance16(l1), _mm_slli_epi32(radiance16(l2), 16));
      }
      __m128 a0 = _mm_castsi128_ps(cell_lo), a1 = _mm_castsi128_ps(cell_hi);
      __m128 a2 = _mm_castsi128_ps(w2), a3 = _mm_castsi128_ps(w3);
      _MM_TRANSPOSE4_PS(a0, a1, a2, a3);
      const __m128 rows[4] = {a0, a1, a2, a3};
      uint32_t tail[4];
      _mm_storeu_si128(reinterpret_cast<__m128i*>(tail), w4);
      for (int k = 0; k < 4; ++k) {
        uint8_t* o = reinterpret_cast<uint8_t*>(&out[i + k]);
        std::memcpy(o, &keys[k], 8);
        _mm_storeu_ps(reinterpret_cast<float*>(o + 8), rows[k]);
        std::memcpy(o + 24, &tail[k], 4);
        _mm_storeu_ps(reinterpret_cast<float*>(o + 28), zero);
        _mm_storeu_ps(reinterpret_cast<float*>(o + 32), zero);
      }
    }
  }
#endif
  for (; i < n; ++i) {
    const SortRecord copy = in[i];
    Pack(copy, &out[i]);
  }
}

// UnpackBlock's stores: a record's floats from byte 8 on, in this order.
static_assert(offsetof(SortRecord, position) == 8 && offsetof(SortRecord, normal) == 20 &&
              offsetof(SortRecord, radius) == 32 && offsetof(SortRecord, radiance) == 36);

void SpillCodec::UnpackBlock(const SortRecord* packed, size_t n, SortRecord* out) const {
  size_t i = 0;
#if defined(__SSE2__)
  // Each lane makes the IEEE operations of DecodePointRecord and MakeSortRecord in the same
  // order (no FMA on the x86-64 baseline), so every float is bit-identical; the branches become
  // masks. Four records are loaded as rows (bytes 0-15 of the point record: cell, normal, radius,
  // first radiance code) and transposed into one field per register.
  const __m128i m21 = _mm_set1_epi32(static_cast<int>(kGridMax));
  const __m128i m16 = _mm_set1_epi32(0xffff);
  const __m128 sign = _mm_castsi128_ps(_mm_set1_epi32(static_cast<int>(0x80000000u)));
  const __m128 half = _mm_set1_ps(0.5f), one = _mm_set1_ps(1.0f), zero = _mm_setzero_ps();
  const __m128 unit = _mm_set1_ps(1.0f / 32767.0f);
  const __m128 step = _mm_set1_ps(grid.step);
  const bool radiance = HasRadiance(channels);
  // DecodeSmallFloat<6, M>: exponent e (0: zero), bits (e - 32 + 127) << 23 | mantissa << (23 - M).
  auto small_float = [](__m128i e, __m128i mant_bits) {
    const __m128i bits =
        _mm_or_si128(_mm_slli_epi32(_mm_add_epi32(e, _mm_set1_epi32(127 - 32)), 23), mant_bits);
    return _mm_castsi128_ps(_mm_andnot_si128(_mm_cmpeq_epi32(e, _mm_setzero_si128()), bits));
  };
  for (; i + 4 <= n; i += 4) {
    __m128 r0 = _mm_castsi128_ps(
        _mm_loadu_si128(reinterpret_cast<const __m128i*>(PackedBytes(&packed[i]))));
    __m128 r1 = _mm_castsi128_ps(
        _mm_loadu_si128(reinterpret_cast<const __m128i*>(PackedBytes(&packed[i + 1]))));
    __m128 r2 = _mm_castsi128_ps(
        _mm_loadu_si128(reinterpret_cast<const __m128i*>(PackedBytes(&packed[i + 2]))));
    __m128 r3 = _mm_castsi128_ps(
        _mm_loadu_si128(reinterpret_cast<const __m128i*>(PackedBytes(&packed[i + 3]))));
    _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
    const __m128i cell_lo = _mm_castps_si128(r0), cell_hi = _mm_castps_si128(r1);
    const __m128i oct = _mm_castps_si128(r2), w3 = _mm_castps_si128(r3);
    // Position: Coord(q) = origin + (q + 0.5) * step per axis.
    const __m128i qx = _mm_and_si128(cell_lo, m21);
    const __m128i qy =
        _mm_and_si128(_mm_or_si128(_mm_srli_epi32(cell_lo, 21), _mm_slli_epi32(cell_hi, 11)), m21);
    const __m128i qz = _mm_and_si128(_mm_srli_epi32(cell_hi, 10), m21);
    const __m128 px = _mm_add_ps(_mm_set1_ps(grid.origin[0]),
                                 _mm_mul_ps(_mm_add_ps(_mm_cvtepi32_ps(qx), half), step));
    const __m128 py = _mm_add_ps(_mm_set1_ps(grid.origin[1]),
                                 _mm_mul_ps(_mm_add_ps(_mm_cvtepi32_ps(qy), half), step));
    const __m128 pz = _mm_add_ps(_mm_set1_ps(grid.origin[2]),
                                 _mm_mul_ps(_mm_add_ps(_mm_cvtepi32_ps(qz), half), step));
    // Normal: DecodeOctahedral. Times +-1 is a sign flip, exact.
    const __m128 x = _mm_mul_ps(_mm_cvtepi32_ps(_mm_srai_epi32(_mm_slli_epi32(oct, 16), 16)), unit);
    const __m128 y = _mm_mul_ps(_mm_cvtepi32_ps(_mm_srai_epi32(oct, 16)), unit);
    const __m128 ax = _mm_andnot_ps(sign, x), ay = _mm_andnot_ps(sign, y);
    const __m128 z = _mm_sub_ps(_mm_sub_ps(one, ax), ay);
    const __m128 fold = _mm_cmplt_ps(z, zero);
    const __m128 ox = _mm_xor_ps(_mm_sub_ps(one, ay), _mm_and_ps(_mm_cmplt_ps(x, zero), sign));
    const __m128 oy = _mm_xor_ps(_mm_sub_ps(one, ax), _mm_and_ps(_mm_cmplt_ps(y, zero), sign));
    const __m128 nx0 = _mm_or_ps(_mm_and_ps(fold, ox), _mm_andnot_ps(fold, x));
    const __m128 ny0 = _mm_or_ps(_mm_and_ps(fold, oy), _mm_andnot_ps(fold, y));
    const __m128 len2 =
        _mm_add_ps(_mm_add_ps(_mm_mul_ps(nx0, nx0), _mm_mul_ps(ny0, ny0)), _mm_mul_ps(z, z));
    const __m128 inv = _mm_div_ps(one, _mm_sqrt_ps(len2));
    const __m128 nx = _mm_mul_ps(nx0, inv), ny = _mm_mul_ps(ny0, inv), nz = _mm_mul_ps(z, inv);
    // Radius: DecodeRadius16, the two-sided flag (cell bit 63) in its sign bit.
    const __m128i rc = _mm_and_si128(w3, m16);
    const __m128 rad =
        _mm_or_ps(small_float(_mm_and_si128(_mm_srli_epi32(rc, 10), _mm_set1_epi32(63)),
                              _mm_slli_epi32(_mm_and_si128(rc, _mm_set1_epi32(1023)), 13)),
                  _mm_and_ps(_mm_castsi128_ps(cell_hi), sign));
    // Radiance: DecodeRadiance16, the code's bit 15 the sign.
    __m128 l0 = zero, l1 = zero, l2 = zero;
    if (radiance) {
      auto radiance16 = [&](__m128i c) {
        const __m128 mag = small_float(_mm_and_si128(_mm_srli_epi32(c, 9), _mm_set1_epi32(63)),
                                       _mm_slli_epi32(_mm_and_si128(c, _mm_set1_epi32(511)), 14));
        return _mm_or_ps(
            mag, _mm_castsi128_ps(_mm_slli_epi32(_mm_and_si128(c, _mm_set1_epi32(0x8000)), 16)));
      };
      uint32_t w4[4];
      for (int k = 0; k < 4; ++k) std::memcpy(&w4[k], PackedBytes(&packed[i + k]) + 16, 4);
      const __m128i l12 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(w4));
      l0 = radiance16(_mm_srli_epi32(w3, 16));
      l1 = radiance16(_mm_and_si128(l12, m16));
      l2 = radiance16(_mm_srli_epi32(l12, 16));
    }
    // Back to records: (position, normal x), (normal y z, radius, radiance 0), (radiance 1 2).
    __m128 a0 = px, a1 = py, a2 = pz, a3 = nx;
    _MM_TRANSPOSE4_PS(a0, a1, a2, a3);
    __m128 b0 = ny, b1 = nz, b2 = rad, b3 = l0;
    _MM_TRANSPOSE4_PS(b0, b1, b2, b3);
    const __m128 c01 = _mm_unpacklo_ps(l1, l2), c23 = _mm_unpackhi_ps(l1, l2);
    const __m128 rows_a[4] = {a0, a1, a2, a3}, rows_b[4] = {b0, b1, b2, b3};
    for (int k = 0; k < 4; ++k) {
      out[i + k].key = packed[i + k].key;
      uint8_t* o = reinterpret_cast<uint8_t*>(&out[i + k]);
      _mm_storeu_ps(reinterpret_cast<float*>(o + 8), rows_a[k]);
      _mm_storeu_ps(reinterpret_cast<float*>(o + 24), rows_b[k]);
    }
    _mm_storel_pi(reinterpret_cast<__m64*>(reinterpret_cast<uint8_t*>(&out[i]) + 40), c01);
    _mm_storeh_pi(reinterpret_cast<__m64*>(reinterpret_cast<uint8_t*>(&out[i + 1]) + 40), c01);
    _mm_storel_pi(reinterpret_cast<__m64*>(reinterpret_cast<uint8_t*>(&out[i + 2]) + 40), c23);
    _mm_storeh_pi(reinterpret_cast<__m64*>(reinterpret_cast<uint8_t*>(&out[i + 3]) + 40), c23);
    // Two-sided records (cell bit 63) hold a sheet tag in their normal: decoded one at a time.
    if (const int two_sided = _mm_movemask_ps(_mm_castsi128_ps(cell_hi)); two_sided != 0) {
      for (int k = 0; k < 4; ++k) {
        if (two_sided & (1 << k)) out[i + k] = Unpack(packed[i + k]);
      }
    }
  }
#endif
  for (; i < n; ++i) out[i] = Unpack(packed[i]);
}

SpillBlockWriter::SpillBlockWriter(const SpillCodec& codec) : codec_(codec) {}
SpillBlockWriter::~SpillBlockWriter() { ZSTD_freeCCtx(static_cast<ZSTD_CCtx*>(cctx_)); }

template <typename Record>
absl::StatusOr<size_t> SpillBlockWriter::EncodeBlock(size_t n, const Record& record, uint8_t* dst,
                                                     bool packed) {
  if (n == 0 || n > kSpillBlockRecords) {
    return absl::InternalError(absl::StrFormat("a spill block of %d records", n));
  }
  if (cctx_ == nullptr) cctx_ = ZSTD_createCCtx();
  if (cctx_ == nullptr) return absl::ResourceExhaustedError("zstd: no memory for a context");
  const bool radiance = HasRadiance(codec_.channels);
  const bool back = codec_.channels == Channels::kRadianceBothSides;
  const Columns c(n, codec_.channels);
  raw_.resize(c.end);
  uint8_t* raw = raw_.data();
  uint64_t prev = 0;
  uint8_t encoded[kPointRecordBothSidesBytes];
  for (size_t i = 0; i < n; ++i) {
    const SortRecord& r = record(i);
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
    if (back) std::memcpy(raw + c.back + 6 * i, rec + 20, 6);
  }
  const size_t z = ZSTD_compressCCtx(static_cast<ZSTD_CCtx*>(cctx_), dst + kSpillBlockHeaderBytes,
                                     codec_.max_block_bytes() - kSpillBlockHeaderBytes, raw, c.end,
                                     kSpillZstdLevel);
  if (ZSTD_isError(z)) {
    return absl::InternalError(
        absl::StrFormat("zstd cannot compress a sort run block: %s", ZSTD_getErrorName(z)));
  }
  PutU32(dst, static_cast<uint32_t>(z));
  PutU32(dst + 4, static_cast<uint32_t>(n));
  return kSpillBlockHeaderBytes + z;
}

absl::StatusOr<size_t> SpillBlockWriter::Encode(absl::Span<const SortRecord> recs, uint8_t* dst,
                                                bool packed) {
  return EncodeBlock(
      recs.size(), [&](size_t i) -> const SortRecord& { return recs[i]; }, dst, packed);
}

absl::StatusOr<size_t> SpillBlockWriter::EncodeGathered(const SortRecord* base,
                                                        absl::Span<const KeyIndex> order,
                                                        uint8_t* dst, bool packed) {
  const size_t n = order.size();
  return EncodeBlock(
      n,
      [&](size_t i) -> const SortRecord& {
        // The gather is random access: fetch a few records ahead.
        if (i + 16 < n) __builtin_prefetch(&base[order[i + 16].index]);
        return base[order[i].index];
      },
      dst, packed);
}

absl::Status SpillBlockWriter::Append(absl::Span<const SortRecord> recs, std::vector<uint8_t>* out,
                                      bool packed) {
  const size_t at = out->size();
  out->resize(at + codec_.max_block_bytes());
  absl::StatusOr<size_t> n = Encode(recs, out->data() + at, packed);
  out->resize(at + (n.ok() ? *n : 0));
  return n.status();
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
  const bool back = codec_.channels == Channels::kRadianceBothSides;
  const Columns c(records, codec_.channels);
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
  uint8_t plain[kPointRecordBothSidesBytes];
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
    if (back) std::memcpy(rec + 20, raw + c.back + 6 * size_t{i}, 6);
    if (packed) {
      out[i].key = key;
    } else {
      out[i] = MakeSortRecord(key, DecodePointRecord(rec, codec_.channels, codec_.grid));
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
