// The engine's outlier gate on a pose's normalized innovation squared (NIS, chi-square with `rows` degrees of freedom
// when the noise model holds): a reading is an outlier when its NIS exceeds nis_per_row x rows x the scale, the scale
// being the median NIS per row of the recent new stand-stills (gated or not) when that is above 1 and at least 5 are
// known. A noise model too optimistic for the cell (every pose's NIS high) does not gate good poses; a gross error (a
// bumped target, a beam break mid-reading) is hundreds of sigmas and stays far outside; when most poses look like
// outliers (the robot or the station changed), the gate opens within half a window.
// It keeps the state a restart needs (the window and the stand-stills gated in a row; EngineState saves both) and the
// last stand-still it gated, so that a gating policy is changed here and in the engine's gateReading() alone.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <deque>

namespace cellcal {

class OutlierGate {
 public:
  OutlierGate(double nis_per_row, std::size_t window) : nis_per_row_(nis_per_row), window_size_(window) {}
  bool enabled() const { return nis_per_row_ > 0; }
  // The largest NIS a reading of `rows` rows may have to pass, from the window as it is.
  double gate(int rows) const;
  // A new stand-still's NIS per row, gated or not (the oldest leaves a full window).
  void record(double nis_per_row);
  // After a silence longer than the drift model's period following the update stamped `last_update_ns`, the window
  // describes the robot as it was: cleared, once per such update.
  void clearOnceAfter(std::int64_t last_update_ns);
  // Everything forgotten: the window, the stand-stills gated in a row, the last gated stand-still.
  void clear();
  // The window, oldest first, and the stand-stills gated in a row (EngineState keeps both).
  const std::deque<double>& window() const { return window_; }
  int inARow() const { return in_a_row_; }
  template <class It>
  void restore(It window_first, It window_last, int in_a_row) {
    window_.assign(window_first, window_last);
    in_a_row_ = in_a_row;
  }

  // A new stand-still was gated: remembered (its joints and their joint state's stamp: later readings of it are not a
  // new stand-still) and, when `count` (not while a calibration file is on probation), counted in a row.
  void gatedStandStill(const Eigen::VectorXd& q_rad, std::int64_t joint_stamp_ns, bool count);
  // The last stand-still gated since a reading passed (q empty: none).
  const Eigen::VectorXd& gatedQ() const { return gated_q_; }
  std::int64_t gatedJointStampNs() const { return gated_joint_stamp_ns_; }
  // A reading passed: nothing is gated in a row.
  void passed() {
    in_a_row_ = 0;
    gated_q_.resize(0);
  }

 private:
  double nis_per_row_;
  std::size_t window_size_;
  std::deque<double> window_;
  std::int64_t cleared_after_ns_ = 0;
  int in_a_row_ = 0;
  Eigen::VectorXd gated_q_;
  std::int64_t gated_joint_stamp_ns_ = 0;
};

}  // namespace cellcal
