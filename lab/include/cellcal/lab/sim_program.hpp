// The simulated robot behind the `sim` sources of the cell: a deterministic program in cell time.
// Campaign g starts at g * hours_between_groups and visits its poses (initial_poses for g = 0, poses_per_group
// after), pose_time_s each: moving for the first (1 - settle_fraction) of it, then standing still. Between
// campaigns (and after the last) the robot works: it moves continuously and never reports settled.
// Everything follows from the seed, so separate processes (joint states, tracker) agree without sharing memory.
#pragma once

#include <Eigen/Core>
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

 private:
  Eigen::VectorXd workAt(double t_s) const;
  SimulationSettings s_;
  std::vector<std::vector<Eigen::VectorXd>> campaigns_;
  std::vector<Eigen::VectorXd> work_;
};

// The simulated cell of robot number `index` of the cell file: seeded from simulation.seed and the index, with the
// cell's registered base and tool frames as the nominal ones.
// With simulation.true_robot_file, its true robot is that file's (SimulationSettings::true_robot).
SimulatedCell makeSimulatedCell(const CellRobot& robot, const SimulationSettings& settings, int index);

// Which robot a simulated cell simulates: "the true robot of <file> (<name>): its joints and frames" or "a random
// <name>: the robot file's nominal with 0.1-0.5 mm and 0.01-0.05 deg errors on every parameter (seed N)".
std::string simulatedRobotText(const SimulatedCell& cell);

}  // namespace cellcal
