// The `udp` sources (a bridge for real trackers and controllers; formats in docs/udp-sources.md): a UDP socket that
// yields one text line per reading (datagrams may carry several lines separated by '\n'), and the two line formats.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/files/cell_config.hpp"

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

// A `udp` source's loop: binds address:port and hands each line received to `handle` until SIGINT/SIGTERM or
// duration_s (0: no limit). `handle` returns false with *why for a line it rejects; such a line is counted and
// logged on stderr as "<who>: udp line <n> ignored: <why>", and the loop goes on.
struct UdpLineCounts {
  std::uint64_t lines = 0, bad = 0;
};
UdpLineCounts serveUdpLines(const std::string& who, const std::string& address, int port, double duration_s,
                            const std::function<bool(const std::string& line, std::string* why)>& handle);

// A joint-state line: <robot_id> <stamp_ns|0> <settled 0|1> <q1_rad> ... <qN_rad> (N: the robot file's joints).
struct JointLine {
  const CellRobot* robot = nullptr;
  std::int64_t stamp_ns = 0;  // 0: stamp on arrival
  bool settled = false;
  Eigen::VectorXd q_rad;
};
// A tracker line: <target_id> <stamp_ns|0> <valid 0|1> <x_m> <y_m> <z_m> [<qx> <qy> <qz> <qw>]
// [<sigma_position_m> <sigma_orientation_rad>] (6, 8, 10 or 12 fields).
struct TrackerLine {
  const CellRobot* robot = nullptr;
  std::int64_t stamp_ns = 0;  // 0: stamp on arrival
  bool valid = false;
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();
  std::optional<std::array<double, 4>> orientation_xyzw;
  double sigma_position_m = 0, sigma_orientation_rad = 0;  // 0: not given
};
// nullopt with *why saying which field is wrong (its 1-based number, name and text) or that the robot / target is
// not in the cell file.
std::optional<JointLine> parseJointLine(const std::string& line, const CellConfig& cell, std::string* why);
std::optional<TrackerLine> parseTrackerLine(const std::string& line, const CellConfig& cell, std::string* why);

// Splits on blanks.
std::vector<std::string> splitFields(const std::string& line);
// Strict number parsing: the whole field must be a finite number ("nan"/"inf" rejected).
bool parseDouble(const std::string& field, double* out);
bool parseInt64(const std::string& field, std::int64_t* out);

}  // namespace cellcal::components
