// The simulated robot behind the `sim` sources of the cell: a deterministic program in cell time.
// Campaign g starts at g * hours_between_groups and visits its poses (initial_poses for g = 0, poses_per_group
// after), pose_time_s each: moving for the first (1 - settle_fraction) of it, then standing still. Between
// campaigns (and after the last) the robot works: it moves continuously and never reports settled.
// Everything follows from the seed, so separate processes (joint states, tracker) agree without sharing memory.
// Following the engine's proposals (simulation.follow_pose_requests) is the exception: the joint-state process
// decides each pose when the robot starts moving to it (advance()), publishes it as the robot's truth (which the
// tracker measures), and lists what it decided (followed()) for the launcher's in-process reference.
#pragma once

#include <Eigen/Core>
#include <map>
#include <vector>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace cellcal {

struct SimRobotState {
  double cell_time_s = 0;
  Eigen::VectorXd q_rad;
  bool settled = false;
  int campaign = -1;            // -1 while working between campaigns
  int pose = -1;                // index within the campaign
  long long pose_id = -1;       // unique over the program
  double settled_for_s = 0;     // time since the robot stopped at this pose
  double settle_duration_s = 0; // how long it stands still at a pose
};

class SimRobotProgram {
 public:
  SimRobotProgram(const SimulatedCell& cell, const SimulationSettings& settings);
  SimRobotState at(double cell_time_s) const;
  int campaigns() const { return static_cast<int>(campaigns_.size()); }
  double campaignStart_s(int g) const;
  double campaignEnd_s(int g) const;
  int posesIn(int g) const { return static_cast<int>(campaigns_.at(g).size()); }
  const std::vector<Eigen::VectorXd>& campaignConfigurations(int g) const { return campaigns_.at(g); }

  // The engine's newest proposal (most informative first; configurations of this robot's joints).
  void offer(std::vector<Eigen::VectorXd> proposal);
  // at() for a program that follows the proposals: pose k of a campaign (every one not yet decided up to the pose at
  // `cell_time_s`) becomes the first configuration of the newest proposal not visited in that campaign; its own
  // random one when no proposal has come or every one was visited. Cell time must not go backwards.
  SimRobotState advance(double cell_time_s);
  // The poses advance() took from a proposal: pose id -> configuration.
  const std::map<long long, Eigen::VectorXd>& followed() const { return followed_; }

 private:
  Eigen::VectorXd workAt(double t_s) const;
  SimulationSettings s_;
  std::vector<std::vector<Eigen::VectorXd>> campaigns_;
  std::vector<Eigen::VectorXd> work_;
  std::vector<Eigen::VectorXd> proposal_;
  std::vector<int> decided_;  // per campaign: poses decided by advance()
  std::map<long long, Eigen::VectorXd> followed_;
};

// The simulated cell of robot number `index` of the cell file: seeded from simulation.seed and the index, with the
// cell's registered base and tool frames as the nominal ones.
// With simulation.true_robot_file, its true robot is that file's (SimulationSettings::true_robot).
SimulatedCell makeSimulatedCell(const CellRobot& robot, const SimulationSettings& settings, int index);

// Which robot a simulated cell simulates: "the true robot of <file> (<name>): its joints and frames" or "a random
// <name>: the robot file's nominal with 0.1-0.5 mm and 0.01-0.05 deg errors on every parameter (seed N)".
std::string simulatedRobotText(const SimulatedCell& cell);

}  // namespace cellcal
