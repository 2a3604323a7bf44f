#include "cellcal/core/engine/compensation.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

const char* outcomeName(CompensationOutcome o) {
  switch (o) {
    case CompensationOutcome::kApplied: return "applied";
    case CompensationOutcome::kClamped: return "clamped";
    case CompensationOutcome::kUnusableModel: return "unusable_model";
    case CompensationOutcome::kUnreachable: return "unreachable";
    case CompensationOutcome::kNotSettled: return "not_settled";
    case CompensationOutcome::kOutsideCalibration: return "outside_calibration";
    case CompensationOutcome::kOverBound: return "over_bound";
    case CompensationOutcome::kClampUnreachable: return "clamp_unreachable";
    case CompensationOutcome::kJointJump: return "joint_jump";
    case CompensationOutcome::kNeverJudged: return "never_judged";
    case CompensationOutcome::kBadInput: return "bad_input";
  }
  return "?";
}

namespace {
// The first range q lies beyond the data of (a joint's, else a driver's, with the driver's value in *x): what
// CompensationResult::beyond_data flags and ProgramCompensation::beyond_data_at holds.
struct BeyondAt {
  const BeyondRange* joint = nullptr;
  const DriverRange* driver = nullptr;
  double x = 0;
  explicit operator bool() const { return joint || driver; }
};
RangeAt rangeAt(const BeyondRange* joint, const DriverRange* driver, const Eigen::VectorXd& q, double x) {
  RangeAt r;
  if (joint) {
    r.joint = *joint;
    r.at = q[joint->joint];
  } else if (driver) {
    r.driver = *driver;
    r.at = x;
  }
  return r;
}
BeyondAt firstBeyondData(const RobotModel& nominal, const IdentifiedModel& model, const Eigen::VectorXd& q,
                         const Drivers& drivers) {
  BeyondAt at;
  if (model.extensions.empty()) return at;
  at.joint = firstBeyond(model.beyond_data, q);
  if (!at.joint) at.driver = firstBeyond(nominal, model.params, model.beyond_drivers, q, drivers, &at.x);
  return at;
}

// Drivers of the solution: the visited path (oldest first), then a straight move to q; the last row of that sequence.
Drivers moveDrivers(const std::vector<Eigen::VectorXd>& path, const Eigen::VectorXd& q) {
  std::vector<Eigen::VectorXd> seq;
  const size_t first = path.size() > static_cast<size_t>(kPlayHistory) ? path.size() - kPlayHistory : 0;
  for (size_t i = first; i < path.size(); ++i)
    if (path[i].size() == q.size() && path[i].allFinite()) seq.push_back(path[i]);
  if (seq.empty()) return Drivers{};
  seq.push_back(q);
  return driversFromSequence(seq, {}, {}).rows.back();
}
}  // namespace

void attachResidualMap(const RobotFile& start, IdentifiedModel& model) {
  if (!start.calibration || !start.calibration->residual_map) return;
  const int b = start.model.baseParam(FrameParam::kX);
  auto baseRotation = [b](const Eigen::VectorXd& p) -> Eigen::Matrix3d {
    return poseFromXyzRpy(p[b], p[b + 1], p[b + 2], p[b + 3], p[b + 4], p[b + 5]).linear();
  };
  model.residual_map = &*start.calibration->residual_map;
  model.residual_map_rotation = baseRotation(model.params) * baseRotation(start.model.nominal).transpose();
}

void attachRobotFile(const RobotFile& start, IdentifiedModel& model) {
  attachResidualMap(start, model);
  if (!start.calibration || model.extensions.empty()) return;
  std::vector<std::string> file, mine;
  for (const Extension& e : start.calibration->extensions) file.push_back(extensionSpec(e));
  for (const Extension& e : model.extensions) mine.push_back(extensionSpec(e));
  std::sort(file.begin(), file.end());
  std::sort(mine.begin(), mine.end());
  if (file == mine) {
    model.beyond_data = start.calibration->beyond_data;
    model.beyond_drivers = start.calibration->beyond_drivers;
  }
}

CompensationResult compensate(const RobotModel& nominal, const Eigen::VectorXd& identified, const Pose& desired,
                              const Eigen::VectorXd& q_seed, const CompensationSettings& s) {
  return compensate(nominal, IdentifiedModel(CalibratedModel::geometric(identified)), desired, q_seed, s);
}

namespace {

// The residual map's correction at q, in this model's tracker frame (zero where it does not apply).
Eigen::Vector3d mapCorrection(const IdentifiedModel& model, const Eigen::VectorXd& q, bool* applies) {
  const ResidualMap::Prediction p = model.residual_map->predict(q);
  *applies = p.applies;
  return model.residual_map_rotation * p.correction_m;
}

// With extensions or a residual map, the joints depend on the correction at them: the fixed point
// q = IK(params(q), desired - c(q)) from ik (the geometric answer). False, with out's outcome, when it does not settle.
template <class DriversAt>  // Drivers(const Eigen::VectorXd& q)
bool settle(const RobotModel& nominal, const IdentifiedModel& model, const Pose& desired, const DriversAt& driversAt,
            const IkOptions& ik_options, IkResult& ik, CompensationResult& out) {
  const Eigen::VectorXd& identified = model.params;
  const bool mapped = model.residual_map && !model.residual_map->empty();
  constexpr int kPasses = 10;
  double moved = 0.0;
  for (int pass = 0; pass < kPasses; ++pass) {
    const Eigen::VectorXd p =
        model.extensions.empty()
            ? identified
            : extendedParams(nominal, identified, model.extensions, model.extension_params, ik.q_rad, driversAt(ik.q_rad));
    Pose target = desired;
    if (mapped) target.translation() -= mapCorrection(model, ik.q_rad, &out.residual_map_applied);
    IkResult next = solveInverseKinematics(nominal, p, target, ik.q_rad, ik_options);
    moved = next.ok() ? (next.q_rad - ik.q_rad).cwiseAbs().maxCoeff() : 0.0;
    ik = std::move(next);
    if (!ik.ok() || moved < 1e-10) break;
  }
  if (ik.ok() && moved > 1e-8) {
    out.outcome = CompensationOutcome::kNotSettled;
    out.settle_move_rad = moved;
    out.settled_extensions = !model.extensions.empty();
    return false;
  }
  if (mapped && ik.ok()) out.residual_map_correction_m = mapCorrection(model, ik.q_rad, &out.residual_map_applied);
  return true;
}

// The predicted 1-sigma position error at q: the calibration's covariance, what the extensions may do beyond their
// data and drivers' ranges, and the residual map's own bound where it applies.
double predictedSigma(const RobotModel& nominal, KinematicsData& data, const IdentifiedModel& model,
                      const Eigen::VectorXd& q, const Drivers& at, bool map_applied) {
  const Eigen::VectorXd& identified = model.params;
  double sigma = 0;
  // The kinematic block (the whole covariance unless it also covers extension parameters).
  sigma =
      model.estimated_extension.empty()
          ? kinematicPositionSigma(nominal, data, identified, model.estimated, model.covariance, q)
          : kinematicPositionSigma(nominal, data, identified, model.estimated, model.kinematicCovariance(), q);
  if (!model.extensions.empty() && !model.beyond_data.empty()) {  // what the extensions may do beyond their data
    Eigen::MatrixXd J(6, nominal.numParams());
    computePoseJacobian(nominal, data, J);  // at identified, q*: kinematicPositionSigma's forward kinematics
    sigma = std::sqrt(std::pow(sigma, 2) +
                                               beyondPositionVariance(nominal, J, model.beyond_data, q));
  }
  if (!model.extensions.empty() && !model.beyond_drivers.empty())  // and beyond their drivers' ranges
    sigma =
        std::sqrt(std::pow(sigma, 2) +
                  driverRangeVariance(nominal, identified, model.beyond_drivers, q, at));
  if (map_applied) {
    const double map_sigma = model.residual_map->sigmaBound_m(q);
    sigma = std::hypot(sigma, std::sqrt(3.0) * map_sigma);
  }
  return sigma;
}

// The correction from desired to the joints ik found, within the settings' bounds, refused or clamped beyond them.
CompensationResult applyCorrection(const RobotModel& nominal, KinematicsData& data, const Pose& desired,
                                   const IkResult& ik, const CompensationSettings& s, const IkOptions& ik_options,
                                   CompensationResult out) {
  const Pose corrected = forwardKinematics(nominal, data, nominal.nominal, ik.q_rad);
  const Eigen::Matrix<double, 6, 1> c = poseError(corrected, desired);  // [dp; dtheta], corrected relative to desired
  out.correction_position_m = c.head<3>().norm();
  out.correction_orientation_rad = c.tail<3>().norm();
  const double over = std::max(out.correction_position_m / s.max_correction_m,
                               out.correction_orientation_rad / s.max_correction_rad);
  if (over <= 1.0) {
    out.applied = true;
    out.outcome = CompensationOutcome::kApplied;
    out.corrected_in_tracker = corrected;
    out.q_rad = ik.q_rad;
    return out;
  }
  out.bound_correction_m = s.max_correction_m;
  out.bound_correction_rad = s.max_correction_rad;
  if (s.on_exceed == ExceedAction::kRefuse) {
    out.outcome = CompensationOutcome::kOverBound;
    return out;
  }
  // Clamp: the same correction direction, scaled to the bound.
  const double k = 1.0 / over;
  Pose clamped = Pose::Identity();
  clamped.translation() = desired.translation() + k * c.head<3>();
  clamped.linear() = expSO3(k * c.tail<3>()) * desired.linear();
  const IkResult back = solveInverseKinematics(nominal, nominal.nominal, clamped, ik.q_rad, ik_options);
  if (!back.ok()) {
    out.outcome = CompensationOutcome::kClampUnreachable;
    out.ik_position_error_m = back.position_error_m;
    out.ik_orientation_error_rad = back.orientation_error_rad;
    return out;
  }
  out.applied = true;
  out.clamped = true;
  out.outcome = CompensationOutcome::kClamped;
  out.corrected_in_tracker = clamped;
  out.q_rad = back.q_rad;
  return out;
}

}  // namespace

CompensationResult compensate(const RobotModel& nominal, const IdentifiedModel& model, const Pose& desired,
                              const Eigen::VectorXd& q_seed, const CompensationSettings& s,
                              const std::vector<Eigen::VectorXd>& path) {
  CompensationResult out;
  out.corrected_in_tracker = desired;
  const Eigen::VectorXd& identified = model.params;
  if (identified.size() != nominal.numParams() || !identified.allFinite() ||
      model.extension_params.size() != numExtensionParams(nominal, model.extensions) ||
      !model.extension_params.allFinite()) {
    out.outcome = CompensationOutcome::kUnusableModel;
    return out;
  }
  Eigen::VectorXd seed = q_seed;
  if (seed.size() != nominal.numJoints() || !seed.allFinite() || !nominal.withinLimits(seed)) {
    seed = Eigen::VectorXd::Zero(nominal.numJoints());
    for (int j = 0; j < nominal.numJoints(); ++j)
      seed[j] = 0.5 * (nominal.limits[j].lower_rad + nominal.limits[j].upper_rad);
  }
  // The controller's own joints for the target are within a fraction of a degree of the answer, on its branch: one
  // descent from them, at most 100 iterations (quadratic convergence takes 3-5). A target it does not reach is
  // refused, not searched for: restarts (a path from the seed, a saddle escape, other branches) rescued none of the
  // 3 % of random targets the seed did not reach (BM_Compensate: near a wrist singularity, 0.1 mm off) and cost
  // 30 us a target on average, up to a millisecond each; another branch must not be commanded anyway.
  IkOptions ik_options;
  ik_options.max_iterations = 100;
  ik_options.restarts = 0;
  ik_options.extend_when_descending = false;
  IkResult ik = solveInverseKinematics(nominal, identified, desired, seed, ik_options);
  const bool mapped = model.residual_map && !model.residual_map->empty();
  // The drivers of the extensions at q: the path to it (a play state; no thermal driver: 0).
  auto driversAt = [&](const Eigen::VectorXd& q) {
    return moveDrivers(path.empty() ? std::vector<Eigen::VectorXd>{seed} : path, q);
  };
  if ((!model.extensions.empty() || mapped) && ik.ok()) {
    if (!settle(nominal, model, desired, driversAt, ik_options, ik, out)) return out;
  }
  if (!ik.ok() || ik.position_error_m > s.max_ik_error_m) {
    out.outcome = CompensationOutcome::kUnreachable;
    out.ik_position_error_m = ik.position_error_m;
    out.ik_orientation_error_rad = ik.orientation_error_rad;
    return out;
  }
  KinematicsData data(nominal);
  // Where the extensions were never judged (beyond_data), their correction is not known.
  const BeyondRange* unjudged = model.extensions.empty() ? nullptr : firstUnjudged(model.beyond_data, ik.q_rad);
  const Drivers at = model.beyond_drivers.empty() ? Drivers{} : driversAt(ik.q_rad);
  double driver_x = 0;
  const DriverRange* unjudged_driver =
      model.extensions.empty() ? nullptr
                               : firstUnjudged(nominal, identified, model.beyond_drivers, ik.q_rad, at, &driver_x);
  if (unjudged || unjudged_driver)
    out.unjudged = rangeAt(unjudged, unjudged_driver, ik.q_rad, driver_x);
  else  // judged: within the data, or beyond it within the judged distance
    out.beyond_data = static_cast<bool>(firstBeyondData(nominal, model, ik.q_rad, at));
  if (!out.unjudged.empty() && s.max_predicted_sigma_m > 0) {
    out.predicted_sigma_position_m = std::numeric_limits<double>::infinity();
    out.outcome = CompensationOutcome::kNeverJudged;
    return out;
  }
  if (!model.estimated.empty() && model.covariance.rows() == model.numEstimated()) {
    out.predicted_sigma_position_m = predictedSigma(nominal, data, model, ik.q_rad, at, out.residual_map_applied);
    if (s.max_predicted_sigma_m > 0 && !(out.predicted_sigma_position_m <= s.max_predicted_sigma_m)) {
      out.outcome = CompensationOutcome::kOutsideCalibration;
      out.bound_sigma_m = s.max_predicted_sigma_m;
      return out;
    }
  }
  if (!out.unjudged.empty())  // guard off: said, applied
    out.predicted_sigma_position_m = std::numeric_limits<double>::infinity();
  return applyCorrection(nominal, data, desired, ik, s, ik_options, std::move(out));
}

ProgramCompensation compensateProgram(const RobotModel& nominal, const IdentifiedModel& identified,
                                      const std::vector<Eigen::VectorXd>& program, const CompensationSettings& settings) {
  ProgramCompensation out;
  KinematicsData data(nominal);
  for (const Eigen::VectorXd& q : program) {
    out.results.push_back(compensate(nominal, identified, forwardKinematics(nominal, data, nominal.nominal, q), q, settings));
    const CompensationResult& r = out.results.back();
    RangeAt where;
    if (r.applied && r.beyond_data) {
      // The drivers as compensate took them: seeded at q (within the limits: a program's configuration), no path.
      const BeyondAt at = firstBeyondData(nominal, identified, r.q_rad,
                                          identified.beyond_drivers.empty() ? Drivers{} : moveDrivers({q}, r.q_rad));
      where = rangeAt(at.joint, at.driver, r.q_rad, at.x);
      ++out.beyond_data;
    }
    out.beyond_data_at.push_back(std::move(where));
    if (r.applied) ++out.applied;
    else if (!r.unjudged.empty()) ++out.unjudged;
    else ++out.refused;
  }
  return out;
}

std::string describe(const RangeAt& r) {
  return r.joint ? unjudgedText(*r.joint, r.at) : r.driver ? unjudgedText(*r.driver, r.at) : std::string();
}

std::string describe(const CompensationResult& r) {
  std::ostringstream m;
  auto ik = [&] {
    m << "target out of reach within the joint limits: closest pose found is " << r.ik_position_error_m * 1e3
      << " mm and " << r.ik_orientation_error_rad * 180 / kPi << " deg away";
  };
  auto over = [&] {
    m << "correction " << r.correction_position_m * 1e3 << " mm / " << r.correction_orientation_rad * 180 / kPi
      << " deg exceeds the bound " << r.bound_correction_m * 1e3 << " mm / " << r.bound_correction_rad * 180 / kPi << " deg";
  };
  switch (r.outcome) {
    case CompensationOutcome::kApplied: break;
    case CompensationOutcome::kClamped: over(); m << ": clamped to the bound"; break;
    case CompensationOutcome::kUnusableModel: m << "identified parameters unusable (size or NaN)"; break;
    case CompensationOutcome::kUnreachable: m << "the identified model cannot reach the target: "; ik(); break;
    case CompensationOutcome::kNotSettled:
      m << (r.settled_extensions ? "the extended model's joint solution did not settle"
                                 : "the joint solution with the residual map did not settle");
      break;
    case CompensationOutcome::kOutsideCalibration:
      m << "predicted error " << r.predicted_sigma_position_m * 1e3 << " mm (1 sigma) at this target above "
        << "compensation.max_predicted_sigma_mm " << r.bound_sigma_m * 1e3
        << ": outside the region the model was calibrated in, passed through uncorrected";
      break;
    case CompensationOutcome::kOverBound: over(); m << ": refused"; break;
    case CompensationOutcome::kClampUnreachable: over(); m << "; clamped pose unreachable: "; ik(); break;
    case CompensationOutcome::kJointJump: m << "the joint solution moves a joint beyond the bound"; break;
    case CompensationOutcome::kNeverJudged:
      m << describe(r.unjudged) << ": the extensions' correction there was never tested, passed through uncorrected";
      break;
    case CompensationOutcome::kBadInput: m << "not finite, or the wrong number of joints"; break;
  }
  return m.str();
}

}  // namespace cellcal
