#include "store/crc32c.h"

#include <cstring>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "tests/store/store_test_util.h"

namespace pbgi::internal {
namespace {

using Fn = uint32_t (*)(uint32_t, const void*, size_t);

struct Impl {
  const char* name;
  Fn fn;
};

std::vector<Impl> Implementations() {
  std::vector<Impl> v = {{"portable", &Crc32cPortable}, {"dispatch", &Crc32c}};
  if (Crc32cHardwareAvailable()) v.push_back({"hardware", &Crc32cHardware});
  return v;
}

// Bit-at-a-time reference, straight from the definition (reflected polynomial 0x82F63B78).
uint32_t Reference(const uint8_t* p, size_t n) {
  uint32_t c = ~0u;
  for (size_t i = 0; i < n; ++i) {
    c ^= p[i];
    for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ 0x82F63B78u : c >> 1;
  }
  return ~c;
}

TEST(Crc32cTest, HardwareIsPresentOnThisMachine) {
  // The CI machines are x86-64 with SSE4.2; if this fails the fast path is silently unused.
#if defined(__x86_64__)
  EXPECT_TRUE(Crc32cHardwareAvailable());
#endif
}

TEST(Crc32cTest, KnownVectors) {
  for (const Impl& impl : Implementations()) {
    SCOPED_TRACE(impl.name);
    EXPECT_EQ(impl.fn(0, "123456789", 9), 0xE3069283u);
    EXPECT_EQ(impl.fn(0, "", 0), 0u);
    // RFC 3720 (iSCSI) B.4 test vectors.
    std::vector<uint8_t> zeros(32, 0), ones(32, 0xff), inc(32), dec(32);
    for (int i = 0; i < 32; ++i) {
      inc[i] = static_cast<uint8_t>(i);
      dec[i] = static_cast<uint8_t>(31 - i);
    }
    EXPECT_EQ(impl.fn(0, zeros.data(), 32), 0x8A9136AAu);
    EXPECT_EQ(impl.fn(0, ones.data(), 32), 0x62A8AB43u);
    EXPECT_EQ(impl.fn(0, inc.data(), 32), 0x46DD794Eu);
    EXPECT_EQ(impl.fn(0, dec.data(), 32), 0x113FDB5Cu);
  }
}

TEST(Crc32cTest, AllLengthsAndAlignmentsMatchTheBitwiseReference) {
  // Long enough for the three-way 8 KiB and 256-byte interleaved loops and every tail.
  std::vector<uint8_t> buf(3 * 8192 * 2 + 3 * 256 + 64);
  for (size_t i = 0; i < buf.size(); ++i) {
    buf[i] = static_cast<uint8_t>(testing_store::SplitMix(i) >> 13);
  }
  std::vector<size_t> lengths;
  for (size_t n = 0; n <= 70; ++n) lengths.push_back(n);
  for (size_t n : {767u, 768u, 769u, 1000u, 4080u, 24575u, 24576u, 24577u, 49152u, 50000u}) {
    lengths.push_back(n);
  }
  for (const Impl& impl : Implementations()) {
    SCOPED_TRACE(impl.name);
    for (size_t offset = 0; offset < 8; ++offset) {
      for (size_t n : lengths) {
        if (offset + n > buf.size()) continue;
        ASSERT_EQ(impl.fn(0, buf.data() + offset, n), Reference(buf.data() + offset, n))
            << "offset " << offset << " length " << n;
      }
    }
  }
}

TEST(Crc32cTest, ExtendEqualsWhole) {
  std::vector<uint8_t> buf(100000);
  for (size_t i = 0; i < buf.size(); ++i) buf[i] = static_cast<uint8_t>(i * 7 + (i >> 9));
  for (const Impl& impl : Implementations()) {
    SCOPED_TRACE(impl.name);
    const uint32_t whole = impl.fn(0, buf.data(), buf.size());
    for (size_t cut : {size_t{0}, size_t{1}, size_t{4095}, size_t{24576}, size_t{99999}}) {
      const uint32_t a = impl.fn(0, buf.data(), cut);
      EXPECT_EQ(impl.fn(a, buf.data() + cut, buf.size() - cut), whole) << "cut " << cut;
    }
  }
}

TEST(Crc32cTest, DetectsEverySingleBitFlip) {
  std::vector<uint8_t> buf(4096 - 16);
  for (size_t i = 0; i < buf.size(); ++i) buf[i] = static_cast<uint8_t>(i);
  const uint32_t good = Crc32c(0, buf.data(), buf.size());
  for (size_t i = 0; i < buf.size(); i += 37) {
    for (int bit = 0; bit < 8; ++bit) {
      buf[i] ^= static_cast<uint8_t>(1 << bit);
      ASSERT_NE(Crc32c(0, buf.data(), buf.size()), good) << "byte " << i << " bit " << bit;
      buf[i] ^= static_cast<uint8_t>(1 << bit);
    }
  }
}

}  // namespace
}  // namespace pbgi::internal
