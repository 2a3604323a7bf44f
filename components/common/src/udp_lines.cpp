#include "cellcal/components/udp_lines.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <iostream>
#include <sstream>
#include <stdexcept>

#include "cellcal/components/process.hpp"

namespace cellcal::components {

UdpLineSocket::UdpLineSocket(const std::string& address, int port) : port_(port) {
  fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd_ < 0) throw std::runtime_error(std::string("udp: socket: ") + std::strerror(errno));
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(port));
  if (::inet_pton(AF_INET, address.c_str(), &a.sin_addr) != 1) {
    ::close(fd_);
    throw std::runtime_error("udp: '" + address + "' is not an IPv4 address");
  }
  if (::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    const std::string e = std::strerror(errno);
    ::close(fd_);
    throw std::runtime_error("udp: cannot bind " + address + ":" + std::to_string(port) + ": " + e);
  }
  socklen_t len = sizeof a;
  if (::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len) == 0) port_ = ntohs(a.sin_port);
}

UdpLineSocket::~UdpLineSocket() {
  if (fd_ >= 0) ::close(fd_);
}

std::vector<std::string> UdpLineSocket::receive(int timeout_ms) {
  std::vector<std::string> lines;
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, timeout_ms) <= 0) return lines;
  char buf[65536];
  for (;;) {
    const ssize_t n = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
    if (n <= 0) break;
    std::istringstream in(std::string(buf, static_cast<size_t>(n)));
    std::string line;
    while (std::getline(in, line)) {
      if (!line.empty() && line.back() == '\r') line.pop_back();
      if (line.find_first_not_of(" \t") != std::string::npos) lines.push_back(line);
    }
  }
  return lines;
}

std::vector<std::string> splitFields(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> out;
  std::string f;
  while (in >> f) out.push_back(f);
  return out;
}

bool parseDouble(const std::string& f, double* out) {
  if (f.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(f.c_str(), &end);
  if (*end != '\0' || errno == ERANGE || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

bool parseInt64(const std::string& f, std::int64_t* out) {
  if (f.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(f.c_str(), &end, 10);
  if (*end != '\0' || errno == ERANGE) return false;
  *out = v;
  return true;
}

namespace {

// Fields 2 and 3 of every line: <stamp_ns|0> <flag 0|1>. Empty when both are good, else what is wrong.
std::string parseStampAndFlag(const std::vector<std::string>& f, const char* flag_name, std::int64_t* stamp_ns,
                              bool* flag) {
  std::int64_t v = 0;
  if (!parseInt64(f[1], stamp_ns) || *stamp_ns < 0)
    return "field 2 (stamp_ns): '" + f[1] + "' is not a non-negative integer";
  if (!parseInt64(f[2], &v) || (v != 0 && v != 1))
    return std::string("field 3 (") + flag_name + "): expected 0 or 1, got '" + f[2] + "'";
  *flag = v == 1;
  return "";
}

}  // namespace

std::optional<JointLine> parseJointLine(const std::string& line, const CellConfig& cell, std::string* why) {
  const auto fail = [why](const std::string& w) {
    if (why) *why = w;
    return std::nullopt;
  };
  const auto f = splitFields(line);
  JointLine out;
  out.robot = f.empty() ? nullptr : cell.robotById(f[0]);
  if (!out.robot) return fail(f.empty() ? "empty line" : "unknown robot_id '" + f[0] + "'");
  const int joints = out.robot->model.numJoints();
  if (static_cast<int>(f.size()) != 3 + joints)
    return fail("expected 3 + " + std::to_string(joints) + " fields, got " + std::to_string(f.size()));
  if (const std::string w = parseStampAndFlag(f, "settled", &out.stamp_ns, &out.settled); !w.empty()) return fail(w);
  out.q_rad.resize(joints);
  for (int j = 0; j < joints; ++j)
    if (!parseDouble(f[3 + j], &out.q_rad[j]))
      return fail("field " + std::to_string(4 + j) + " (q" + std::to_string(j + 1) + "_rad): '" + f[3 + j] +
                  "' is not a finite number");
  return out;
}

std::optional<TrackerLine> parseTrackerLine(const std::string& line, const CellConfig& cell, std::string* why) {
  const auto fail = [why](const std::string& w) {
    if (why) *why = w;
    return std::nullopt;
  };
  const auto f = splitFields(line);
  TrackerLine out;
  out.robot = f.empty() ? nullptr : cell.robotByTarget(f[0]);
  if (!out.robot) return fail(f.empty() ? "empty line" : "unknown target_id '" + f[0] + "'");
  const size_t n = f.size();
  if (n != 6 && n != 8 && n != 10 && n != 12) return fail("expected 6, 8, 10 or 12 fields, got " + std::to_string(n));
  if (const std::string w = parseStampAndFlag(f, "valid", &out.stamp_ns, &out.valid); !w.empty()) return fail(w);
  double v[9] = {0, 0, 0, 0, 0, 0, 1, 0, 0};
  for (size_t k = 3; k < n; ++k)
    if (!parseDouble(f[k], &v[k - 3]))
      return fail("field " + std::to_string(k + 1) + ": '" + f[k] + "' is not a finite number");
  out.position_m = Eigen::Vector3d(v[0], v[1], v[2]);
  if (n >= 10) out.orientation_xyzw = std::array<double, 4>{v[3], v[4], v[5], v[6]};
  out.sigma_position_m = n == 8 ? v[3] : n == 12 ? v[7] : 0;
  out.sigma_orientation_rad = n == 8 ? v[4] : n == 12 ? v[8] : 0;
  return out;
}

UdpLineCounts serveUdpLines(const std::string& who, const std::string& address, int port, double duration_s,
                            const std::function<bool(const std::string&, std::string*)>& handle) {
  UdpLineSocket socket(address, port);
  std::cerr << who << ": udp " << address << ":" << socket.port() << "\n";
  UdpLineCounts counts;
  const RunLimit limit(duration_s);
  while (!limit.over()) {
    for (const std::string& text : socket.receive(50)) {
      ++counts.lines;
      std::string why;
      if (handle(text, &why)) continue;
      ++counts.bad;
      std::cerr << who << ": udp line " << counts.lines << " ignored: " << why << "\n";
    }
  }
  return counts;
}

}  // namespace cellcal::components
