#include "cellcal/core/engine/pairing.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

namespace cellcal {

std::string clockOffsetText(const ClockOffsetHint& h) {
  std::ostringstream m;
  m << std::fixed << std::setprecision(1);
  auto lead = [&](double ahead_s, double lo_s, double hi_s) {
    m << std::abs(ahead_s) * 1e3 << " ms " << (ahead_s > 0 ? "ahead of" : "behind") << " (a lead of " << lo_s * 1e3
      << " to " << hi_s * 1e3 << " ms fits)";
  };
  m << "tracker stamps ";
  lead(h.tracker_ahead_s, h.tracker_ahead_min_s, h.tracker_ahead_max_s);
  if (h.other_ahead_s) {
    m << " or ";
    lead(*h.other_ahead_s, h.other_ahead_min_s, h.other_ahead_max_s);
  }
  m << " the joint states: " << h.fit_with_shift << " of the last " << h.readings << " readings fit a stand-still "
    << "shifted so, " << h.fit_without_shift << " as stamped; synchronize the hosts' clocks (NTP/PTP)";
  return m.str();
}
namespace {

std::int64_t toNs(double s) { return static_cast<std::int64_t>(std::llround(s * 1e9)); }

template <typename... Args>
void setDetail(std::string* d, Args&&... args) {
  if (!d) return;
  std::ostringstream s;
  (s << ... << args);
  *d = s.str();
}

std::optional<Rejection> checkStamp(std::int64_t stamp_ns, std::int64_t receive_ns, double max_age_s, std::string* d,
                                    const char* stream, std::uint64_t seq) {
  if (max_age_s == 0) return std::nullopt;  // off: stamps are not compared with the receiver's clock (replays)
  const std::int64_t age = receive_ns - stamp_ns;
  if (age < -toNs(max_age_s)) {
    setDetail(d, stream, " #", seq, ": stamp ", -age / 1e6, " ms ahead of the receiver's clock (clocks not synchronized?)");
    return Rejection::kStampInFuture;
  }
  if (age > toNs(max_age_s)) {
    setDetail(d, stream, " #", seq, ": stamp ", age / 1e6, " ms older than the receiver's clock");
    return Rejection::kStampTooOld;
  }
  return std::nullopt;
}

}  // namespace

const char* rejectionName(Rejection r) {
  static const char* names[] = {"non_finite",       "wrong_joint_count", "joints_outside_limits", "non_unit_quaternion",
                                "bad_covariance",   "tracker_invalid",   "duplicate",             "out_of_order",
                                "stamp_in_future",  "stamp_too_old",     "no_joint_state",        "robot_moving",
                                "robot_moved",      "already_applied",   "outlier",               "unknown_key",
                                "implausible_value", "unsafe_update"};
  static_assert(sizeof(names) / sizeof(names[0]) == static_cast<size_t>(Rejection::kCount));
  return names[static_cast<int>(r)];
}

bool PairingOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* m) {
    if (error) *error = m;
    return false;
  };
  if (!(max_skew_s > 0)) return fail("max_skew_s must be > 0");
  if (!(settle_tolerance_rad >= 0)) return fail("settle_tolerance_rad must be >= 0");
  if (!(max_sample_age_s >= 0)) return fail("max_sample_age_s must be >= 0 (0: off)");
  if (!(history_s >= 0)) return fail("history_s must be >= 0");
  if (!(default_sigma_position_m > 0 && default_sigma_orientation_rad > 0)) return fail("default sigmas must be > 0");
  return true;
}

PairingBuffer::PairingBuffer(const RobotModel& model, PairingOptions options) : model_(&model), opt_(options) {
  std::string e;
  if (!opt_.IsValid(&e)) throw std::invalid_argument("PairingOptions: " + e);
}

std::optional<Rejection> PairingBuffer::addJointState(const JointSample& s, std::int64_t receive_ns,
                                                      std::string* d) {
  if (s.q_rad.size() != model_->numJoints()) {
    setDetail(d, "joint state #", s.sequence, ": ", s.q_rad.size(), " joints, the robot has ", model_->numJoints());
    return Rejection::kWrongJointCount;
  }
  if (!s.q_rad.allFinite()) {
    setDetail(d, "joint state #", s.sequence, ": NaN/Inf joint position");
    return Rejection::kNonFinite;
  }
  if (!model_->withinLimits(s.q_rad)) {
    setDetail(d, "joint state #", s.sequence, ": joints outside the limits of ", model_->name);
    return Rejection::kJointsOutsideLimits;
  }
  if (auto r = checkStamp(s.stamp_ns, receive_ns, opt_.max_sample_age_s, d, "joint state", s.sequence)) return r;
  if (last_joint_) {
    if (s.stamp_ns == last_joint_->stamp_ns || (s.sequence == last_joint_->sequence && s.sequence != 0)) {
      setDetail(d, "joint state #", s.sequence, ": duplicate of #", last_joint_->sequence);
      return Rejection::kDuplicate;
    }
    if (s.stamp_ns < last_joint_->stamp_ns) {
      setDetail(d, "joint state #", s.sequence, ": stamp ", (last_joint_->stamp_ns - s.stamp_ns) / 1e6,
                " ms older than #", last_joint_->sequence, " received before it");
      return Rejection::kOutOfOrder;
    }
  }
  last_joint_ = s;
  joints_.push_back(s);
  const std::int64_t keep = toNs(opt_.max_skew_s + opt_.history_s);
  while (joints_.size() > 2 && joints_.front().stamp_ns < s.stamp_ns - keep) joints_.pop_front();
  return std::nullopt;
}

std::optional<Rejection> PairingBuffer::addTrackerSample(const TrackerSample& s, std::int64_t receive_ns,
                                                         std::string* d) {
  bool finite = s.position_m.allFinite();
  for (double v : s.orientation_xyzw) finite = finite && std::isfinite(v);
  for (double v : s.covariance) finite = finite && std::isfinite(v);
  if (!finite) {
    setDetail(d, "tracker reading #", s.sequence, ": NaN/Inf field");
    return Rejection::kNonFinite;
  }
  if (!s.valid) {
    setDetail(d, "tracker reading #", s.sequence, ": the tracker flagged it invalid");
    return Rejection::kTrackerInvalid;
  }
  if (s.has_orientation) {
    const double n = std::sqrt(s.orientation_xyzw[0] * s.orientation_xyzw[0] + s.orientation_xyzw[1] * s.orientation_xyzw[1] +
                               s.orientation_xyzw[2] * s.orientation_xyzw[2] + s.orientation_xyzw[3] * s.orientation_xyzw[3]);
    if (std::abs(n - 1.0) > 1e-6) {
      setDetail(d, "tracker reading #", s.sequence, ": quaternion norm ", n, " (expected 1)");
      return Rejection::kNonUnitQuaternion;
    }
  }
  // A laser tracker measures up to ~160 m: a reading farther than this is in the wrong unit (millimetres sent as
  // metres) or garbage, and would drag the estimate by metres if it got through.
  constexpr double kMaxRange_m = 200.0;
  if (s.position_m.norm() > kMaxRange_m) {
    setDetail(d, "tracker reading #", s.sequence, ": position ", s.position_m.norm(), " m from the tracker, beyond any tracker's range (",
              kMaxRange_m, " m): millimetres sent as metres?");
    return Rejection::kImplausible;
  }
  for (int i = 0; i < 3; ++i) {
    const double v = s.covariance[i * 7];
    if (v > 0 && v < 1e-14) {  // (0.1 um)^2
      setDetail(d, "tracker reading #", s.sequence, ": covariance[", i * 7, "] = ", v,
                " m^2 claims better than 0.1 um (a variance in mm^2 or um^2 sent as m^2?)");
      return Rejection::kImplausible;
    }
  }
  for (int i = 0; i < 6; ++i) {
    if (s.covariance[i * 7] < 0) {
      setDetail(d, "tracker reading #", s.sequence, ": negative variance at covariance[", i * 7, "]");
      return Rejection::kBadCovariance;
    }
    for (int j = 0; j < i; ++j)
      if (std::abs(s.covariance[i * 6 + j] - s.covariance[j * 6 + i]) > 1e-12 * (1 + std::abs(s.covariance[i * 6 + j]))) {
        setDetail(d, "tracker reading #", s.sequence, ": covariance not symmetric at (", i, ", ", j, ")");
        return Rejection::kBadCovariance;
      }
  }
  if (auto r = checkStamp(s.stamp_ns, receive_ns, opt_.max_sample_age_s, d, "tracker reading", s.sequence)) return r;
  if (s.stamp_ns <= applied_until_ns_) {
    setDetail(d, "tracker reading #", s.sequence, ": at or before the last reading already in the calibration");
    return Rejection::kAlreadyApplied;
  }
  if (last_tracker_) {
    if (s.stamp_ns == last_tracker_->stamp_ns || (s.sequence == last_tracker_->sequence && s.sequence != 0)) {
      setDetail(d, "tracker reading #", s.sequence, ": duplicate of #", last_tracker_->sequence);
      return Rejection::kDuplicate;
    }
    if (s.stamp_ns < last_tracker_->stamp_ns) {
      setDetail(d, "tracker reading #", s.sequence, ": older than #", last_tracker_->sequence, " received before it");
      return Rejection::kOutOfOrder;
    }
  }
  last_tracker_ = s;
  pending_.emplace_back(s, receive_ns);
  return std::nullopt;
}

PairingOutcome PairingBuffer::poll(std::int64_t now_ns) {
  PairingOutcome out;
  judgeFits();
  const std::int64_t skew = toNs(opt_.max_skew_s);
  while (!pending_.empty()) {
    const auto& [s, received] = pending_.front();
    const std::int64_t t = s.stamp_ns;
    // The first joint state at or after t decides; without one, wait up to max_skew of receive time.
    const JointSample* after = nullptr;
    const JointSample* before = nullptr;
    for (auto it = joints_.rbegin(); it != joints_.rend(); ++it) {
      if (it->stamp_ns >= t) after = &*it;
      if (it->stamp_ns <= t) {
        before = &*it;
        break;
      }
    }
    // Stamps ahead of the receive clock wait for their time, unless stamps are not compared with the clock
    // (max_sample_age_s = 0: a replay faster than real time, where stamps run ahead of it by design).
    const std::int64_t waiting_since = opt_.max_sample_age_s == 0 ? received : std::max(received, t);
    if (!after && now_ns - waiting_since < skew) break;  // still waiting for the next joint state
    std::string detail;
    std::optional<Rejection> why;
    if (!before || !after || t - before->stamp_ns > skew || after->stamp_ns - t > skew) {
      why = Rejection::kNoJointState;
      std::ostringstream m;
      m << "tracker reading #" << s.sequence << ": no joint state within " << opt_.max_skew_s * 1e3 << " ms "
        << (!before || t - before->stamp_ns > skew ? "before" : "after") << " it";
      detail = m.str();
    } else if (!before->settled || !after->settled) {
      why = Rejection::kRobotMoving;
      detail = "tracker reading #" + std::to_string(s.sequence) + ": robot not settled";
    } else if ((before->q_rad - after->q_rad).cwiseAbs().maxCoeff() > opt_.settle_tolerance_rad) {
      why = Rejection::kRobotMoved;
      std::ostringstream m;
      m << "tracker reading #" << s.sequence << ": joints moved by "
        << (before->q_rad - after->q_rad).cwiseAbs().maxCoeff() * 180 / 3.14159265358979323846
        << " deg across it while reported settled";
      detail = m.str();
    }
    fits_to_judge_.push_back(t);
    if (why) {
      out.rejected.emplace_back(*why, detail);
    } else {
      PairedReading p;
      p.observation = toObservation(s, before->q_rad, opt_);
      p.tracker_stamp_ns = t;
      p.tracker_sequence = s.sequence;
      p.joint_stamp_ns = before->stamp_ns;
      out.paired.push_back(std::move(p));
    }
    pending_.pop_front();
  }
  return out;
}

namespace {
constexpr size_t kFitWindow = 12;
constexpr std::int64_t kFitReach_ns = 500000000;  // stand-stills within 0.5 s of a reading
}  // namespace

void PairingBuffer::judgeFits() {
  while (!fits_to_judge_.empty() && !joints_.empty() && joints_.back().stamp_ns >= fits_to_judge_.front() + kFitReach_ns) {
    recordFit(fits_to_judge_.front());
    fits_to_judge_.pop_front();
  }
  while (fits_to_judge_.size() > 4 * kFitWindow) fits_to_judge_.pop_front();  // no joint states: nothing to judge by
}

void PairingBuffer::recordFit(std::int64_t t) {
  // Stand-stills of the joint history within 0.5 s of t: runs of settled states whose joints stay within the settle
  // tolerance of the run's first.
  const std::int64_t reach = kFitReach_ns;
  std::vector<std::pair<std::int64_t, std::int64_t>> fits;
  const JointSample* first = nullptr;
  const JointSample* last = nullptr;
  auto close = [&] {
    if (first && last->stamp_ns >= t - reach && first->stamp_ns <= t + reach)
      fits.emplace_back(first->stamp_ns - t, last->stamp_ns - t);
    first = last = nullptr;
  };
  for (const auto& j : joints_) {
    if (first && (!j.settled || (j.q_rad - first->q_rad).cwiseAbs().maxCoeff() > opt_.settle_tolerance_rad)) close();
    if (j.settled) {
      if (!first) first = &j;
      last = &j;
    }
  }
  close();
  if (fits.empty()) return;
  recent_fits_.push_back(std::move(fits));
  if (recent_fits_.size() > kFitWindow) recent_fits_.pop_front();
}

std::optional<ClockOffsetHint> PairingBuffer::clockOffsetHint() const {
  const int n = static_cast<int>(recent_fits_.size());
  if (n < 8) return std::nullopt;
  // Sweep over the shifts: +1 where a reading's interval opens, -1 after it closes (a reading's intervals are
  // disjoint, so the coverage counts readings).
  std::vector<std::pair<std::int64_t, int>> events;
  int at_zero = 0;
  for (const auto& fits : recent_fits_)
    for (const auto& [a, b] : fits) {
      events.emplace_back(a, +1);
      events.emplace_back(b + 1, -1);
      if (a <= 0 && 0 <= b) ++at_zero;
    }
  std::sort(events.begin(), events.end());
  // The coverage on each stretch between events; the stretches of the largest coverage, the one nearest zero first.
  struct Stretch {
    std::int64_t lo, hi;
    int cover;
  };
  std::vector<Stretch> stretches;
  int cover = 0, best = 0;
  for (size_t i = 0; i + 1 < events.size(); ++i) {
    cover += events[i].second;
    if (events[i + 1].first == events[i].first) continue;
    stretches.push_back({events[i].first, events[i + 1].first - 1, cover});
    best = std::max(best, cover);
  }
  auto nearest = [](const Stretch& s) { return s.lo <= 0 && 0 <= s.hi ? std::int64_t{0} : s.lo + (s.hi - s.lo) / 2; };
  std::vector<Stretch> top;
  for (const auto& st : stretches)
    if (st.cover == best) {
      if (!top.empty() && top.back().hi + 1 == st.lo) top.back().hi = st.hi;  // contiguous: one stretch
      else top.push_back(st);
    }
  if (top.empty()) return std::nullopt;
  std::sort(top.begin(), top.end(),
            [&](const Stretch& x, const Stretch& y) { return std::llabs(nearest(x)) < std::llabs(nearest(y)); });
  if (best < 9 || best - at_zero < 4 || std::llabs(nearest(top[0])) < 2000000) return std::nullopt;
  ClockOffsetHint h;
  // A reading fits when moved back by the lead: lead = -shift.
  h.tracker_ahead_s = -static_cast<double>(nearest(top[0])) * 1e-9;
  h.tracker_ahead_min_s = -static_cast<double>(top[0].hi) * 1e-9;
  h.tracker_ahead_max_s = -static_cast<double>(top[0].lo) * 1e-9;
  if (top.size() > 1) {
    h.other_ahead_s = -static_cast<double>(nearest(top[1])) * 1e-9;
    h.other_ahead_min_s = -static_cast<double>(top[1].hi) * 1e-9;
    h.other_ahead_max_s = -static_cast<double>(top[1].lo) * 1e-9;
  }
  h.fit_with_shift = best;
  h.fit_without_shift = at_zero;
  h.readings = n;
  return h;
}

Observation toObservation(const TrackerSample& s, const Eigen::VectorXd& q_rad, const PairingOptions& options) {
  Observation o;
  o.q_rad = q_rad;
  o.kind = (options.kind == MeasurementKind::kPose6D && s.has_orientation) ? MeasurementKind::kPose6D
                                                                             : MeasurementKind::kPosition3D;
  o.measured_in_tracker = Pose::Identity();
  o.measured_in_tracker.translation() = s.position_m;
  if (s.has_orientation)
    o.measured_in_tracker.linear() =
        Eigen::Quaterniond(s.orientation_xyzw[3], s.orientation_xyzw[0], s.orientation_xyzw[1], s.orientation_xyzw[2])
            .normalized()
            .toRotationMatrix();
  const double var_p = (s.covariance[0] + s.covariance[7] + s.covariance[14]) / 3;
  const double var_o = (s.covariance[21] + s.covariance[28] + s.covariance[35]) / 3;
  o.sigma_position_m = var_p > 0 ? std::sqrt(var_p) : options.default_sigma_position_m;
  o.sigma_orientation_rad = var_o > 0 ? std::sqrt(var_o) : options.default_sigma_orientation_rad;
  return o;
}

}  // namespace cellcal
