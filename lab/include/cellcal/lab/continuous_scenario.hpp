// Continuous calibration over a measured data set in time order, as a cell would run it: an initial batch (a
// one-off calibration from the first `initial_h` hours), then every `update_interval_h` a handful of freshly measured poses (15-20 in the published study) update the
// estimate with RLS, pose by pose. Before an interval's poses are used, every row of that interval is predicted by the
// models as they stand: an honest running verification (no row predicts itself).
//
//   ContinuousScenario s{&model, rows, options};
//   ContinuousScenarioResult r = runContinuousScenario(s);   // r.intervals[i].static_mm, .rls_mm, .rls_extended_mm
//
// Three models are run side by side over the same poses:
//   static        the initial batch fit (geometric), never updated: what a one-off calibration keeps;
//   rls           geometric model, RLS from the initial batch fit, drift process noise between intervals;
//   rls_extended  the same with `extensions` in the RLS state (e.g. the cause `cellcal diagnose` named); only when
//                 extensions are given.
// Frames: the robot base and target are registered on the initial batch only. Drivers are causal: the thermal driver
// is the temperature minus the first row's (or hours since the first row without temperatures); the play state of a
// backlash comes from the moves between consecutive rows.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/identification/rls.hpp"

namespace cellcal {

struct ContinuousScenarioOptions {
  double update_interval_h = 0.5;   // one update per interval of the stamps that holds rows
  int poses_per_update = 18;        // evenly spaced over the interval's rows
  double initial_h = 0.5;           // the initial batch comes from the rows of the first initial_h hours
  int initial_poses = 60;           // evenly spaced over those rows
  std::vector<Extension> extensions;  // empty: no rls_extended
  DriftModel drift;                 // process noise per hour between updates (both RLS runs)
  double drift_scale = 1.0;         // multiplies the drift sigmas; 0: no process noise (the paper's lambda = 1 RLS)
  bool IsValid(std::string* error) const;
};

struct ContinuousRow {
  Observation observation;
  double stamp_s = 0;                    // non-decreasing
  std::optional<double> temperature_c;
};

struct ContinuousScenario {
  const RobotModel* model = nullptr;
  std::vector<ContinuousRow> rows;  // in time order
  ContinuousScenarioOptions options;
};

struct IntervalResult {
  double start_h = 0, end_h = 0;     // stamps of the interval's first and last rows, hours since the first row
  double temperature_c = 0;          // mean over the interval (NaN without temperatures)
  int rows = 0;                      // rows predicted (all of the interval's rows)
  int poses_used = 0;                // of them, used to update after predicting
  ErrorStats static_model, rls, rls_extended;  // a-priori errors on the interval's rows
};

struct ContinuousScenarioResult {
  int initial_rows = 0;              // rows of the first initial_h hours (the batch is taken from them; not predicted)
  ErrorStats initial_fit;            // the initial geometric batch fit on its own poses
  std::vector<IntervalResult> intervals;  // after the initial period
  ErrorStats static_overall, rls_overall, rls_extended_overall;  // over all predicted rows
  int updates = 0, poses_used = 0;
  double solve_time_s = 0;
};

// Throws std::invalid_argument on invalid options, too few rows, or stamps that go back in time.
ContinuousScenarioResult runContinuousScenario(const ContinuousScenario& scenario);

}  // namespace cellcal
