// A set-up change hidden in one file's rows: between two rows the tracker was moved or the target re-mounted, and no
// setup column says so. Found from the structure of a calibrated model's residuals, not from their size: the robot's
// own model error (tenths of a millimetre) hides a move of half a millimetre from any registration of the nominal
// model, but not from a test of whether the rows after some row want frames of their own.
//
//   SetupChangeScan s = scanSetupChange(model, fit.params, fit.estimated, observations);
//   if (s.found) ...  // rows [0, s.first_row) and [s.first_row, n) are two set-ups
//
// The score. The rows' whitened residuals r and Jacobian at the calibrated parameters are taken in visiting order:
// the null model X (the estimated columns, and the drift's: the frames' and joint zeros' columns times shapes of
// time) and the twelve frame columns F (base and tool). A split at row k adds S_k F (F on rows >= k, zero before);
// what it removes from the squared residual beyond X is
//     T_k = b_k^T M_k^+ b_k / s^2,   b_k = (S_k F)^T (I - H) r,   M_k = (S_k F)^T (I - H) (S_k F),
// H the projection onto X, s^2 the residual variance X leaves (so a model error larger than the readings' noise
// scales it). Every k costs O(p 12^2) from running sums from the end; beyond 400 splits they are scored
// on a grid, then row by row beside its best. The best split is the one whose chi-square tail is smallest.
//
// Its law. The chi-square tail would hold for independent rows of one size; a model error larger in some
// configurations than others, heavier tails, and rows that share their error with their neighbours (a path through
// nearby configurations) do not. So the best split's -log(tail) is compared with the same scan of the rows' own
// scatter (what the split, fitted, leaves: each row's error, change or none) with signs drawn at random per block of
// rows as long as the scatter stays correlated (a block wild bootstrap); the draws' maxima are fitted with a Gumbel
// law, whose tail at the observed value is `probability`. A change is found when it is below false_alarm and the
// change moves the target by min_move_m.
//
// What is no set-up change:
//  - a gross error (one row off by millimetres): each row's residual is clipped at clip_sigmas robust sigmas per
//    axis (its direction kept) before the scan, so one row cannot make a split; a block of rows that all moved the same
//    way still does;
//  - drift (the frames or the joints' zeros creeping over the file: a warming stand, a tracker settling): X carries
//    their columns times a straight line over time, the warm-up shape 1 - exp(-t / tau) whose tau fits best, and the
//    temperature where a thermometer moved, so only what such a motion cannot explain makes a split.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct SetupChangeOptions {
  int min_rows = 20;          // rows on each side of a split, at the least
  double false_alarm = 1e-6;  // probability of a change found in a file of one set-up (the law's estimate)
  double clip_sigmas = 4.0;   // a row's residual is clipped at this many robust sigmas per axis
  // A change moves the target by at least this (RMS over the rows after it). Of 18 splits of simulated files of one
  // set-up (4,000 files, before this bound), 15 moved it by 0.07-0.22 mm; a change of the 0.5 mm the search is built
  // for moves it by 0.4 mm or more.
  double min_move_m = 0.25e-3;
  // The drift: the frames and the joints' zeros moving along a straight line over the file and along the warm-up
  // shape (1 - exp(-u / tau), u the row's place in the file, 0 .. 1) whose tau leaves the least. false: no drift.
  bool drift = true;
  int bootstrap_draws = 200;  // scans of the rows' scatter with random signs: the law of the best split under none
  std::uint64_t seed = 0x5e7c4a11;  // their signs' generator (the same rows give the same answer)
  bool IsValid(std::string* error) const;
};

struct SetupChangeScan {
  bool found = false;
  int first_row = -1;          // the best split: first row (index into the observations) of the second set-up
  double score = 0;            // its model-based score (chi-square with dof degrees of freedom under one set-up)
  int dof = 0;
  double log_tail = 0;         // -log of the score's chi-square tail: the best over the splits
  // The law of the best -log(tail) over the splits when there is no change (Gumbel, from the bootstrap draws), and
  // the probability that it reaches log_tail: found when below false_alarm.
  double null_location = 0, null_scale = 1, probability = 1;
  int block_rows = 1;          // the draws' signs were drawn per block of this many consecutive rows
  int splits = 0;              // splits tried (0: too few rows, nothing scanned)
  // The robust per-axis sigmas of the calibration's residuals (position, orientation), in the readings' stated sigmas:
  // the rows are re-whitened by them before the scan.
  double position_scale = 1, orientation_scale = 1;
  double residual_scale = 0;   // s: what the model and the drift leave per row and axis, in those re-whitened units
  double move_m = 0;           // how far the second set-up's frames move the target there (RMS over its rows), m
  double residual_position_m = 0;  // what the model and the drift leave of a row's position, RMS, m
  double drift_statistic = 0;  // what the drift removed, in s^2
  double drift_warmup_fraction = 0;  // the warm-up shape chosen (0: the straight line alone)
  bool drift_temperature = false;    // the temperature was a drift shape too
  std::vector<double> profile;  // the score for every row k (0 where not tried): where a change would be, as a curve
};

// `params`: a calibration over all the rows as one set-up (its base and tool frames those rows' registration);
// `estimated`: the columns it estimated. The observations in visiting order. Throws std::invalid_argument when the
// options are invalid or the sizes do not fit the model.
// `times_s`: each row's time (the drift's clock; empty: the rows' order, evenly spaced); `temperatures_c`: each row's
// temperature (empty: no thermometer), a drift's shape beside the line and the warm-up where it moves.
SetupChangeScan scanSetupChange(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<int>& estimated, const std::vector<Observation>& observations,
                                const SetupChangeOptions& options = {}, const std::vector<double>& times_s = {},
                                const std::vector<double>& temperatures_c = {});

}  // namespace cellcal
