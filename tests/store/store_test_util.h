// Helpers shared by the store tests: a scratch directory per test and deterministic page bytes.
#ifndef PBGI_TESTS_STORE_STORE_TEST_UTIL_H_
#define PBGI_TESTS_STORE_STORE_TEST_UTIL_H_

#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/store.h"
#include "tests/common/scratch_dir.h"

namespace pbgi::testing_store {

using ::pbgi::testing_common::ScratchDir;

inline uint64_t SplitMix(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// Deterministic payload of `n` bytes for (section, page_no, seed).
inline std::vector<uint8_t> PagePayload(Section s, uint64_t page_no, size_t n, uint64_t seed = 0) {
  std::vector<uint8_t> p(n);
  uint64_t x = SplitMix(seed * 1000003 + page_no * 2 + (s == Section::kNodes ? 0 : 1));
  for (size_t i = 0; i < n; ++i) {
    if (i % 8 == 0) x = SplitMix(x);
    p[i] = static_cast<uint8_t>(x >> (8 * (i % 8)));
  }
  return p;
}

// Payload size for page `page_no` of a store with `capacity` bytes of payload per page: mostly
// full pages, some partly filled, some empty.
inline size_t PayloadSizeFor(uint64_t page_no, size_t capacity) {
  switch (page_no % 5) {
    case 0:
      return capacity;
    case 1:
      return capacity / 3;
    case 2:
      return 0;
    case 3:
      return capacity - 1;
    default:
      return 17 % (capacity + 1);
  }
}

}  // namespace pbgi::testing_store

#endif  // PBGI_TESTS_STORE_STORE_TEST_UTIL_H_
