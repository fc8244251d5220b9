#include "store/crc32c.h"

#include <array>
#include <bit>
#include <cstring>

#if defined(__x86_64__)
#include <nmmintrin.h>
#endif

namespace pbgi::internal {
namespace {

static_assert(std::endian::native == std::endian::little,
              "the slicing-by-8 and word-at-a-time paths assume a little-endian CPU");

// The Castagnoli polynomial, bit-reflected (bit 31 - k holds the coefficient of x^k).
constexpr uint32_t kPoly = 0x82F63B78u;

using Table = std::array<std::array<uint32_t, 256>, 8>;

// Slicing-by-8: table[0] is the classic byte table; table[k][b] is the register after byte b is
// followed by k zero bytes, so eight table look-ups consume eight input bytes at once.
constexpr Table MakeSlicingTables() {
  Table t{};
  for (uint32_t b = 0; b < 256; ++b) {
    uint32_t c = b;
    for (int i = 0; i < 8; ++i) c = (c & 1) ? (c >> 1) ^ kPoly : c >> 1;
    t[0][b] = c;
  }
  for (int k = 1; k < 8; ++k) {
    for (uint32_t b = 0; b < 256; ++b) {
      uint32_t c = t[k - 1][b];
      t[k][b] = (c >> 8) ^ t[0][c & 0xff];
    }
  }
  return t;
}
constexpr Table kSlicing = MakeSlicingTables();

// Product of two polynomials modulo the CRC polynomial, both bit-reflected.
constexpr uint32_t MultModP(uint32_t a, uint32_t b) {
  uint32_t m = 1u << 31;
  uint32_t p = 0;
  while (m != 0) {
    if (a & m) p ^= b;
    m >>= 1;
    b = (b & 1) ? (b >> 1) ^ kPoly : b >> 1;
  }
  return p;
}

// x^(8n) modulo the polynomial: the operator "append n zero bytes" on a raw CRC register.
constexpr uint32_t XPow8N(uint64_t n) {
  uint32_t result = 1u << 31;  // x^0
  uint32_t base = 1u << 23;    // x^8
  while (n != 0) {
    if (n & 1) result = MultModP(result, base);
    base = MultModP(base, base);
    n >>= 1;
  }
  return result;
}

// The linear map reg -> reg * x^(8n) mod P as four byte tables, so that shifting a register
// over n zero bytes costs four look-ups. Used to join interleaved streams: the register after
// A then B is Shift_|B|(register after A) ^ (register of B started from zero).
using ShiftTable = std::array<std::array<uint32_t, 256>, 4>;
constexpr ShiftTable MakeShiftTable(uint64_t n) {
  ShiftTable t{};
  const uint32_t xn = XPow8N(n);
  for (int k = 0; k < 4; ++k) {
    for (uint32_t b = 0; b < 256; ++b) t[k][b] = MultModP(xn, b << (8 * k));
  }
  return t;
}

inline uint32_t Shift(const ShiftTable& t, uint32_t reg) {
  return t[0][reg & 0xff] ^ t[1][(reg >> 8) & 0xff] ^ t[2][(reg >> 16) & 0xff] ^ t[3][reg >> 24];
}

// Stream lengths for the three-way interleaved hardware loop. The crc32 instruction has a
// latency of three cycles and a throughput of one per cycle, so three independent streams keep
// it busy; long blocks amortize the join, short blocks serve the tail of a page.
constexpr size_t kLongStream = 8192;
constexpr size_t kShortStream = 256;
constexpr ShiftTable kShiftLong = MakeShiftTable(kLongStream);
constexpr ShiftTable kShiftShort = MakeShiftTable(kShortStream);

#if defined(__x86_64__)

__attribute__((target("sse4.2"))) inline uint64_t HwStreams(uint64_t reg, const uint8_t* p,
                                                            size_t stream, const ShiftTable& t) {
  uint64_t c0 = reg, c1 = 0, c2 = 0;
  const uint8_t* p1 = p + stream;
  const uint8_t* p2 = p + 2 * stream;
  for (size_t i = 0; i < stream; i += 8) {
    uint64_t w0, w1, w2;
    std::memcpy(&w0, p + i, 8);
    std::memcpy(&w1, p1 + i, 8);
    std::memcpy(&w2, p2 + i, 8);
    c0 = _mm_crc32_u64(c0, w0);
    c1 = _mm_crc32_u64(c1, w1);
    c2 = _mm_crc32_u64(c2, w2);
  }
  uint32_t r = Shift(t, static_cast<uint32_t>(c0)) ^ static_cast<uint32_t>(c1);
  return Shift(t, r) ^ static_cast<uint32_t>(c2);
}

__attribute__((target("sse4.2"))) uint32_t HwCrc(uint32_t crc, const uint8_t* p, size_t n) {
  uint64_t reg = ~crc;
  while (n != 0 && (reinterpret_cast<uintptr_t>(p) & 7) != 0) {
    reg = _mm_crc32_u8(static_cast<uint32_t>(reg), *p++);
    --n;
  }
  while (n >= 3 * kLongStream) {
    reg = HwStreams(reg, p, kLongStream, kShiftLong);
    p += 3 * kLongStream;
    n -= 3 * kLongStream;
  }
  while (n >= 3 * kShortStream) {
    reg = HwStreams(reg, p, kShortStream, kShiftShort);
    p += 3 * kShortStream;
    n -= 3 * kShortStream;
  }
  while (n >= 8) {
    uint64_t w;
    std::memcpy(&w, p, 8);
    reg = _mm_crc32_u64(reg, w);
    p += 8;
    n -= 8;
  }
  while (n != 0) {
    reg = _mm_crc32_u8(static_cast<uint32_t>(reg), *p++);
    --n;
  }
  return ~static_cast<uint32_t>(reg);
}

bool DetectHardware() { return __builtin_cpu_supports("sse4.2"); }

#else

uint32_t HwCrc(uint32_t crc, const uint8_t* p, size_t n) { return Crc32cPortable(crc, p, n); }
bool DetectHardware() { return false; }

#endif

const bool kHaveHardware = DetectHardware();

}  // namespace

uint32_t Crc32cPortable(uint32_t crc, const void* data, size_t n) {
  const auto* p = static_cast<const uint8_t*>(data);
  uint32_t reg = ~crc;
  while (n != 0 && (reinterpret_cast<uintptr_t>(p) & 7) != 0) {
    reg = (reg >> 8) ^ kSlicing[0][(reg ^ *p++) & 0xff];
    --n;
  }
  while (n >= 8) {
    uint64_t v;
    std::memcpy(&v, p, 8);
    v ^= reg;
    reg = kSlicing[7][v & 0xff] ^ kSlicing[6][(v >> 8) & 0xff] ^ kSlicing[5][(v >> 16) & 0xff] ^
          kSlicing[4][(v >> 24) & 0xff] ^ kSlicing[3][(v >> 32) & 0xff] ^
          kSlicing[2][(v >> 40) & 0xff] ^ kSlicing[1][(v >> 48) & 0xff] ^ kSlicing[0][v >> 56];
    p += 8;
    n -= 8;
  }
  while (n != 0) {
    reg = (reg >> 8) ^ kSlicing[0][(reg ^ *p++) & 0xff];
    --n;
  }
  return ~reg;
}

bool Crc32cHardwareAvailable() { return kHaveHardware; }

uint32_t Crc32cHardware(uint32_t crc, const void* data, size_t n) {
  return HwCrc(crc, static_cast<const uint8_t*>(data), n);
}

uint32_t Crc32c(uint32_t crc, const void* data, size_t n) {
  return kHaveHardware ? HwCrc(crc, static_cast<const uint8_t*>(data), n)
                       : Crc32cPortable(crc, data, n);
}

}  // namespace pbgi::internal
