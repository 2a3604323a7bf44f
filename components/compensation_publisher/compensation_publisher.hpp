// The compensation publisher process: for every cellcal/target_pose, solves the identified model for the joints that
// reach the target and publishes on cellcal/compensated_target the pose to command the unmodified controller (the
// nominal model's pose of those joints), the joints, the correction and the calibration version used.
// Uses the latest calibration whose health is ok. When the engine's latest is not ok (degraded: drift alarm;
// hold_last_good; uncalibrated after a reset) it keeps applying the last ok one it had and says so in `reason`; it
// also says when the engine reports stale inputs (the tracker or the controller stopped), and when the engine is gone
// (no CalibrationState writer left: killed, or its host down), while it applies the last ok calibration. Refuses (applied = false,
// with the reason) when it never had an ok calibration, the identified model cannot reach the target, or the
// correction exceeds compensation.max_correction_mm / _deg (or clamps, if so set) -- whatever it received.
// A calibration with model extensions (CalibrationState::model_extensions) is solved with them (compensation.hpp); a
// target corrected beyond the extensions' data, within the distance they were judged there (a calibrated robot file's
// beyond_data), is flagged (CompensatedTarget::beyond_data) and said first in its reason (kBeyondDataNote), and
// --stats-json counts them (beyond_data_applied). Every answer carries its outcome as a code.
// With --ros-pose-topic it also publishes every applied correction as a ROS 2 geometry_msgs/PoseStamped (directly
// over DDS, docs/ros2.md): the corrected pose in the targets' frame (header.frame_id from --ros-frame-id), stamped
// with the target's stamp. Targets passed through uncorrected are not published there (an uncorrected pose on a
// topic of corrected ones would look like a correction); their reasons stay on cellcal/compensated_target.
// With --ros-description-topic it publishes the robot's URDF with the chain's joint origins calibrated (std_msgs/String,
// reliable, transient local, keep last 1, as robot_state_publisher publishes robot_description) after each new ok
// calibration, so RViz and MoveIt see the calibrated arm: the robot's robot_file must be a URDF or a robot file
// converted from one (`cellcal robot import`); the target's registered place on the flange (the cell file's
// tool_in_flange) is where the calibrated tool frame's change is measured from, so the exported tip is the robot's
// (core/files/urdf.hpp exportUrdf). Model extensions are not carried (said once).
//
// A servo loop streams setpoints on cellcal/servo_setpoint (one per controller cycle; joints, or a pose with a seed)
// and reads each answer on cellcal/servo_correction (best effort, keep last 1 both ways: an older setpoint than the
// last answered is dropped, and the writer never waits for a slow reader). A new ok calibration is blended in over
// compensation.blend_s of the setpoints' own stamps (core/engine/servo.hpp), so no cycle steps.
// Per target and setpoint only what depends on it: the model is prepared when its version arrives, the note for the
// operator when the state changes, the samples are reused; --stats-json has each callback's CPU time and the outcomes.
//
// Lifetime: the constructor joins the domain, creates the writer and the calibration readers, waits for every
// robot's calibration (at most --wait-for-calibration-s), then takes targets; run() returns on SIGINT/SIGTERM or after
// the duration, having left the domain and written --stats-json.
#pragma once

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/engine/servo.hpp"
#include "cellcal/core/files/urdf.hpp"

namespace cellcal::components {

class CompensationPublisher {
 public:
  struct Options {
    ProcessOptions process;
    double duration_s = 0;              // 0: until SIGINT/SIGTERM
    double wait_for_calibration_s = 3;  // at start, for every robot's calibration
    std::string ros_pose_topic;         // empty: no ROS 2 output; with several robots, <topic>/<robot_id> each
    std::string ros_frame_id = "cellcal_tracker";
    std::string ros_description_topic;  // empty: none; with several robots, <topic>/<robot_id> each
    // Every target and setpoint answered unchanged, no calibration read or applied: a controller bridge commissioned
    // before there is a calibration, and the transport's floor beside the compensation (bench-cell --pass-through).
    bool pass_through = false;
  };
  explicit CompensationPublisher(const Options& options);
  int run();

 private:
  // --ros-description-topic: the robot's nominal URDF and the last calibration published as its calibrated URDF.
  struct Description {
    std::string path, xml;
    UrdfImport nominal;
    Writer<std_msgs::msg::dds_::String_> writer;
    std::uint64_t version = 0, stamp_ns = 0;  // of the calibration last published (0: none yet)
    std::uint64_t published = 0, failed = 0;
    bool extensions_said = false;
  };
  struct Robot {
    const CellRobot* robot = nullptr;
    std::optional<ReceivedCalibration> calibration;  // the latest received
    std::optional<ReceivedCalibration> last_ok;      // the latest received with health ok (the one applied)
    // The last compensated targets' joints, oldest first: the seed when a target brings none, and backlash's play.
    std::vector<Eigen::VectorXd> path;
    std::uint64_t seq = 0;
    std::string engine_warning;                      // from the engine's diagnostics: stale inputs
    // Prepared once per ok calibration version (what every target is solved with), and the note said with every
    // answer, rebuilt only when the health, the engine's warning or its presence changes.
    std::optional<IdentifiedModel> applied_model;
    bool judged_ranges_said = false;  // the robot file's beyond_data, said once when first attached
    std::string note;
    bool engine_gone = false;
    // cellcal/servo_setpoint: the stream's compensator (blends between versions) and the last setpoint answered.
    std::optional<ServoCompensator> servo;
    std::uint64_t servo_last_sequence = 0, servo_seq = 0;
    std::optional<Writer<geometry_msgs::msg::dds_::PoseStamped_>> ros_pose;  // --ros-pose-topic
    std::optional<Description> description;                                // --ros-description-topic
  };
  void onCalibrationState(const msg::CalibrationState& m);
  void onDiagnostics(const msg::CalibrationDiagnostics& d);
  void onTarget(const msg::TargetPose& t);
  void onServoSetpoint(const msg::ServoSetpoint& sp);
  void openDescription(const std::string& id, Robot& r);
  void publishDescription(const std::string& id, Robot& r);
  void waitForCalibrations();
  void refreshNote(Robot& r);
  void noticeEngine(Robot& r);
  // The answer to one target in out_ (reused: fastddsgen's constructors re-register the IDL's types, tens of us).
  void answer(const msg::TargetPose& t, Robot& r);

  Options options_;
  CellConfig cell_;
  std::mutex mutex_;  // robots_ and the counters, between the readers
  std::map<std::string, Robot> robots_;
  std::uint64_t applied_ = 0, refused_ = 0, clamped_ = 0, bad_states_ = 0;
  std::uint64_t residual_map_applied_ = 0;  // targets applied with the start file's residual map near measured poses
  // Targets and setpoints applied beyond the extensions' data, within the distance they were judged (kBeyondDataNote).
  std::uint64_t beyond_data_applied_ = 0, servo_beyond_data_ = 0;
  std::array<std::uint64_t, kNumCompensationOutcomes> outcomes_{};  // targets the compensation answered, per outcome
  // The CPU time of a callback (take to write) per sample: a histogram of 1 us bins to 10 ms.
  struct CpuHistogram {
    std::vector<std::uint32_t> bins = std::vector<std::uint32_t>(10001, 0);
    double sum_us = 0, max_us = 0;
    std::uint64_t n = 0;
    void add(double us);
    nlohmann::json json() const;  // {"samples", "mean", "p50", "p99", "max"} in us
  };
  CpuHistogram target_cpu_, servo_cpu_;
  std::uint64_t servo_answered_ = 0, servo_applied_ = 0, servo_out_of_order_ = 0;
  DdsNode node_;
  Writer<msg::CompensatedTarget> writer_;
  Writer<msg::ServoCorrection> servo_writer_;
  const std::atomic<int>& engine_writers_;  // CalibrationState writers matched: 0 when the engine is gone
  msg::CompensatedTarget out_;
  msg::ServoCorrection servo_out_;
  geometry_msgs::msg::dds_::PoseStamped_ ros_sample_;
};

}  // namespace cellcal::components
