#include "cellcal/components/host_limits.hpp"

#include <fstream>
#include <sstream>
#include <vector>

namespace cellcal::components {

std::optional<std::int64_t> readKernelLimit(const std::string& proc_file) {
  std::ifstream in(proc_file);
  std::int64_t v = 0;
  if (!(in >> v)) return std::nullopt;
  return v;
}

std::string socketBufferWarning(const std::string& transport, std::uint32_t receive_bytes, std::uint32_t send_bytes,
                                std::optional<std::int64_t> rmem_max, std::optional<std::int64_t> wmem_max) {
  std::string w;
  auto check = [&](const char* what, std::uint32_t asked, std::optional<std::int64_t> cap, const char* sysctl) {
    if (asked == 0 || !cap || *cap >= static_cast<std::int64_t>(asked)) return;
    w += std::string(w.empty() ? "" : "; ") + "the kernel caps the " + what + " buffer of " + transport +
         " at " + sysctl + " = " + std::to_string(*cap) + " bytes, below the " + std::to_string(asked) +
         " the profile asks for";
  };
  check("UDP receive", receive_bytes, rmem_max, "net.core.rmem_max");
  check("UDP send", send_bytes, wmem_max, "net.core.wmem_max");
  if (!w.empty())
    w += ": a stall of this host longer than the capped buffer holds drops best-effort samples (joint states, "
         "tracker readings) in the kernel. Raise the caps as root: sysctl -p config/sysctl/60-cellcal.conf "
         "(to keep it, copy the file to /etc/sysctl.d/; docs/deployment.md)";
  return w;
}

std::optional<std::uint64_t> udpReceiveBufferErrors(const std::string& snmp_file) {
  // Two "Udp:" lines: the field names, then the values.
  std::ifstream in(snmp_file);
  std::string line;
  std::vector<std::string> names;
  while (std::getline(in, line)) {
    if (line.rfind("Udp: ", 0) != 0) continue;
    std::istringstream fields(line.substr(5));
    std::vector<std::string> words;
    for (std::string f; fields >> f;) words.push_back(f);
    if (names.empty()) {
      names = words;
      continue;
    }
    for (size_t i = 0; i < names.size() && i < words.size(); ++i)
      if (names[i] == "RcvbufErrors") {
        try {
          return std::stoull(words[i]);
        } catch (const std::exception&) {
          return std::nullopt;
        }
      }
    return std::nullopt;
  }
  return std::nullopt;
}

}  // namespace cellcal::components
