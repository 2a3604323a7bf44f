// Writes an MCAP file with random content (channels, payload sizes, times from the seed) and, beside it, the truth as
// JSON for a reader written by others (mcap_independent_reader.mjs, @mcap/core) to compare with.
//   mcap_sample_writer OUT.mcap OUT.json SEED
#include <cstdio>
#include <fstream>
#include <random>
#include <string>

#include "cellcal/mcap/mcap.hpp"

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr, "usage: mcap_sample_writer OUT.mcap OUT.json SEED\n");
    return 2;
  }
  std::mt19937_64 rng(std::stoull(argv[3]));
  cellcal::mcap::WriterOptions o;
  o.chunk_size_bytes = 512 + rng() % 4096;
  cellcal::mcap::Writer w(argv[1], o);
  const auto s = w.addSchema("cellcal::msg::Sample", "omgidl", "module cellcal { module msg { struct Sample { long a; }; }; };");
  const int channels = 1 + static_cast<int>(rng() % 4);
  for (int c = 0; c < channels; ++c)
    w.addChannel(s, "cellcal/sample_" + std::to_string(c), "cdr", {{"index", std::to_string(c)}});
  const int n = 50 + static_cast<int>(rng() % 500);
  std::uint64_t t = 1'700'000'000'000'000'000ULL, bytes = 0, first_sum = 0;
  for (int i = 0; i < n; ++i) {
    cellcal::mcap::Message m;
    m.channel_id = static_cast<std::uint16_t>(rng() % channels);
    m.sequence = static_cast<std::uint32_t>(i);
    t += 1 + rng() % 5'000'000;
    m.log_time_ns = t;
    m.publish_time_ns = t - rng() % 1000;
    m.data.resize(rng() % 200);
    for (auto& ch : m.data) ch = static_cast<char>(rng());
    for (unsigned char ch : m.data) first_sum += ch;
    bytes += m.data.size();
    w.write(m);
  }
  w.close();
  std::ofstream(argv[2]) << "{\"messages\": " << n << ", \"channels\": " << channels << ", \"schemas\": 1, \"payload_bytes\": "
                         << bytes << ", \"payload_byte_sum\": " << first_sum << ", \"last_log_time_ns\": \"" << t << "\"}\n";
  return 0;
}
