// Private to core/src/engine: write(2) until every byte is written (EINTR retried), for the state files.
#pragma once

#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <string>

namespace cellcal::detail {

// Throws std::runtime_error "<path>: write failed: <why>".
inline void writeAll(int fd, const char* data, std::size_t n, const std::string& path) {
  std::size_t off = 0;
  while (off < n) {
    const ssize_t k = ::write(fd, data + off, n - off);
    if (k < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error(path + ": write failed: " + std::strerror(errno));
    }
    off += static_cast<std::size_t>(k);
  }
}

}  // namespace cellcal::detail
