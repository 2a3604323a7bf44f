// The engine's outlier gate on a pose's normalized innovation squared (NIS, chi-square with `rows` degrees of freedom
// when the noise model holds): a reading is an outlier when its NIS exceeds nis_per_row x rows x the scale, the scale
// being the median NIS per row of the recent new stand-stills (gated or not) when that is above 1 and at least 5 are
// known. A noise model too optimistic for the cell (every pose's NIS high) does not gate good poses; a gross error (a
// bumped target, a beam break mid-reading) is hundreds of sigmas and stays far outside; when most poses look like
// outliers (the robot or the station changed), the gate opens within half a window.
#pragma once

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
  void clear() { window_.clear(); }
  // The window, oldest first (EngineState keeps it).
  const std::deque<double>& window() const { return window_; }
  template <class It>
  void assign(It first, It last) {
    window_.assign(first, last);
  }

 private:
  double nis_per_row_;
  std::size_t window_size_;
  std::deque<double> window_;
  std::int64_t cleared_after_ns_ = 0;
};

}  // namespace cellcal
