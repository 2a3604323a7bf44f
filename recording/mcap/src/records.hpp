// Byte-level pieces of MCAP records (little endian; strings and byte arrays with a uint32 length; maps with a uint32
// byte length). Internal to the MCAP library.
#pragma once

#include <cstdint>
#include <cstring>
#include <map>
#include <stdexcept>
#include <string>

namespace cellcal::mcap::detail {

inline constexpr char kMagic[8] = {'\x89', 'M', 'C', 'A', 'P', '0', '\r', '\n'};
enum Op : std::uint8_t {
  kHeader = 0x01, kFooter = 0x02, kSchema = 0x03, kChannel = 0x04, kMessage = 0x05, kChunk = 0x06,
  kMessageIndex = 0x07, kChunkIndex = 0x08, kAttachment = 0x09, kAttachmentIndex = 0x0A, kStatistics = 0x0B,
  kMetadata = 0x0C, kMetadataIndex = 0x0D, kSummaryOffset = 0x0E, kDataEnd = 0x0F
};

struct Out {
  std::string b;
  template <typename T>
  void u(T v) {
    for (std::size_t i = 0; i < sizeof(T); ++i) b.push_back(static_cast<char>((static_cast<std::uint64_t>(v) >> (8 * i)) & 0xff));
  }
  void str(const std::string& s) {
    u<std::uint32_t>(static_cast<std::uint32_t>(s.size()));
    b += s;
  }
  void stringMap(const std::map<std::string, std::string>& m) {
    Out o;
    for (const auto& [k, v] : m) {
      o.str(k);
      o.str(v);
    }
    str(o.b);
  }
  template <typename K>
  void u64Map(const std::map<K, std::uint64_t>& m) {
    Out o;
    for (const auto& [k, v] : m) {
      o.u<K>(k);
      o.u<std::uint64_t>(v);
    }
    str(o.b);
  }
};

// Reads fields of one record; running past its end throws (caught by the reader, which names file and offset).
struct In {
  const char* p;
  std::size_t n, at = 0;
  In(const char* data, std::size_t size) : p(data), n(size) {}
  explicit In(const std::string& s) : p(s.data()), n(s.size()) {}  // s must outlive the In
  explicit In(std::string&&) = delete;
  void need(std::size_t k) const {
    if (n - at < k) throw std::out_of_range("record shorter than its fields");
  }
  template <typename T>
  T u() {
    need(sizeof(T));
    std::uint64_t v = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) v |= static_cast<std::uint64_t>(static_cast<unsigned char>(p[at + i])) << (8 * i);
    at += sizeof(T);
    return static_cast<T>(v);
  }
  std::string bytes(std::size_t k) {
    need(k);
    std::string s(p + at, k);
    at += k;
    return s;
  }
  std::string str() { return bytes(u<std::uint32_t>()); }
  std::string rest() { return bytes(n - at); }
  std::map<std::string, std::string> stringMap() {
    const std::string bytes = str();
    In m(bytes);
    std::map<std::string, std::string> out;
    while (m.at < m.n) {
      std::string k = m.str();
      out[k] = m.str();
    }
    return out;
  }
  template <typename K>
  std::map<K, std::uint64_t> u64Map() {
    const std::string bytes = str();
    In m(bytes);
    std::map<K, std::uint64_t> out;
    while (m.at < m.n) {
      const K k = m.u<K>();
      out[k] = m.u<std::uint64_t>();
    }
    return out;
  }
};

}  // namespace cellcal::mcap::detail
