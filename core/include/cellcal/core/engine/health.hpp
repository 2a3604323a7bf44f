// The engine's health: what it says of the calibration it publishes, decided after each update (and at a start) from
// the facts of the estimate, by this rule, in this order:
//  1. fewer poses than needed (every estimated parameter twice over at 6 or 3 rows a pose; none when the engine
//     started from a calibrated robot file): uncalibrated (too_few_poses);
//  2. EngineSettings::outlier_hold_after poses in a row beyond the outlier gate (which also raises the drift alarm),
//     (outliers_in_a_row) or the predicted position error where the cell works (the worst over the configurations it
//     measured, work_configurations.hpp) above hold_prediction_sigma_m (prediction_above_bound): the
//     last version published ok is held (hold_last_good: its model is published), or without one uncalibrated;
//  3. the drift alarm (the recent normalized innovation above drift_alarm_nis_per_row): degraded (drift_alarm);
//  4. else ok: this version becomes the one a later hold publishes.
// The verdict is values (its cause, the facts and the bounds it was decided on); describe() puts it in words.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/model/measurement_kind.hpp"

namespace cellcal {

enum class Health { kUncalibrated = 0, kOk = 1, kDegraded = 2, kHoldLastGood = 3 };
const char* healthName(Health h);  // "uncalibrated", "ok", "degraded", "hold_last_good"

struct HealthFacts {
  std::size_t poses_used = 0, poses_needed = 0;
  int consecutive_outliers = 0;       // stand-stills in a row beyond the outlier gate
  double prediction_sigma_m = 0;      // predicted 1-sigma position error of the estimate where the cell works
  std::size_t work_configurations = 0;  // ... the worst over this many measured configurations (0: the workspace's)
  bool drift_alarm = false;           // as the recent poses' statistics set it
  double recent_nis_per_row = 0;
  std::optional<std::uint64_t> good_version;  // the last version published ok, if any
  bool refused_file = false;          // the calibration file was refused: started from nominal
  bool file_worse = false;            // the calibration file did worse than its nominal kinematics: started from nominal
};

// Why health is not ok, in the rule's order. The wire's HealthCause (idl/cellcal_msgs.idl) has these in this order.
enum class HealthCause { kNone = 0, kTooFewPoses = 1, kOutliersInARow = 2, kPredictionAboveBound = 3, kDriftAlarm = 4 };
// "none", "too_few_poses", "outliers_in_a_row", "prediction_above_bound", "drift_alarm"
const char* healthCauseName(HealthCause c);

struct HealthVerdict {
  Health health = Health::kUncalibrated;
  HealthCause cause = HealthCause::kTooFewPoses;  // kNone when ok
  bool hold = false;         // publish the last good version's model (health hold_last_good)
  bool drift_alarm = false;  // the facts' alarm, raised too by outliers in a row
  // What it was decided on: the facts, and the settings' bounds they were held to.
  HealthFacts facts;
  int outlier_hold_after = 0;
  double hold_prediction_sigma_m = 0;
  double drift_alarm_nis_per_row = 0;
};
// Why health is not ok, in words: "holding v52: 5 poses in a row beyond the outlier gate: ..."; "" when ok.
std::string describe(const HealthVerdict& verdict);

// Rule 1's count: 2 x ceil(state / rows), rows 6 for 6D readings and 3 for points; 0 when started calibrated.
std::size_t posesNeeded(std::size_t state, MeasurementKind kind, bool started_calibrated);
HealthVerdict judgeHealth(const HealthFacts& facts, const EngineSettings& settings);

}  // namespace cellcal
