// CRC-32 (IEEE 802.3: reflected polynomial 0xEDB88320, initial and final XOR 0xFFFFFFFF; zlib's and MCAP's), for the
// file formats that frame their records with one (the engine's state journal, MCAP). Header-only and dependency-free,
// so a layer that does not link core (recording/mcap) can use it too. Incremental: crc32(b, nb, crc32(a, na)) is the
// CRC of a then b. Check value: crc32("123456789", 9) == 0xCBF43926.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

namespace cellcal {

inline std::uint32_t crc32(const void* data, std::size_t size, std::uint32_t crc = 0) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  const auto* p = static_cast<const unsigned char*>(data);
  crc = ~crc;
  for (std::size_t i = 0; i < size; ++i) crc = table[(crc ^ p[i]) & 0xffu] ^ (crc >> 8);
  return ~crc;
}

}  // namespace cellcal
