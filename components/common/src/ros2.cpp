#include "cellcal/components/ros2.hpp"

#include <cctype>
#include <cmath>

namespace cellcal::components {

std::optional<std::string> ros2DdsTopic(const std::string& ros_name, std::string* error) {
  auto fail = [&](const std::string& why) -> std::optional<std::string> {
    if (error) *error = "ROS 2 topic '" + ros_name + "': " + why;
    return std::nullopt;
  };
  if (ros_name.empty() || ros_name == "/") return fail("empty");
  const std::string name = ros_name.front() == '/' ? ros_name.substr(1) : ros_name;
  if (name.back() == '/') return fail("ends with '/'");
  bool token_start = true;
  for (char c : name) {
    if (c == '/') {
      if (token_start) return fail("contains '//'");
      token_start = true;
      continue;
    }
    if (c == '~' || c == '{' || c == '}') return fail("'~' and substitutions need a ROS 2 node to resolve them");
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_'))
      return fail(std::string("character '") + c + "' (letters, digits, '_' and '/' only)");
    if (token_start && std::isdigit(static_cast<unsigned char>(c))) return fail("a name part starts with a digit");
    token_start = false;
  }
  return "rt/" + name;
}

std::optional<Eigen::VectorXd> jointPositionsByName(const std::vector<std::string>& msg_names,
                                                    const std::vector<double>& msg_positions,
                                                    const std::vector<std::string>& joint_names, std::string* why) {
  auto fail = [&](const std::string& w) -> std::optional<Eigen::VectorXd> {
    if (why) *why = w;
    return std::nullopt;
  };
  if (msg_names.size() != msg_positions.size())
    return fail(std::to_string(msg_names.size()) + " names but " + std::to_string(msg_positions.size()) + " positions");
  Eigen::VectorXd q(static_cast<Eigen::Index>(joint_names.size()));
  for (size_t j = 0; j < joint_names.size(); ++j) {
    int found = -1;
    for (size_t k = 0; k < msg_names.size(); ++k)
      if (msg_names[k] == joint_names[j]) {
        if (found >= 0) return fail("joint '" + joint_names[j] + "' named twice");
        found = static_cast<int>(k);
      }
    if (found < 0) return fail("no joint '" + joint_names[j] + "'");
    const double v = msg_positions[static_cast<size_t>(found)];
    if (!std::isfinite(v)) return fail("joint '" + joint_names[j] + "': position is not finite");
    q[static_cast<Eigen::Index>(j)] = v;
  }
  return q;
}

StandStillDetector::StandStillDetector(double window_s, double tolerance_rad, double velocity_radps)
    : window_ns_(static_cast<std::int64_t>(window_s * 1e9)),
      tolerance_rad_(tolerance_rad),
      velocity_radps_(velocity_radps) {}

bool StandStillDetector::update(std::int64_t stamp_ns, const Eigen::VectorXd& q_rad,
                                const std::vector<double>& velocity_radps) {
  const bool restart = anchor_q_.size() != q_rad.size() || stamp_ns < last_ns_ ||
                       (q_rad - anchor_q_).cwiseAbs().maxCoeff() > tolerance_rad_;
  if (restart) {
    anchor_q_ = q_rad;
    anchor_ns_ = stamp_ns;
  }
  last_ns_ = stamp_ns;
  for (double v : velocity_radps)
    if (!(std::abs(v) <= velocity_radps_)) return false;
  return !restart && stamp_ns - anchor_ns_ >= window_ns_;
}

}  // namespace cellcal::components
