// The published experiments, reproduced on a simulated robot (default: Staubli TX60):
// G groups of P poses measured H hours apart while the robot's accuracy degrades; in each group the first half
// identifies and the second half verifies.
//  - Pose-number sweep (paper's Table 2): RLS from the prior with the first N identification poses of group 0;
//    mean position error on those N poses ("identification") and on the verification poses.
//  - Accuracy maintenance (paper's Table 4): group 0 is the initial calibration (all identification poses);
//    every later group updates the previous estimate either periodically (all identification poses) or
//    continuously (only the first K freshly measured poses), with RLS and with LM. "Before" is the previous
//    estimate on the new group's poses, "after" the updated one. Identification errors are on the poses used.
//  - Variants the paper lacks: continuous RLS that chooses its K poses among the group's identification
//    configurations (greedy, minimizing the predicted position variance; never looking at measurements), LM with the same Gaussian prior RLS carries (previous estimate and covariance plus
//    process noise), RLS with a forgetting factor instead of process noise, and the tracker noise floor (mean
//    |measured - true| on the verification poses: what a perfect model would score).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace cellcal {

struct PaperExperimentConfig {
  SimulationConfig sim;
  int groups = 4;
  int poses_per_group = 100;
  int identification_poses = 50;
  double hours_between_groups = 2.0;
  std::vector<int> sweep_poses = {4, 5, 10, 15, 20, 25, 50};
  std::vector<int> continuous_poses = {15, 20};
  MeasurementKind kind = MeasurementKind::kPose6D;
  // Prior of the initial calibration: manufacturing tolerances and registration accuracy (1 sigma).
  double prior_sigma_length_m = 1e-3;
  double prior_sigma_angle_rad = 0.1 * 3.14159265358979323846 / 180.0;
  // Process noise between groups (random walk of the parameters over hours_between_groups, 1 sigma).
  DriftModel drift;
  double forgetting = 0.95;  // lambda of the forgetting variant
  // Candidates of the chosen-pose variant: 0 = the group's identification configurations; N > 0 = N fresh random
  // reachable configurations per group, the chosen ones measured when chosen (a cell that can ask for any pose).
  int selection_candidates = 0;
  bool IsValid(std::string* error) const;
};

struct MaintenanceGroup {
  int group = 0;
  double t_h = 0;
  int poses_used = 0;
  double ident_before_m = 0, ident_after_m = 0, verify_before_m = 0, verify_after_m = 0;
  double noise_floor_m = 0;      // of this group's verification poses
  double update_time_s = 0;      // wall time of this group's update
  // Change of each joint's zero since the nominal model, after this group's update and in the simulated robot's
  // truth at t_h (rad, per joint), as the estimated parameters carry it: theta_j when it is estimated, else the
  // kept parameter that stands for it (joint_zero_names; joint 6's zero is the tool yaw when the tool frame is kept)
  // in joint-zero units, with the truth mapped by the same absorption map (identifiability.hpp).
  Eigen::VectorXd joint_offsets_rad, true_joint_offsets_rad;
};

struct MaintenanceRun {
  std::string mode;              // "periodic" | "continuous"
  std::string algorithm;         // "rls" | "lm"
  int updated_poses = 0;         // per group after the initial calibration
  bool prior = false;            // LM with the RLS prior
  std::string pose_selection = "first";  // "first": the first K poses visited; "i-optimal": chosen to minimize predicted position variance (pose_selection.hpp)
  double forgetting = 1.0;       // RLS lambda
  std::vector<MaintenanceGroup> groups;  // group 0 = initial calibration
  // Means over the update groups (1..G-1).
  double ident_before_m = 0, ident_after_m = 0, verify_before_m = 0, verify_after_m = 0;
  double worst_verify_to_floor = 0;  // max over update groups of verify_after / noise floor
};

struct SweepRow {
  int poses = 0;
  double ident_mean_m = 0;
  double verify_mean_m = 0;
};

struct PaperExperimentResult {
  std::vector<SweepRow> sweep;
  std::vector<MaintenanceRun> maintenance;
  double noise_floor_m = 0;            // all verification poses of all groups
  double true_error_nominal_m = 0;     // mean error of the nominal model on group 0 verification poses
  double rls_time_per_pose_s = 0;      // mean wall time of one RLS pose update (linearization + update)
  double lm_time_50_s = 0;             // wall time of the 50-pose initial LM solve
  std::vector<std::string> joint_zero_names;  // per joint: "joint 6" or "joint 6 (as tool.yaw_rad)"
};

using ProgressFn = std::function<void(const std::string& step, int done, int total)>;

PaperExperimentResult runPaperExperiment(const RobotModel& nominal, const PaperExperimentConfig& config,
                                         const ProgressFn& progress = nullptr);

}  // namespace cellcal
