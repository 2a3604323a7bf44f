#include "cellcal/lab/sim_program.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace cellcal {
namespace {
double smoothstep(double x) { return x * x * (3 - 2 * x); }
constexpr int kWorkPoints = 32;
}  // namespace

SimulatedCell makeSimulatedCell(const CellRobot& robot, const SimulationSettings& settings, int index) {
  SimulationConfig c;
  c.seed = settings.seed + 7919ULL * static_cast<std::uint64_t>(index);
  c.base_in_tracker = robot.model.nominal.segment<6>(robot.model.baseParam(FrameParam::kX));
  c.tool_in_flange = robot.model.nominal.segment<6>(robot.model.toolParam(FrameParam::kX));
  if (settings.true_robot) {
    c.true_params = settings.true_robot->model.nominal;
    c.true_frames = settings.true_robot->calibration.has_value();
    c.true_robot_name = settings.true_robot->model.name + " of " + settings.true_robot_file;
  }
  if (settings.effect == Cause::kNone) return SimulatedCell(robot.model, c);
  // The hidden effect, scaled to its RMS joint error over the workspace (configurations drawn from the seed).
  const SimulatedCell plain(robot.model, c);
  std::mt19937_64 rng(c.seed * 1000003ULL + 424243ULL);
  const std::vector<Eigen::VectorXd> qs = plain.randomConfigurations(200, rng);
  const Eigen::VectorXd true0 = plain.trueParams(0.0);
  std::vector<LinkInertia> links = robot.model.links;
  if (settings.effect == Cause::kJointCompliance && links.empty()) links = plausibleLinks(plain.model(), true0, rng);
  c.hidden = scaledHiddenEffect(plain.model(), true0, settings.effect, settings.effect_joint, settings.effect_size_rad,
                                links, qs, rng);
  return SimulatedCell(robot.model, c);
}

std::string simulatedRobotText(const SimulatedCell& cell) {
  const SimulationConfig& c = cell.config();
  char buf[400];
  if (c.true_params) {
    std::snprintf(buf, sizeof buf, "the true robot is %s: its joints%s", c.true_robot_name.c_str(),
                  c.true_frames ? " and frames (a calibrated robot file)" : ", the cell's registration with random frame errors");
  } else {
    std::snprintf(buf, sizeof buf,
                  "a random %s: the robot file's nominal with %.1f-%.1f mm and %.2f-%.2f deg errors on every parameter "
                  "(seed %llu; simulation.true_robot_file names a robot of your own)",
                  cell.model().name.c_str(), c.length_error_min_m * 1e3, c.length_error_max_m * 1e3,
                  radToDeg(c.angle_error_min_rad), radToDeg(c.angle_error_max_rad), static_cast<unsigned long long>(c.seed));
  }
  return buf;
}

SimRobotProgram::SimRobotProgram(const SimulatedCell& cell, const SimulationSettings& s) : s_(s) {
  if (!s.program.empty()) {  // simulation.program_csv: its rows, in order, instead of the random campaigns
    for (const auto& q : s.program)
      if (q.size() != cell.model().numJoints())
        throw std::invalid_argument("simulation.program_csv: a row of " + std::to_string(q.size()) + " joints for " +
                                    cell.model().name);
    campaigns_.push_back(s.program);
  }
  for (int g = 0; g < s.groups && s.program.empty(); ++g) {
    const int n = g == 0 ? s.initial_poses : s.poses_per_group;
    if (g > 0 && s.hours_between_groups * 3600.0 < campaignEnd_s(g - 1) - campaignStart_s(g - 1))
      throw std::invalid_argument("simulation: campaigns overlap (hours_between_groups shorter than a campaign)");
    std::mt19937_64 rng(cell.config().seed * 1000003ULL + static_cast<std::uint64_t>(g) + 17);
    campaigns_.push_back(cell.randomConfigurations(n, rng));
  }
  std::mt19937_64 rng(cell.config().seed * 1000003ULL + 999983ULL);
  work_ = cell.randomConfigurations(kWorkPoints, rng);
}

void SimRobotProgram::offer(std::vector<Eigen::VectorXd> proposal) { proposal_ = std::move(proposal); }

SimRobotState SimRobotProgram::advance(double t) {
  if (decided_.empty()) decided_.assign(campaigns_.size(), 0);
  const SimRobotState where = at(t);  // which campaign and pose t falls in
  if (where.campaign < 0) return where;
  std::vector<Eigen::VectorXd>& poses = campaigns_[static_cast<size_t>(where.campaign)];
  const long long first_id = where.pose_id - where.pose;
  for (int& d = decided_[static_cast<size_t>(where.campaign)]; d <= where.pose; ++d) {
    const auto visited = [&](const Eigen::VectorXd& q) {
      return std::any_of(poses.begin(), poses.begin() + d,
                         [&](const Eigen::VectorXd& p) { return (p - q).cwiseAbs().maxCoeff() < 1e-9; });
    };
    const auto next = std::find_if(proposal_.begin(), proposal_.end(), [&](const Eigen::VectorXd& q) {
      return q.size() == poses[static_cast<size_t>(d)].size() && !visited(q);
    });
    if (next == proposal_.end()) continue;  // none yet, or every one visited: the program's own pose
    poses[static_cast<size_t>(d)] = *next;
    followed_[first_id + d] = *next;
  }
  return at(t);
}

double SimRobotProgram::campaignStart_s(int g) const { return g * s_.hours_between_groups * 3600.0; }
double SimRobotProgram::campaignEnd_s(int g) const { return campaignStart_s(g) + posesIn(g) * s_.pose_time_s; }

Eigen::VectorXd SimRobotProgram::workAt(double t) const {
  const double u = t / s_.pose_time_s;
  const double seg = std::floor(u);
  const auto i = static_cast<long long>(seg) % kWorkPoints;
  const auto j = (i + 1) % kWorkPoints;
  const double f = smoothstep(u - seg);
  return (1 - f) * work_[static_cast<size_t>(i)] + f * work_[static_cast<size_t>(j)];
}

SimRobotState SimRobotProgram::at(double t) const {
  SimRobotState st;
  st.cell_time_s = t;
  st.settle_duration_s = s_.settle_fraction * s_.pose_time_s;
  long long before = 0;
  for (int g = 0; g < campaigns(); ++g) {
    const double t0 = campaignStart_s(g);
    if (t >= t0 && t < campaignEnd_s(g)) {
      const int k = std::min(posesIn(g) - 1, static_cast<int>(std::floor((t - t0) / s_.pose_time_s)));
      const double tau = (t - t0 - k * s_.pose_time_s) / s_.pose_time_s;
      const Eigen::VectorXd& cur = campaigns_[g][k];
      const Eigen::VectorXd prev = k == 0 ? workAt(t0) : campaigns_[g][k - 1];
      const double move = 1.0 - s_.settle_fraction;
      st.campaign = g;
      st.pose = k;
      st.pose_id = before + k;
      if (tau < move) {
        st.q_rad = prev + smoothstep(tau / move) * (cur - prev);
      } else {
        st.q_rad = cur;
        st.settled = true;
        st.settled_for_s = (tau - move) * s_.pose_time_s;
      }
      return st;
    }
    before += posesIn(g);
  }
  // Working: continue the work path from where the last campaign left it.
  st.q_rad = workAt(t);
  return st;
}

}  // namespace cellcal
