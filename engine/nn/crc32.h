// CRC-32 (IEEE 802.3, the polynomial of zlib's crc32 and of the .dncw weights file).
//
// Usage:
//   uint32_t crc = dance::engine::Crc32(bytes);              // whole buffer
//   uint32_t c = Crc32Update(0, part1); c = Crc32Update(c, part2);  // incremental, same result
//
// Thread safety: pure functions, safe from any thread.
#ifndef DANCE_ENGINE_NN_CRC32_H_
#define DANCE_ENGINE_NN_CRC32_H_

#include <cstdint>

#include "absl/types/span.h"

namespace dance::engine {

// Continues a CRC-32 over `bytes`; start with crc = 0. Equal to zlib's crc32(crc, bytes, n).
uint32_t Crc32Update(uint32_t crc, absl::Span<const uint8_t> bytes);

// CRC-32 of `bytes`.
inline uint32_t Crc32(absl::Span<const uint8_t> bytes) { return Crc32Update(0, bytes); }

}  // namespace dance::engine

#endif  // DANCE_ENGINE_NN_CRC32_H_
