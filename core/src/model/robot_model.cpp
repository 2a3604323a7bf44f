#include "cellcal/core/model/robot_model.hpp"

#include <cmath>

#include "cellcal/core/model/se3.hpp"

namespace cellcal {
namespace {
const char* const kJointNames[] = {"theta_offset", "d", "a", "alpha", "beta"};
const char* const kFrameNames[] = {"x", "y", "z", "roll", "pitch", "yaw"};
}  // namespace

bool RobotModel::isLength(int index) const {
  const int n = numJoints();
  if (index < 5 * n) {
    const int k = index % 5;
    return k == 1 || k == 2;
  }
  return ((index - 5 * n) % 6) < 3;
}

// Built by concatenation: the engine names every parameter in each CalibrationState it publishes (latency path), and
// a stream per name cost about 1 us.
std::string RobotModel::paramName(int index) const {
  const int n = numJoints();
  std::string s;
  if (index < 5 * n) {
    s = "joint" + std::to_string(index / 5 + 1) + "." + kJointNames[index % 5];
  } else {
    const int k = index - 5 * n;
    s = std::string(k < 6 ? "base." : "tool.") + kFrameNames[k % 6];
  }
  s += isLength(index) ? "_m" : "_rad";
  return s;
}

std::string RobotModel::paramNameHuman(int index) const {
  std::string s = paramName(index);
  const auto pos = s.rfind('_');
  return s.substr(0, pos) + (isLength(index) ? "_mm" : "_deg");
}

double RobotModel::toHuman(int index, double value_si) const {
  return isLength(index) ? value_si * 1e3 : radToDeg(value_si);
}

bool RobotModel::isCanonical(int index) const {
  const int n = numJoints();
  if (index >= 5 * n) return true;
  const int j = index / 5;
  const int k = index % 5;
  if (k == static_cast<int>(JointParam::kD)) return !parallel_to_next[j];
  if (k == static_cast<int>(JointParam::kBeta)) return parallel_to_next[j];
  return true;
}

std::vector<int> RobotModel::canonicalParams() const {
  std::vector<int> out;
  for (int i = 0; i < numParams(); ++i)
    if (isCanonical(i)) out.push_back(i);
  return out;
}

bool RobotModel::IsValid(std::string* error) const {
  auto fail = [&](const std::string& msg) {
    if (error) *error = "robot '" + name + "': " + msg;
    return false;
  };
  const int n = numJoints();
  if (n < 1) return fail("no joints");
  if (static_cast<int>(limits.size()) != n) return fail("limits must have one entry per joint");
  if (!links.empty() && static_cast<int>(links.size()) != n)
    return fail("links must be empty or have one entry per joint (" + std::to_string(n) + ")");
  if (nominal.size() != numParams()) return fail("parameter vector has the wrong size");
  for (int i = 0; i < nominal.size(); ++i)
    if (!std::isfinite(nominal[i])) return fail(paramName(i) + " is not finite");
  for (int j = 0; j < n; ++j) {
    if (!(limits[j].lower_rad < limits[j].upper_rad))
      return fail("joint" + std::to_string(j + 1) + " limits must satisfy lower < upper");
    if (parallel_to_next[j] && nominal[jointParam(j, JointParam::kD)] != 0.0)
      return fail("joint" + std::to_string(j + 1) + " is parallel_to_next, so its d must be 0 (use beta)");
    if (!parallel_to_next[j] && nominal[jointParam(j, JointParam::kBeta)] != 0.0)
      return fail("joint" + std::to_string(j + 1) + " is not parallel_to_next, so its beta must be 0");
  }
  if (parallel_to_next.back()) return fail("the last joint cannot be parallel_to_next");
  if (!gravity_in_base_mps2.allFinite()) return fail("gravity is not finite");
  return true;
}

RobotModel RobotModel::withParams(const Eigen::VectorXd& params) const {
  RobotModel m = *this;
  m.nominal = params;
  return m;
}

bool RobotModel::withinLimits(const Eigen::VectorXd& q_rad) const {
  if (q_rad.size() != numJoints()) return false;
  for (int j = 0; j < numJoints(); ++j)
    if (q_rad[j] < limits[j].lower_rad || q_rad[j] > limits[j].upper_rad) return false;
  return true;
}

}  // namespace cellcal
