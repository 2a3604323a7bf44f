// The error a model leaves beyond the readings' own sigmas, as a variance component (the Helmert / maximum-likelihood
// view of "the residual is more than noise"): with per-reading sigmas sigma_i from the tracker, a row's weight should
// be 1 / (sigma_i^2 + sigma_m^2), where sigma_m is what the model does not describe. Weighting by sigma_i alone gives
// rows the tracker measured a little better many times the weight of others once the model error dominates (on the
// ipa UR10 Series B: 0.02 mm sigmas against 0.25 mm per axis of model error; docs/real-robots.md).
//
//   const ModelErrorSigma m = modelErrorSigma(model, fit.params, ident, flagged_rows);
//   addModelError(ident, m);  addModelError(verify, m);     // then fit again
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct ModelErrorSigma {
  double position_m = 0;       // per axis, 1 sigma; 0 where the readings' sigmas explain the residual
  double orientation_rad = 0;  // per axis (rows with orientation only)
  int position_rows = 0, orientation_rows = 0;  // rows it was estimated from
};

// sigma_m per measurement type such that the rows' residuals under `params`, each with its own sigma, have a mean
// squared normalized residual of 1 per axis: mean_i |r_i|^2 / (3 (sigma_i^2 + sigma_m^2)) = 1 (a root of a
// decreasing function, found by bisection; 0 when the sigmas alone already give at most 1). Rows in `skip` (gross
// errors, indices into `obs`) are left out.
ModelErrorSigma modelErrorSigma(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                                const std::vector<int>& skip = {});

// Each observation's sigmas replaced by sqrt(sigma^2 + sigma_m^2).
void addModelError(std::vector<Observation>& obs, const ModelErrorSigma& m);

}  // namespace cellcal
