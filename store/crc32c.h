// CRC-32C (Castagnoli), the checksum of every page. This Abseil has no absl/crc, so the store
// carries its own: the SSE4.2 crc32 instruction when the CPU has it (chosen once, at run time),
// a portable slicing-by-8 table otherwise. Both give identical results; tests check both against
// the published check value CRC-32C("123456789") = 0xE3069283.
#ifndef PBGI_STORE_CRC32C_H_
#define PBGI_STORE_CRC32C_H_

#include <cstddef>
#include <cstdint>

namespace pbgi::internal {

// Extends `crc` (the CRC-32C of some earlier bytes, 0 for none) with `n` bytes:
// Crc32c(Crc32c(0, a), b) == Crc32c(0, a + b). Uses the fastest available implementation.
uint32_t Crc32c(uint32_t crc, const void* data, size_t n);

// The portable implementation (slicing-by-8 tables).
uint32_t Crc32cPortable(uint32_t crc, const void* data, size_t n);

// Whether this CPU has the SSE4.2 crc32 instruction.
bool Crc32cHardwareAvailable();

// The SSE4.2 implementation: three interleaved streams for long inputs.
// REQUIRES: Crc32cHardwareAvailable().
uint32_t Crc32cHardware(uint32_t crc, const void* data, size_t n);

}  // namespace pbgi::internal

#endif  // PBGI_STORE_CRC32C_H_
