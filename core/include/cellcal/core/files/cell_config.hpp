// The cell file (config/cell.yaml): one file every process of a cell reads (DDS settings, robots, engine,
// compensation, simulation). Strict like the robot file: unknown or duplicated keys, wrong types and values out of
// range are ConfigError "<file>:<line>:<column>: <field>: <message>". Human units in the file (mm, deg, ms, s),
// SI in the structs. See docs/cell-file.md.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"

namespace cellcal {

enum class EngineMode { kContinuous, kPeriodic };

// How an engine keeps each robot's state between runs (cell file engine.durability; core/engine/state_journal.hpp).
enum class Durability {
  kJournal,   // one journal record per change; the JSON snapshot on start, every few MiB of journal and on a clean stop
  kSnapshot,  // the whole JSON snapshot replaced per change (cellcal before the journal; for comparison)
};
const char* durabilityName(Durability d);  // "journal" / "snapshot"

struct DdsSettings {
  int domain_id = 0;                           // 0..232; CELLCAL_DOMAIN_ID or --domain-id override it
  std::string profiles_file;                   // absolute path (resolved against the cell file's folder)
  std::string participant_profile = "cellcal"; // "cellcal_loopback": UDP on 127.0.0.1 only
  // DDS Security (authentication, access control, encryption): the folder config/security/make_pki.sh filled, absolute;
  // empty: off. Each process uses its own identity from it (docs/SECURITY.md). CELLCAL_SECURITY_DIR overrides it.
  std::string security_dir;
  // Send the types' TypeObject and TypeInformation in discovery (what lets tools learn the types). Cyclone DDS 0.10
  // refuses Fast DDS 2.9's TypeInformation and drops the endpoint: false for a cell with Cyclone DDS peers
  // (docs/interop.md).
  bool type_information = true;
  // Discovery without multicast (key discovery), for networks that block it; empty: the profile's (multicast).
  //   peers: [10.0.0.1, ...]  static peers: discovery by unicast to these hosts (their participants 0..31)
  //   server: "10.0.0.3:11811", server_id: 0   a Fast DDS Discovery Server (`fastdds discovery -i 0 -l 10.0.0.3
  //                                             -p 11811`, Debian's fastdds-tools); every process is its client
  std::vector<std::string> discovery_peers;       // IPv4 addresses
  std::string discovery_server_address;           // IPv4
  int discovery_server_port = 0;                  // 0: no server
  int discovery_server_id = 0;
  // A shard of the cell (a process's --robots; not a key of the file): the robots this process serves, and their
  // targets. Its readers then take only their samples (DDS content filters on robot_id, target_id), so an engine
  // serving half the robots does not receive the other half's streams. Empty: every robot, no filter.
  std::vector<std::string> shard_robot_ids, shard_target_ids;
};

struct CellRobot {
  std::string robot_id;                        // DDS key of JointState / CalibrationState / TargetPose
  std::string target_id;                       // DDS key of the TrackerPose stream of the target on its flange
  std::string robot_file;                      // absolute path
  MeasurementKind measurement = MeasurementKind::kPose6D;
  // Registration of this cell (override the robot file when given), SI: x, y, z (m), roll, pitch, yaw (rad).
  std::optional<Eigen::Matrix<double, 6, 1>> base_in_tracker, tool_in_flange;
  // Model extensions the engine estimates with the kinematic parameters (what `cellcal diagnose` named), e.g.
  // [joint_compliance:2]. Not thermal_drift: the cell's topics carry no temperature (the drift model follows warm-up).
  std::vector<Extension> extensions;
  // The nominal model of this robot in this cell (robot file + registration); filled by loadCellConfig. It stays the
  // controller's model (what compensation corrects) whatever the engine starts from.
  RobotModel model;
  // Its place in the cell file's robots (0-based), filled by loadCellConfig: what the simulation seeds the robot by,
  // so a process serving a shard of the robots (--robots) simulates each one as the whole cell does.
  int index = 0;
  // Where the engine starts when it has no state file yet (key calibration_file): a calibrated robot file of this
  // robot (`cellcal calibrate --save-robot`). Its kinematics, frames and extension values are the RLS start, its
  // covariance widened by the drift since its date the prior (calibration_engine.hpp). Empty / nullopt: start from
  // `model` and the engine's prior.
  std::string calibration_file;                // absolute path
  std::optional<RobotFile> start;
  // The names this robot's joints have in a ROS 2 sensor_msgs/JointState (key ros2_joint_names), base to flange,
  // one per joint of the robot file, e.g. a UR driver's [shoulder_pan_joint, ..., wrist_3_joint]. The joint-state
  // adapter's ROS 2 source maps the message's names through it (docs/ros2.md). Empty: not given.
  std::vector<std::string> ros2_joint_names;
};

// The poses the engine proposes to measure next (cellcal/pose_request, core/engine/pose_requests.hpp): after each new
// version (at most once per min_period_s of wall time), the `count` most informative of `candidates` configurations
// drawn once within the joint limits where the cell's tracker (the registration's tracker frame origin) sees the
// target. count 0: none proposed.
struct PoseRequestSettings {
  int count = 10;
  int candidates = 400;
  double min_period_s = 1.0;
  double min_range_m = 0, max_range_m = 0;  // the tracker's range; max 0: not checked
  double link_radius_m = 0.06;              // the beam keeps this far from every link but the last two
  double acceptance_rad = 0;                // > 0: the target's z axis within this of the direction to the tracker
  double min_radius_m = 0.2;                // the target this far from joint 1's axis at least
  // The tracker's 1-sigma noise, for the choice's whitening and the predicted figures.
  double sigma_position_m = 15e-6, sigma_orientation_rad = 8.7e-5;
};

struct EngineSettings {
  EngineMode mode = EngineMode::kContinuous;
  int batch_poses = 15;                        // periodic mode: poses per update
  std::string state_dir = "state";             // absolute path after loading; one JSON file per robot
  // <robot_id>.state.json (snapshot) and <robot_id>.state.journal (records since it), core/engine/state_journal.hpp.
  Durability durability = Durability::kJournal;
  double max_pairing_skew_s = 0.05;            // joint state used for a tracker reading: at most this far in time
  double settle_tolerance_rad = 1e-5;          // joints of the bracketing states may differ by at most this
  double max_sample_age_s = 5.0;               // source stamp vs receive time: older (or newer) = clock problem; 0 = off
  // Stale inputs (stale_input in the diagnostics). Joint states: none for stale_input_s (a controller streams without
  // pause). Tracker readings come only while the robot stands still for them, so a pause in the robot program is not
  // an alarm: stale after stale_stand_stills stand-stills in a row without a reading, or, when tracker_silence_s > 0,
  // after that long without one.
  double stale_input_s = 3.0;
  int stale_stand_stills = 3;
  double tracker_silence_s = 0;
  double republish_period_s = 1.0;             // CalibrationState and diagnostics are republished this often
  // Outlier gate on a pose's normalized innovation squared (NIS; chi-square with the measurement rows as dof when the
  // noise model holds, mean 1 per row): gated above this many per row, times the recent median NIS per row when that
  // is above 1 (a noise model too optimistic for the cell does not gate good poses). 50 per row is a chi-square
  // tail of 3e-32 for 3 rows, 8e-62 for 6; good poses of the simulated cell reach 17 per row after a 2 h pause (drift
  // faster than its model), a target bumped by 0.5 mm under 0.05 mm noise 100. 0 = off.
  double outlier_gate_nis_per_row = 50;
  int outlier_hold_after = 5;                  // this many stand-stills gated in a row: hold last good + drift alarm
  // The model's predicted 1-sigma position error (worst of 16 reference configurations over the joint limits) above
  // this: the engine publishes its last good calibration (health hold_last_good) until the estimate is back under it.
  double hold_prediction_sigma_m = 1e-3;
  double drift_alarm_nis_per_row = 3.0;        // recent mean NIS per row above this: drift alarm
  double prior_length_m = 1e-3;                // 1 sigma of the uncalibrated robot (manufacturing + registration)
  double prior_angle_rad = 0.1 * 3.14159265358979323846 / 180.0;
  // Random walk of the parameters (1 sigma accumulated over drift_per_h hours of cell time).
  double drift_joint_offset_rad = 0.02 * 3.14159265358979323846 / 180.0;
  double drift_joint_length_m = 0.05e-3;
  double drift_axis_angle_rad = 0.002 * 3.14159265358979323846 / 180.0;
  double drift_frame_length_m = 0.01e-3;
  double drift_frame_angle_rad = 0.001 * 3.14159265358979323846 / 180.0;
  double drift_per_h = 2.0;
  PoseRequestSettings pose_requests;
};

enum class ExceedAction { kRefuse, kClamp };

struct CompensationSettings {
  double max_correction_m = 5e-3;              // never send a correction larger than this
  double max_correction_rad = 0.5 * 3.14159265358979323846 / 180.0;
  ExceedAction on_exceed = ExceedAction::kRefuse;
  double max_ik_error_m = 1e-6;                // the identified model must reach the target this closely
  // The model's predicted 1-sigma position error at the target's joints above this: passed through uncorrected (the
  // target lies where the calibration poses did not pin the model down). 0 = off.
  double max_predicted_sigma_m = 1e-3;
  // A servo stream (cellcal/servo_setpoint) moves to a new calibration version over this much of the setpoints' own
  // time (servo.hpp); 0 = at once.
  double blend_s = 2.0;
  // A servo setpoint whose joints the correction moves by more than this (any joint) is passed through: near a wrist
  // or elbow singularity the identified model reaches the pose along another branch (the wrist turned by a radian
  // with the same pose), which a servo loop must never be commanded. A calibration moves joints by hundredths of a
  // degree away from singularities, by degrees within ten degrees of a wrist singularity.
  double max_joint_correction_rad = 5.0 * 3.14159265358979323846 / 180.0;
};

// The simulated cell behind the `sim` sources (and the launcher's hold-out check).
struct SimulationSettings {
  std::uint64_t seed = 1;
  int initial_poses = 50;                      // campaign at t = 0
  int poses_per_group = 15;                    // every later campaign
  int groups = 4;                              // campaigns including the initial one
  double hours_between_groups = 2.0;           // cell time between campaigns (the robot works meanwhile)
  double pose_time_s = 20.0;                   // cell time per pose: move then settle
  double settle_fraction = 0.5;                // last part of pose_time_s the robot stands still
  double joint_rate_hz = 500.0;                // JointState rate (wall clock)
  int tracker_readings_per_pose = 1;
  double tracker_delay_fraction = 0.3;         // tracker reads this far into the settled part
  // The simulated tracker's host clock runs this far ahead of the robot's (key tracker_clock_offset_ms): its stamps
  // are that much late. A drill for the engine's clock warning (pairing.hpp ClockOffsetHint); 0 in a healthy cell.
  double tracker_clock_offset_s = 0;
  // An effect the geometric model lacks, hidden in every simulated robot (to demonstrate extensions):
  // joint_compliance, cyclic_transmission or joint_scale on `effect_joint`, making an RMS joint error of
  // `effect_size_rad` over the workspace (negative: the opposite sign). kNone: none.
  Cause effect = Cause::kNone;
  int effect_joint = -1;                       // 0-based
  double effect_size_rad = 0.0;
  // The true robot of every simulated robot of this structure (key true_robot_file, a robot file or URDF, relative to
  // the cell file): its joints exactly, its base and tool frames too when it is a calibrated robot file (else the
  // cell's registration with the usual random frame errors). Empty: nominal plus random errors (SimulationConfig).
  std::string true_robot_file;
  std::optional<RobotFile> true_robot;
  // A robot program to run instead of the random campaigns (key program_csv, relative to the cell file: CSV v1's joint
  // columns, with pose and cycle as `cellcal plan iso9283` writes them): one stand-still per row, in order, pose_time_s
  // each, from t = 0; then the robot works. Every simulated robot runs it (it must fit each one's joints and limits).
  std::string program_csv;
  std::vector<Eigen::VectorXd> program;
  // The simulated robot program visits the engine's proposed poses (cellcal/pose_request) instead of its own random
  // ones, wherever a proposal has arrived: each pose of a campaign the first proposed configuration it has not
  // visited in that campaign (lab/sim_program.hpp).
  bool follow_pose_requests = false;
  // `cellcal cell` also streams KUKA RSI at this rate per robot (a simulated controller against a cellcal_rsi_bridge
  // process each, docs/deployment.md); 0: none. The launcher's --rsi-hz overrides it.
  double rsi_hz = 0;
};

struct CellConfig {
  std::string source;                          // the file it came from
  DdsSettings dds;
  double time_compression = 1.0;               // cell seconds per wall second (simulated cells run faster)
  std::vector<CellRobot> robots;
  EngineSettings engine;
  CompensationSettings compensation;
  SimulationSettings simulation;

  const CellRobot* robotById(const std::string& robot_id) const;
  const CellRobot* robotByTarget(const std::string& target_id) const;
};

// Reads and checks the cell file and every robot file it names (relative paths are relative to the cell file).
CellConfig loadCellConfig(const std::string& path);
CellConfig parseCellConfig(const std::string& yaml_text, const std::string& source, const std::string& base_dir);

}  // namespace cellcal
