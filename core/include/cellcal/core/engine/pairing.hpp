// Pairing tracker readings with the joint state valid at their timestamp (DDS-free; the calibration engine process
// and `cellcal validate` feed it samples).
//
// Contract: source stamps of both streams are nanoseconds since the Unix epoch on one clock (PTP/NTP-synchronized
// hosts). A tracker reading at time t pairs with the robot only if the last joint state at or before t and the first
// at or after t both exist within `max_skew_s` of t, both say `settled`, and their joints differ by at most
// `settle_tolerance_rad`: the robot provably stood still across the reading. The joints of the earlier state are used.
// A reading waits (pending) until a joint state at or after t arrives or `max_skew_s` of receive time passes.
// Clocks that disagree show up as rejections: a sample whose stamp is more than `max_sample_age_s` away from the
// receiver's clock is rejected as stamp_in_future / stamp_too_old (the engine never pairs across a clock offset).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

enum class Rejection {
  kNonFinite = 0,          // NaN/Inf in a field
  kWrongJointCount,
  kJointsOutsideLimits,
  kNonUnitQuaternion,
  kBadCovariance,          // not symmetric positive semi-definite, or negative variances
  kTrackerInvalid,         // the tracker's own validity flag is false
  kDuplicate,              // same stamp or sequence number as the previous sample of the stream
  kOutOfOrder,             // older than the previous sample of the stream
  kStampInFuture,
  kStampTooOld,
  kNoJointState,           // no joint state within max_skew_s before / after the reading
  kRobotMoving,            // a bracketing joint state says not settled
  kRobotMoved,             // bracketing joint states differ: moved while "settled"
  kAlreadyApplied,         // reading at or before the last one in the persisted state (restart)
  kOutlier,                // normalized innovation above the gate
  kUnknownKey,             // robot_id / target_id not in the cell file
  kImplausible,            // finite but impossible: a position beyond any tracker's range (mm sent as m?), a
                           // covariance claiming better than 0.1 um
  kUnsafeUpdate,           // the update would make the estimate non-finite: rolled back, the estimate kept
  kCount
};
const char* rejectionName(Rejection r);  // snake_case, e.g. "robot_moving"

struct JointSample {
  std::int64_t stamp_ns = 0;
  std::uint64_t sequence = 0;
  Eigen::VectorXd q_rad;
  bool settled = false;
};

struct TrackerSample {
  std::int64_t stamp_ns = 0;
  std::uint64_t sequence = 0;
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();
  std::array<double, 4> orientation_xyzw{0, 0, 0, 1};
  bool has_orientation = true;
  std::array<double, 36> covariance{};   // row-major 6x6 (x, y, z in m; rotation vector in rad); zeros = unknown
  bool valid = true;
};

struct PairingOptions {
  double max_skew_s = 0.05;
  double settle_tolerance_rad = 1e-5;
  double max_sample_age_s = 5.0;         // 0: off (a replay faster than real time keeps the recorded stamps)
  double history_s = 2.0;                // joint states kept (beyond max_skew_s)
  MeasurementKind kind = MeasurementKind::kPose6D;  // position3d robots ignore the orientation
  double default_sigma_position_m = 10e-6;           // used when the reading has no covariance
  double default_sigma_orientation_rad = 8.7e-5;
  bool IsValid(std::string* error) const;
};

struct PairedReading {
  Observation observation;
  std::int64_t tracker_stamp_ns = 0;
  std::uint64_t tracker_sequence = 0;
  std::int64_t joint_stamp_ns = 0;
};

// Tracker stamps that miss the robot's stand-stills by a consistent shift: what two hosts' clocks that disagree look
// like (each reading is taken while the robot stands still, but its stamp lands beside the stand-still). Over the
// recent readings, the shift of the tracker's stamps that puts the most of them inside a stand-still of the joint
// history (the one nearest zero among equals) against how many are inside without a shift.
struct ClockOffsetHint {
  double tracker_ahead_s = 0;   // the tracker's stamps are this much later than the robot's for the same instant
  double tracker_ahead_min_s = 0, tracker_ahead_max_s = 0;  // every lead in this range fits as many (the middle above)
  // A robot program of equal stand-stills and moves fits as well with another lead (the next stand-still): the
  // second one nearest zero, when there is one.
  std::optional<double> other_ahead_s;
  double other_ahead_min_s = 0, other_ahead_max_s = 0;
  int fit_with_shift = 0;       // readings inside a stand-still once shifted
  int fit_without_shift = 0;    // ... as stamped
  int readings = 0;             // recent readings judged (those with a stand-still within 0.5 s)
};

// What an operator reads of a hint: "tracker stamps 12.0 ms ahead of (a lead of 10.0 to 14.0 ms fits) the joint
// states: 11 of the last 12 readings fit a stand-still shifted so, 2 as stamped; synchronize the hosts' clocks
// (NTP/PTP)"; with the other lead that fits as well, when there is one.
std::string clockOffsetText(const ClockOffsetHint& hint);

struct PairingOutcome {
  std::vector<PairedReading> paired;
  std::vector<std::pair<Rejection, std::string>> rejected;  // reason and detail (stream, sequence, values)
};

class PairingBuffer {
 public:
  PairingBuffer(const RobotModel& model, PairingOptions options);

  // Checks and stores a joint state; a rejection is returned (and nothing stored) for bad samples.
  std::optional<Rejection> addJointState(const JointSample& s, std::int64_t receive_ns, std::string* detail = nullptr);
  // Checks and queues a tracker reading for pairing.
  std::optional<Rejection> addTrackerSample(const TrackerSample& s, std::int64_t receive_ns,
                                            std::string* detail = nullptr);
  // Pairs every queued reading that can be decided at `now_ns` (receive clock).
  PairingOutcome poll(std::int64_t now_ns);

  // Readings at or before this stamp are rejected as already applied (set from the persisted engine state).
  void setAppliedUntil(std::int64_t stamp_ns) { applied_until_ns_ = stamp_ns; }
  std::size_t pending() const { return pending_.size(); }
  // A consistent clock offset over the last 12 readings with a stand-still nearby: at least 9 fit with one shift
  // (of at least 2 ms), at least 4 more than fit as stamped. nullopt: no sign of one (or fewer than 8 readings judged).
  std::optional<ClockOffsetHint> clockOffsetHint() const;
  std::size_t jointHistory() const { return joints_.size(); }

 private:
  const RobotModel* model_;
  PairingOptions opt_;
  std::deque<JointSample> joints_;
  std::deque<std::pair<TrackerSample, std::int64_t>> pending_;  // sample, receive time
  std::optional<JointSample> last_joint_;
  std::optional<TrackerSample> last_tracker_;
  std::int64_t applied_until_ns_ = INT64_MIN;
  // Per recent reading: the shifts (ns, relative to its stamp) that would put it inside each stand-still near it,
  // judged once the joint history reaches 0.5 s past the reading (a stand-still after it counts too).
  std::deque<std::vector<std::pair<std::int64_t, std::int64_t>>> recent_fits_;
  std::deque<std::int64_t> fits_to_judge_;
  void recordFit(std::int64_t t);
  void judgeFits();
};

// Observation of a reading (orientation used only for 6D robots with an oriented reading).
Observation toObservation(const TrackerSample& s, const Eigen::VectorXd& q_rad, const PairingOptions& options);

}  // namespace cellcal
