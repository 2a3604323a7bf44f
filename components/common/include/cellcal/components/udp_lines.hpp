// A UDP socket that yields one text line per reading (the `udp` sources: a bridge for real trackers and
// controllers; formats in docs/udp-sources.md). Datagrams may carry several lines separated by '\n'.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace cellcal::components {

class UdpLineSocket {
 public:
  // Binds `address:port` (e.g. 127.0.0.1 or 0.0.0.0). Throws std::runtime_error naming the port on failure.
  UdpLineSocket(const std::string& address, int port);
  ~UdpLineSocket();
  UdpLineSocket(const UdpLineSocket&) = delete;
  UdpLineSocket& operator=(const UdpLineSocket&) = delete;
  // Waits up to timeout_ms; returns the lines received (empty on timeout).
  std::vector<std::string> receive(int timeout_ms);
  int port() const { return port_; }

 private:
  int fd_ = -1;
  int port_ = 0;
};

// Splits on blanks.
std::vector<std::string> splitFields(const std::string& line);
// Strict number parsing: the whole field must be a finite number ("nan"/"inf" rejected).
bool parseDouble(const std::string& field, double* out);
bool parseInt64(const std::string& field, std::int64_t* out);

}  // namespace cellcal::components
