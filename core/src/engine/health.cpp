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

const char* healthCauseName(HealthCause c) {
  switch (c) {
    case HealthCause::kNone: return "none";
    case HealthCause::kTooFewPoses: return "too_few_poses";
    case HealthCause::kOutliersInARow: return "outliers_in_a_row";
    case HealthCause::kPredictionAboveBound: return "prediction_above_bound";
    case HealthCause::kDriftAlarm: return "drift_alarm";
  }
  return "?";
}

std::size_t posesNeeded(std::size_t state, MeasurementKind kind, bool started_calibrated) {
  const std::size_t rows = kind == MeasurementKind::kPose6D ? 6 : 3;
  return started_calibrated ? 0 : 2 * ((state + rows - 1) / rows);
}

HealthVerdict judgeHealth(const HealthFacts& f, const EngineSettings& s) {
  HealthVerdict v;
  v.facts = f;
  v.outlier_hold_after = s.outlier_hold_after;
  v.hold_prediction_sigma_m = s.hold_prediction_sigma_m;
  v.drift_alarm_nis_per_row = s.drift_alarm_nis_per_row;
  v.drift_alarm = f.drift_alarm;
  HealthCause hold_cause = HealthCause::kNone;
  if (f.consecutive_outliers >= s.outlier_hold_after) {
    hold_cause = HealthCause::kOutliersInARow;
    v.drift_alarm = true;
  } else if (f.prediction_sigma_m > s.hold_prediction_sigma_m) {
    hold_cause = HealthCause::kPredictionAboveBound;
  }
  if (f.poses_used < f.poses_needed) {
    v.health = Health::kUncalibrated;
    v.cause = HealthCause::kTooFewPoses;
  } else if (hold_cause != HealthCause::kNone) {
    v.cause = hold_cause;
    v.hold = f.good_version.has_value();
    v.health = v.hold ? Health::kHoldLastGood : Health::kUncalibrated;
  } else if (v.drift_alarm) {
    v.health = Health::kDegraded;
    v.cause = HealthCause::kDriftAlarm;
  } else {
    v.health = Health::kOk;
    v.cause = HealthCause::kNone;
  }
  return v;
}

std::string describe(const HealthVerdict& v) {
  const HealthFacts& f = v.facts;
  std::ostringstream why;
  switch (v.cause) {
    case HealthCause::kNone: return "";
    case HealthCause::kTooFewPoses:
      return std::to_string(f.poses_used) + " of the " + std::to_string(f.poses_needed) + " poses needed" +
             (f.refused_file ? " (started from nominal: the calibration file does not fit this cell)"
              : f.file_worse ? " (started from nominal: the calibration file did worse here than its nominal kinematics)"
                             : "");
    case HealthCause::kDriftAlarm:
      why << "drift alarm: recent normalized innovation " << f.recent_nis_per_row << " per row (alarm above "
          << v.drift_alarm_nis_per_row << "): the estimate follows something the noise and drift models do not "
          << "allow (a biased tracker, a missing model effect)";
      return why.str();
    case HealthCause::kOutliersInARow:
      why << f.consecutive_outliers << " poses in a row beyond the outlier gate: the robot, the target or the tracker "
          << "moved (check the station and the target, then re-register if it was bumped)";
      break;
    case HealthCause::kPredictionAboveBound:
      why << "predicted position error " << f.prediction_sigma_m * 1e3 << " mm (1 sigma, worst of "
          << (f.work_configurations > 0 ? std::to_string(f.work_configurations) + " configurations measured"
                                        : std::string("the reference configurations over the workspace"))
          << ") above the bound " << v.hold_prediction_sigma_m * 1e3
          << " mm: the recent poses do not pin the model down where the cell works";
      break;
  }
  return (v.hold ? "holding v" + std::to_string(*f.good_version) + ": " : std::string("nothing good to hold yet: ")) +
         why.str();
}

}  // namespace cellcal
