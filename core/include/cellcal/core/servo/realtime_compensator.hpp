// Compensation inside a controller's own cycle: KUKA RSI and ABB EGM at 250 Hz, Universal Robots' servoj at 500 Hz,
// a ros2_control hardware interface's read/update/write. The thread that owns the controller's socket calls
// RealtimeCompensator::correct() once per cycle and gets the joints to command; calibration versions, which change a
// few times a minute, are prepared on another thread (ServoVersion::prepare) and handed over without waiting.
//
//   RealtimeCompensator rt(nominal, settings, blend_s);           // allocates everything it will ever use
//   // feed thread, per calibration version:
//   std::string why;
//   if (auto v = ServoVersion::prepare(nominal, 12, model, &why)) rt.publish(std::move(v)); else log(why);
//   // controller thread, per cycle:
//   const RealtimeAnswer a = rt.correct(ipoc_stamp_ns, q_setpoint, 6);
//   send(a.q_rad);                                                 // describe(a) later, off this thread
//
// Contract of correct(): it allocates nothing, takes no lock, makes no system call and throws nothing. Its storage is
// fixed-size (up to kMaxServoJoints joints). Its inverse kinematics is bounded by forward-kinematics evaluations, not
// by convergence: each version's solve gives up after RealtimeSettings::max_ik_evaluations (a setpoint the
// calibrated model does not reach within the budget is refused as unreachable). A version's answer costs the descent,
// three more evaluations (the setpoint's pose, the predicted error, the corrected pose) and, where a correction is
// clamped, a second descent; a blend answers with two versions: RealtimeCompensator::evaluationBound().
//
// Each setpoint is answered as compensate() (compensation.hpp) answers the pose the controller believes it commands,
// FK(nominal, q_s), seeded at q_s: the same damped least-squares steps from the same seed, the same predicted-error
// guard (the calibration's covariance at q*), the same bound and clamp, and servo.hpp's joint-jump guard (a correction
// of any joint above max_joint_correction_rad is another branch near a singularity, refused). The correction is a
// joint offset, dq = q* - q_s.
//
// Versions. The first version applies at once when it arrives before the stream's first cycle; one that arrives on a
// running stream, and every later one, is blended in over blend_s of the setpoints' own stamps (the controller's cycle
// clock, not the wall clock):  dq = dq_from + w (dq_to - dq_from), w = (t - t_start) / blend_s clipped to [0, 1], with
// dq_from the previous version's answer at this setpoint (solved every cycle of the blend), or the correction last
// commanded where there is no previous version. A version arriving during a blend waits for it to end (only the
// newest waits; a blend restarted from the correction last commanded takes the waiting version as its target at
// once, at weight 0). blend_s = 0 switches at once. A blend from the correction last commanded (no previous version)
// takes |jump| / recovery_rate_rad_s, at most blend_s.
//
// Refusals. A setpoint the current version refuses (unreachable, predicted error or correction over the bounds, a
// joint jump) is answered with the correction last commanded, held, and faded linearly to zero over blend_s of the
// refusals' stamps; when the version answers again, the answer blends from what the stream was last commanded to the
// version's answer over |jump| / recovery_rate_rad_s (the largest joint's jump at the first answer), at most blend_s.
// No refusal steps the stream. A previous version that refuses during a blend is
// replaced by the correction last commanded, the blend restarted from it.
//
// Threads: one thread (the feed) calls publish() and collectRetired(); one thread (the controller's) calls correct()
// and version(). Both sides are wait-free: a single-slot mailbox the feed fills and the controller empties at the start
// of a cycle (a version the controller never took is freed by the feed when a newer one replaces it), and a fixed ring
// through which the controller hands back the versions it no longer needs, freed by the feed. Construction and
// destruction happen with neither thread running.
#pragma once

#include <Eigen/Core>
#include <Eigen/Cholesky>
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

constexpr int kMaxServoJoints = 7;
constexpr int kMaxServoParams = 5 * kMaxServoJoints + 12;
// A joint vector with its storage inside (no heap): up to kMaxServoJoints values.
using ServoJoints = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxServoJoints, 1>;

struct RealtimeSettings {
  CompensationSettings compensation;
  double blend_s = 2.0;  // version switches, and the fade of a held correction (see above); 0: at once
  // A blend from the correction last commanded (after refusals, or a first version on a running stream) moves each
  // joint at most this fast, so it ends sooner than blend_s when the jump is small: a correction held at one
  // configuration is wrong at the next, and a 3 deg wrist correction held near a singularity, blended back over 2 s
  // while the robot moved on, landed 10-20 mm off (cellcal cell --rsi-hz).
  double recovery_rate_rad_s = 0.1;
  // Forward-kinematics evaluations one version's descent may spend (its damped steps and their trials). From the
  // controller's own setpoint the answer takes 2-5 (cellcal_servo_rt_bench prints how many); the budget is spent where
  // the model's answer lies beyond a joint limit (the damping grows without a better step) or the descent is slow near
  // a singularity, where the answer would be refused anyway (a joint jump) or is not worth a late cycle.
  int max_ik_evaluations = 20;
  // Sizes and signs, named in *error.
  bool IsValid(std::string* error) const;
};

// One calibration version made ready for the controller's thread: the identified model's parameters and the factor
// of its covariance (sigma^2 = |J_p G|^2 over the position rows of the pose Jacobian at q*), built off that thread.
class ServoVersion {
 public:
  // The version, or nullptr with the reason in *error: the model does not fit `nominal` (sizes, non-finite values, a
  // covariance that is not symmetric positive semi-definite), the robot has more than kMaxServoJoints joints, or the
  // model has extensions or a residual map (the controller's loop answers the geometric model; the compensation
  // publisher's DDS stream answers extended ones).
  static std::unique_ptr<const ServoVersion> prepare(const RobotModel& nominal, std::uint64_t version,
                                                     const IdentifiedModel& model, std::string* error);
  std::uint64_t version() const { return version_; }
  const Eigen::VectorXd& params() const { return params_; }
  bool hasCovariance() const { return sigma_factor_.cols() > 0; }
  // G: numParams x rank, zero rows for the parameters not estimated.
  const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxServoParams, kMaxServoParams>& sigmaFactor() const {
    return sigma_factor_;
  }

 private:
  ServoVersion() = default;
  std::uint64_t version_ = 0;
  Eigen::VectorXd params_;
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxServoParams, kMaxServoParams> sigma_factor_;
};

// What became of one setpoint.
enum class ServoStatus : std::uint8_t {
  kApplied,        // corrected (blended between versions where w < 1)
  kHeld,           // the version refused it: the correction last commanded, held or fading (hold_fraction)
  kNoCalibration,  // no version yet: the setpoint as given
  kBadSetpoint,    // wrong joint count or not finite: the setpoint as given, nothing else changed
};
const char* statusName(ServoStatus s);  // "applied", "held", "no_calibration", "bad_setpoint"

struct RealtimeAnswer {
  ServoStatus status = ServoStatus::kNoCalibration;
  // kApplied or kClamped where applied; the refusing version's reason where held (kUnreachable, kOutsideCalibration,
  // kOverBound, kClampUnreachable, kJointJump); kBadInput for a bad setpoint.
  CompensationOutcome outcome = CompensationOutcome::kUnusableModel;
  ServoJoints q_rad;           // the joints to command
  ServoJoints correction_rad;  // q_rad - the setpoint
  std::uint64_t version = 0;       // answering (0: none yet)
  std::uint64_t from_version = 0;  // blended from (= version when not blending with a previous version)
  double weight = 1.0;             // of `version`'s answer in the blend
  // The previous version refused this setpoint during its blend: the blend restarted from the correction last
  // commanded (from_version is then `version`, weight 0).
  bool from_refused = false;
  double hold_fraction = 0.0;      // held: the share of the correction commanded when the refusals began
  double predicted_sigma_m = 0.0;  // the answering version's at q* (NaN without a covariance)
  int ik_evaluations = 0;          // forward-kinematics evaluations this cycle, every solve together
  // What decided a refusal or a clamp, as values: the version, and the figure against its bound (a joint jump: the
  // largest joint move and max_joint_correction_rad; the predicted sigma and max_predicted_sigma_m; the correction's
  // size (m) and max_correction_m; an unreachable pose: the closest position error found and max_ik_error_m; a bad
  // setpoint: its joint count and the robot's).
  std::uint64_t decided_by = 0;
  double value = 0.0, bound = 0.0;
};
// "v3: the correction moves joint values by 6.1 deg, above max_joint_correction_deg 5.0: held at 40 % of the last
// correction"; "" when applied in full. Off the real-time path.
std::string describe(const RealtimeAnswer& answer);

class RealtimeCompensator {
 public:
  // Throws std::invalid_argument on invalid settings or a robot with more than kMaxServoJoints joints.
  RealtimeCompensator(const RobotModel& nominal, const RealtimeSettings& settings);
  ~RealtimeCompensator();
  RealtimeCompensator(const RealtimeCompensator&) = delete;
  RealtimeCompensator& operator=(const RealtimeCompensator&) = delete;

  // Feed thread. Hands a version over (the controller takes it at its next cycle); frees what the controller retired.
  // A version not newer than the last published is dropped: false.
  bool publish(std::unique_ptr<const ServoVersion> version);
  // Feed thread: frees the versions the controller no longer needs (publish() does it too).
  void collectRetired();

  // Controller thread, once per cycle: the joints to command for a joint setpoint of `joints` values.
  RealtimeAnswer correct(std::int64_t cycle_stamp_ns, const double* q_setpoint_rad, int joints) noexcept;
  RealtimeAnswer correct(std::int64_t cycle_stamp_ns, const ServoJoints& q_setpoint_rad) noexcept {
    return correct(cycle_stamp_ns, q_setpoint_rad.data(), static_cast<int>(q_setpoint_rad.size()));
  }
  // The most forward-kinematics evaluations one cycle can take: 2 x (3 + 2 x max_ik_evaluations).
  static int evaluationBound(const RealtimeSettings& s) { return 2 * (3 + 2 * s.max_ik_evaluations); }
  // Controller thread: the version answering (0: none yet), and whether a blend is in progress.
  std::uint64_t version() const noexcept { return current_ ? current_->version() : 0; }
  bool blending() const noexcept { return from_ != From::kNone; }

 private:
  struct Solve;  // one version's answer at one setpoint (realtime_compensator.cpp)
  bool solve(const ServoVersion& v, const ServoJoints& q_s, Solve& out) noexcept;
  bool descend(const Eigen::VectorXd& params, const Pose& target, ServoJoints& q, int& evaluations,
               double& position_error_m) noexcept;
  void takeNewest(std::int64_t t) noexcept;
  void retire(const ServoVersion* v) noexcept;
  void startBlendFromLast(std::int64_t t) noexcept;

  enum class From { kNone, kVersion, kFrozen };
  static constexpr int kRetireSlots = 16;  // the controller retires at most 4 between two feed calls

  const RobotModel* nominal_;
  RealtimeSettings settings_;
  int n_;
  // Handover.
  std::atomic<const ServoVersion*> mailbox_{nullptr};
  std::array<std::atomic<const ServoVersion*>, kRetireSlots> retired_{};
  std::atomic<std::uint32_t> retired_head_{0};  // written by the controller
  std::atomic<std::uint32_t> retired_tail_{0};  // written by the feed
  std::uint64_t last_published_ = 0;            // feed side
  // Controller side.
  const ServoVersion* current_ = nullptr;
  const ServoVersion* waiting_ = nullptr;
  const ServoVersion* from_version_ = nullptr;
  From from_ = From::kNone;
  std::int64_t blend_start_ns_ = 0;
  double blend_duration_s_ = 0;         // of the blend in progress
  bool blend_duration_pending_ = false;  // a blend from the last correction: its duration set at its first answer
  ServoJoints frozen_dq_, last_dq_, hold_dq_;
  bool cycled_ = false, refusing_ = false;
  std::int64_t refuse_start_ns_ = 0;
  // Workspace, sized once.
  KinematicsData data_;
  Eigen::VectorXd q_eval_;
  Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, kMaxServoJoints> joint_jacobian_;
  Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, kMaxServoParams> pose_jacobian_;
};

}  // namespace cellcal
