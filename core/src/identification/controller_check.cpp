#include "cellcal/core/identification/controller_check.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {
namespace {

void setFrame(Eigen::VectorXd& p, int first, const Pose& T) { p.segment<6>(first) = xyzRpyFromPose(T); }

// The readings against the model at p: the figures of ControllerCheck's first block.
void compare(const RobotModel& model, const Eigen::VectorXd& p, const std::vector<Observation>& readings,
             ControllerCheck& c) {
  KinematicsData data(model);
  c.rows = static_cast<int>(readings.size());
  for (size_t i = 0; i < readings.size(); ++i) {
    const Observation& o = readings[i];
    const Pose& T = forwardKinematics(model, data, p, o.q_rad);
    const double mm = (T.translation() - o.measured_in_tracker.translation()).norm() * 1e3;
    c.mean_mm += mm / c.rows;
    if (mm > c.max_mm) c.max_mm = mm, c.worst_row = static_cast<int>(i);
    if (o.kind == MeasurementKind::kPose6D) {
      const double deg = radToDeg(logSO3(o.measured_in_tracker.linear() * T.linear().transpose()).norm());
      ++c.oriented;
      c.mean_deg += deg;
      c.max_deg = std::max(c.max_deg, deg);
    }
  }
  if (c.oriented > 0) c.mean_deg /= c.oriented;
}

}  // namespace

bool ControllerCheckOptions::IsValid(std::string* error) const {
  if (!(tolerance_mm > 0) || !(tolerance_deg > 0) || !std::isfinite(tolerance_mm) || !std::isfinite(tolerance_deg)) {
    if (error) *error = "tolerance_mm and tolerance_deg must be > 0 and finite";
    return false;
  }
  if (!base_in_controller.matrix().allFinite() || !tool_in_flange.matrix().allFinite()) {
    if (error) *error = "base_in_controller and tool_in_flange must be finite";
    return false;
  }
  return true;
}

ControllerCheck checkController(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<Observation>& readings, const ControllerCheckOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument("ControllerCheckOptions: " + err);
  if (params.size() != model.numParams()) throw std::invalid_argument("checkController: params not of the model");
  if (readings.empty()) throw std::invalid_argument("checkController: no readings");
  Eigen::VectorXd p = params;
  setFrame(p, model.baseParam(FrameParam::kX), options.base_in_controller);
  setFrame(p, model.toolParam(FrameParam::kX), options.tool_in_flange);
  ControllerCheck c;
  compare(model, p, readings, c);
  c.matches = c.max_mm <= options.tolerance_mm && c.max_deg <= options.tolerance_deg;
  if (c.matches) return c;
  // Which kinematic parameters explain the difference: fitted with the frames held (the controller's are given).
  CalibrationProblem problem{&model, p, readings, std::nullopt, {}, {}};
  problem.outliers.enabled = false;
  for (int k = 0; k < 6; ++k) {
    problem.identifiability.held.push_back(model.baseParam(static_cast<FrameParam>(k)));
    problem.identifiability.held.push_back(model.toolParam(static_cast<FrameParam>(k)));
  }
  const CalibrationResult r = solveGaussNewton(problem);
  c.fit_converged = r.converged;
  ControllerCheck left;
  compare(model, r.params, readings, left);
  c.left_mean_mm = left.mean_mm;
  const Eigen::VectorXd plausible = plausibleDeviation(model);
  for (int i : r.estimated) {
    const double change = r.params[i] - p[i];
    if (std::abs(change) > 1e-3 * plausible[i]) c.explained_by.emplace_back(i, change);
  }
  std::sort(c.explained_by.begin(), c.explained_by.end(), [&](const auto& a, const auto& b) {
    return std::abs(a.second) / plausible[a.first] > std::abs(b.second) / plausible[b.first];
  });
  return c;
}

}  // namespace cellcal
