#include "cellcal/core/engine/health.hpp"

#include <sstream>

namespace cellcal {

const char* healthName(Health h) {
  switch (h) {
    case Health::kUncalibrated: return "uncalibrated";
    case Health::kOk: return "ok";
    case Health::kDegraded: return "degraded";
    case Health::kHoldLastGood: return "hold_last_good";
  }
  return "?";
}

std::size_t posesNeeded(std::size_t state, MeasurementKind kind, bool started_calibrated) {
  const std::size_t rows = kind == MeasurementKind::kPose6D ? 6 : 3;
  return started_calibrated ? 0 : 2 * ((state + rows - 1) / rows);
}

HealthVerdict judgeHealth(const HealthFacts& f, const EngineSettings& s) {
  HealthVerdict v;
  v.drift_alarm = f.drift_alarm;
  std::ostringstream why;
  if (f.consecutive_outliers >= s.outlier_hold_after) {
    why << f.consecutive_outliers << " poses in a row beyond the outlier gate: the robot, the target or the tracker "
        << "moved (check the station and the target, then re-register if it was bumped)";
    v.drift_alarm = true;
  } else if (f.prediction_sigma_m > s.hold_prediction_sigma_m) {
    why << "predicted position error " << f.prediction_sigma_m * 1e3 << " mm (1 sigma) above the bound "
        << s.hold_prediction_sigma_m * 1e3 << " mm: the recent poses do not pin the model down";
  }
  if (f.poses_used < f.poses_needed) {
    v.health = Health::kUncalibrated;
    v.reason = std::to_string(f.poses_used) + " of the " + std::to_string(f.poses_needed) + " poses needed" +
               (f.refused_file ? " (started from nominal: the calibration file does not fit this cell)" : "");
    return v;
  }
  if (!why.str().empty()) {
    if (f.good_version) {
      v.health = Health::kHoldLastGood;
      v.hold = true;
      v.reason = "holding v" + std::to_string(*f.good_version) + ": " + why.str();
    } else {
      v.health = Health::kUncalibrated;
      v.reason = "nothing good to hold yet: " + why.str();
    }
    return v;
  }
  if (v.drift_alarm) {
    std::ostringstream d;
    d << "drift alarm: recent normalized innovation " << f.recent_nis_per_row << " per row (alarm above "
      << s.drift_alarm_nis_per_row << "): the estimate follows something the noise and drift models do not "
      << "allow (a biased tracker, a missing model effect)";
    v.health = Health::kDegraded;
    v.reason = d.str();
    return v;
  }
  v.health = Health::kOk;
  return v;
}

}  // namespace cellcal
