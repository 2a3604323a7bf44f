#include "cellcal/core/inverse_kinematics.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <random>
#include <sstream>

namespace cellcal {

bool IkOptions::IsValid(std::string* error) const {
  if (max_iterations < 1 || restarts < 0 || !(position_tolerance_m > 0) || !(orientation_tolerance_rad > 0) ||
      !(damping >= 0) || !(orientation_weight_m > 0)) {
    if (error) *error = "IkOptions: iterations >= 1, restarts >= 0, tolerances > 0, damping >= 0, weight > 0";
    return false;
  }
  return true;
}

namespace {
struct Attempt {
  Eigen::VectorXd q;
  double pos = 0, ori = 0;
  int iterations = 0;
};

Attempt descend(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params, const Pose& target,
                Eigen::VectorXd q, const IkOptions& o) {
  const int n = model.numJoints();
  const int rows = o.kind == MeasurementKind::kPose6D ? 6 : 3;
  Eigen::MatrixXd J(6, n);
  // Weighted error: orientation rows count as orientation_weight_m metres per radian.
  auto error = [&](const Eigen::VectorXd& qq, Eigen::VectorXd& e) {
    const Eigen::Matrix<double, 6, 1> full = poseError(target, forwardKinematics(model, data, params, qq));
    e = full.head(rows);
    if (rows == 6) e.tail(3) *= o.orientation_weight_m;
  };
  auto clampToLimits = [&](Eigen::VectorXd& qq) {
    for (int j = 0; j < n; ++j) qq[j] = std::clamp(qq[j], model.limits[j].lower_rad, model.limits[j].upper_rad);
  };
  Attempt a;
  Eigen::VectorXd e, e_trial;
  error(q, e);
  double lambda = std::max(o.damping, 1e-6);  // Levenberg-Marquardt: grows on a failed step, shrinks on a good one
  for (a.iterations = 0; a.iterations < o.max_iterations; ++a.iterations) {
    a.pos = e.head(3).norm();
    a.ori = rows == 6 ? e.tail(3).norm() / o.orientation_weight_m : 0.0;
    if (a.pos < o.position_tolerance_m && a.ori < o.orientation_tolerance_rad) break;
    // `data` holds the FK of q: the last evaluation was error(q) or the accepted trial that became q.
    computeJointJacobian(model, data, J);
    Eigen::MatrixXd Jr = J.topRows(rows);
    if (rows == 6) Jr.bottomRows(3) *= o.orientation_weight_m;
    bool improved = false;
    for (int tries = 0; tries < 30 && !improved; ++tries) {
      // dq = J^T (J J^T + lambda I)^-1 e, then clamp to the limits.
      Eigen::MatrixXd JJt = Jr * Jr.transpose();
      JJt.diagonal().array() += lambda;
      Eigen::VectorXd q_trial = q + Jr.transpose() * JJt.ldlt().solve(e);
      clampToLimits(q_trial);
      error(q_trial, e_trial);
      if (e_trial.squaredNorm() < e.squaredNorm()) {
        q = q_trial;
        e = e_trial;
        lambda = std::max(o.damping, lambda * 1e-3);
        improved = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved) break;  // stuck (local minimum or at a limit): let a restart try elsewhere
  }
  a.pos = e.head(3).norm();
  a.ori = rows == 6 ? e.tail(3).norm() / o.orientation_weight_m : 0.0;
  a.q = q;
  return a;
}
}  // namespace

IkResult solveInverseKinematics(const RobotModel& model, const Eigen::VectorXd& params, const Pose& target_in_tracker,
                                const Eigen::VectorXd& q_seed_rad, const IkOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument(err);
  if (q_seed_rad.size() != model.numJoints()) throw std::invalid_argument("IK seed has the wrong number of joints");
  KinematicsData data(model);
  std::mt19937_64 rng(12345);
  Eigen::VectorXd seed = q_seed_rad;
  for (int j = 0; j < model.numJoints(); ++j)
    seed[j] = std::clamp(seed[j], model.limits[j].lower_rad, model.limits[j].upper_rad);
  Attempt best;
  bool have_best = false;
  IkResult res;
  for (int attempt = 0; attempt <= options.restarts; ++attempt) {
    // Restarts: first around the given seed with growing spread (the right branch is usually near it; near a
    // singularity the first descent can slide into a neighbouring branch's shallow minimum), then anywhere.
    if (attempt > 0 && attempt <= options.restarts / 2) {
      std::normal_distribution<double> g(0.0, 0.05 * attempt);
      for (int j = 0; j < model.numJoints(); ++j)
        seed[j] = std::clamp(q_seed_rad[j] + g(rng), model.limits[j].lower_rad, model.limits[j].upper_rad);
    } else if (attempt > 0) {
      for (int j = 0; j < model.numJoints(); ++j)
        seed[j] = std::uniform_real_distribution<double>(std::max(model.limits[j].lower_rad, -kPi),
                                                         std::min(model.limits[j].upper_rad, kPi))(rng);
    }
    Attempt a = descend(model, data, params, target_in_tracker, seed, options);
    res.iterations += a.iterations;
    const double score = a.pos + options.orientation_weight_m * a.ori;
    if (!have_best || score < best.pos + options.orientation_weight_m * best.ori) {
      best = a;
      have_best = true;
    }
    if (a.pos < options.position_tolerance_m && a.ori < options.orientation_tolerance_rad) break;
  }
  res.q_rad = best.q;
  res.position_error_m = best.pos;
  res.orientation_error_rad = best.ori;
  if (best.pos < options.position_tolerance_m && best.ori < options.orientation_tolerance_rad) {
    res.status = IkStatus::kSolved;
    res.message = "solved";
  } else {
    std::ostringstream s;
    s << "target out of reach within the joint limits: closest pose found is " << best.pos * 1e3 << " mm and "
      << radToDeg(best.ori) << " deg away (" << options.restarts + 1 << " starts)";
    res.message = s.str();
  }
  return res;
}

}  // namespace cellcal
