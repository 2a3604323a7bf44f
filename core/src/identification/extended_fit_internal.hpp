// What the extended fit (extended_fit.cpp) shares with diagnose (diagnosis.cpp): the per-row bases, the stacked
// residual and Jacobian, and the screening of a fit's rows. Internal to core/src/identification.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cellcal/core/identification/extended_fit.hpp"

namespace cellcal::internal {

// B_i of every observation; a backlash's play state evaluated at the width in `evaluated_at` (empty: width 0).
std::vector<Eigen::MatrixXd> bases(const RobotModel& model, const Eigen::VectorXd& params,
                                   const std::vector<Extension>& exts, const std::vector<Observation>& obs,
                                   const std::vector<Drivers>& drivers, const Eigen::VectorXd& evaluated_at);
std::vector<Eigen::MatrixXd> bases(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                                   const std::vector<Drivers>& drivers);
// Stacked whitened residual and Jacobian [d/dparams (all), d/de (all)] of the extended model (J optional).
void stackExtended(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& e,
                   const std::vector<Observation>& obs, const std::vector<Eigen::MatrixXd>& B, Eigen::VectorXd& r,
                   Eigen::MatrixXd* J);
// The kinematic parameters of one row under a fit: params + B e.
Eigen::VectorXd rowParams(const CalibratedModel& fit, const Eigen::MatrixXd& B);
// Whether a thermal extension on a time driver still needs its warm-up time constant fitted.
bool needsTimeConstant(const Extension& e, const std::vector<Drivers>& drivers);
// Position and orientation errors of `obs` under a fit, screened (rows with an unknown play judged beyond it).
OutlierScreen screenFitRows(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                            const std::vector<Drivers>& drivers, const OutlierOptions& options);

}  // namespace cellcal::internal
