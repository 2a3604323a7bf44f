// A simulated robot cell: a "true" robot (nominal + random geometric errors + true base/tool frames) whose accuracy
// degrades over hours (thermal growth of link lengths, joint-zero drift with temperature and wear), a laser tracker
// with the Leica AT960 specification and the robot's repeatability. Everything is reproducible from the seed.
// Used by tests, the paper experiment and (later) the DDS simulators.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <random>
#include <vector>

#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

// AT960: maximum permissible error +-(15 um + 6 um/m) in position, 0.01 deg in orientation; MPE = 2 sigma.
struct TrackerSpec {
  double mpe_constant_m = 15e-6;
  double mpe_per_distance = 6e-6;  // metres per metre of distance
  double orientation_mpe_rad = 0.01 * 3.14159265358979323846 / 180.0;
  double mpe_in_sigmas = 2.0;
  double sigmaPosition(double distance_m) const { return (mpe_constant_m + mpe_per_distance * distance_m) / mpe_in_sigmas; }
  double sigmaOrientation() const { return orientation_mpe_rad / mpe_in_sigmas; }
};

// An effect on one joint that a geometric model does not have (to test and demonstrate diagnosis). The true joint
// angle is the reported one plus dq_j:
//   kJointCompliance     dq_j = compliance_rad_per_Nm * gravity torque on joint j of `links` (true masses)
//   kThermalDrift        dq_j = zero_drift_rad_per_K * temperature rise (lengths grow by expansion_per_K as always)
//   kCyclicTransmission  dq_j = harmonics_rad . (sin q_j, cos q_j, sin 2q_j, cos 2q_j)
//   kJointScale          dq_j = scale * q_j
//   kBacklash            dq_j = -backlash_width_rad / 2 * s_j: the link lags the motor, s_j the play state
//                        (HiddenJointState; +-1 after a move larger than the width, partly crossed by smaller ones)
struct HiddenJointEffect {
  Cause cause = Cause::kNone;
  int joint = 0;  // 0-based
  double compliance_rad_per_Nm = 0.0;
  std::vector<LinkInertia> links;  // one per joint, DH frame i
  double zero_drift_rad_per_K = 0.0;
  Eigen::Vector4d harmonics_rad = Eigen::Vector4d::Zero();
  double scale = 0.0;
  double backlash_width_rad = 0.0;
};

// Random true link masses (kg) with centres of mass along each link, a few cm off it: a realistic arm (2-12 kg for
// links 1-3, 0.5-3 kg beyond), for a simulated joint compliance when the robot file gives no masses.
std::vector<LinkInertia> plausibleLinks(const RobotModel& model, const Eigen::VectorXd& params, std::mt19937_64& rng);

// A hidden effect of `cause` on `joint` scaled to an RMS joint error of `size_rad` over the configurations `qs`
// (negative: the other sign): joint_compliance from the gravity torque of `links` at `true_params`, joint_scale from
// the joint angle. cyclic_transmission draws the direction of its four harmonics from `rng` (the direction is random,
// so the sign only flips it). Throws std::invalid_argument for the causes that need more (thermal drift: a warm-up;
// backlash: a width, hiddenEffect.backlash_width_rad = 2 size).
HiddenJointEffect scaledHiddenEffect(const RobotModel& model, const Eigen::VectorXd& true_params, Cause cause, int joint,
                                     double size_rad, const std::vector<LinkInertia>& links,
                                     const std::vector<Eigen::VectorXd>& qs, std::mt19937_64& rng);

// State a hidden effect carries from pose to pose.
struct HiddenJointState {
  double backlash_play = 1.0;  // -1..1, see kBacklash
};

struct SimulationConfig {
  std::uint64_t seed = 1;
  // Geometric errors of the true robot: uniform magnitude in [min, max], random sign, on every canonical parameter
  // (kinematics, and the base/tool frames relative to their registered values).
  double length_error_min_m = 0.1e-3, length_error_max_m = 0.5e-3;
  double angle_error_min_rad = 0.01 * 3.14159265358979323846 / 180.0;
  double angle_error_max_rad = 0.05 * 3.14159265358979323846 / 180.0;
  // Registered (nominal) placement of the robot base in the tracker frame and of the target on the flange:
  // x, y, z (m), roll, pitch, yaw (rad).
  Eigen::Matrix<double, 6, 1> base_in_tracker = (Eigen::Matrix<double, 6, 1>() << 2.2, 0.4, -0.3, 0, 0, 2.8).finished();
  Eigen::Matrix<double, 6, 1> tool_in_flange = (Eigen::Matrix<double, 6, 1>() << 0.03, 0.0, 0.06, 0, 0, 0).finished();
  TrackerSpec tracker;
  double repeatability_m = 0.02e-3;  // +- (2 sigma), isotropic at the target
  // Degradation: temperature rise dT(t) = warmup_K (1 - exp(-t / warmup_tau_h)); lengths grow by expansion_per_K dT;
  // each joint zero drifts by c_j dT + w_j t with c_j, w_j uniform in +-max.
  double expansion_per_K = 23e-6;  // aluminium arm
  double warmup_K = 6.0;
  double warmup_tau_h = 1.5;
  double zero_drift_per_K_max_rad = 0.005 * 3.14159265358979323846 / 180.0;
  double zero_wear_per_h_max_rad = 0.005 * 3.14159265358979323846 / 180.0;
  // Poses: joints uniform in this fraction of their limits (and of +-180 deg), flange above z_min in the base frame
  // and at least min_radius from joint 1's axis.
  double pose_range_fraction = 0.8;
  double pose_min_z_m = -0.2;
  double pose_min_radius_m = 0.2;
  double ambient_temperature_c = 20.0;  // temperature = ambient + rise
  HiddenJointEffect hidden;              // none by default
  // The true robot's kinematics (the layout of the nominal model's vector), instead of nominal plus the random errors
  // above: its joints; its frames too when true_frames (else the registration plus the random frame errors).
  std::optional<Eigen::VectorXd> true_params;
  bool true_frames = false;
  std::string true_robot_name;  // what the true robot is, for the cell to say ("" for a random robot)
};

class SimulatedCell {
 public:
  SimulatedCell(const RobotModel& nominal, const SimulationConfig& config);

  // What the user knows: the nominal model with the registered base and tool frames.
  const RobotModel& model() const { return model_; }
  const Eigen::VectorXd& nominalParams() const { return model_.nominal; }
  // The truth at t hours of work (never given to the code under test).
  Eigen::VectorXd trueParams(double t_h) const;
  double temperatureRiseK(double t_h) const;

  std::vector<Eigen::VectorXd> randomConfigurations(int n, std::mt19937_64& rng) const;
  // A noisy tracker measurement at configuration q, time t (sigmas set from the spec).
  Observation measure(const Eigen::VectorXd& q_rad, double t_h, std::mt19937_64& rng,
                      MeasurementKind kind = MeasurementKind::kPose6D) const;
  // state: what the hidden effect carries along the robot's path (backlash's play state; advance it with
  // advanceHiddenState as the robot moves); none: the gap taken up moving positive.
  Observation measure(const Eigen::VectorXd& q_rad, const HiddenJointState* state, double t_h, std::mt19937_64& rng,
                      MeasurementKind kind = MeasurementKind::kPose6D) const;
  Pose truePose(const Eigen::VectorXd& q_rad, double t_h, const HiddenJointState* state = nullptr) const;
  // The tracker's reading of a target at `true_pose` (noise and repeatability drawn from rng), with q_rad reported:
  // what measure() does after truePose, for effects composed outside this class.
  Observation measurePose(const Pose& true_pose, const Eigen::VectorXd& q_rad, std::mt19937_64& rng,
                          MeasurementKind kind = MeasurementKind::kPose6D) const;
  // The hidden effect's joint error (rad per joint) at this configuration (the truth, for tests).
  Eigen::VectorXd hiddenJointErrorRad(const Eigen::VectorXd& q_rad, const HiddenJointState* state, double t_h) const;
  // The state after the robot moved from q_from to q_to (the play operator of the backlash joint).
  HiddenJointState advanceHiddenState(HiddenJointState state, const Eigen::VectorXd& q_from_rad,
                                      const Eigen::VectorXd& q_to_rad) const;
  double temperatureC(double t_h) const { return config_.ambient_temperature_c + temperatureRiseK(t_h); }
  const SimulationConfig& config() const { return config_; }

 private:
  SimulationConfig config_;
  RobotModel model_;
  Eigen::VectorXd true0_;
  Eigen::VectorXd zero_drift_per_K_, zero_wear_per_h_;
};

}  // namespace cellcal
