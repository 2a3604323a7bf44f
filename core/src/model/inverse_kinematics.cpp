#include "cellcal/core/model/inverse_kinematics.hpp"

#include <Eigen/Cholesky>
#include <Eigen/SVD>
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
constexpr int kContinuationSteps = 8;

struct Attempt {
  Eigen::VectorXd q;
  double pos = 0, ori = 0;
  int iterations = 0;
  bool still_descending = false;  // stopped by the iteration budget, not by a minimum
};

Attempt descend(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params, const Pose& target,
                Eigen::VectorXd q, const IkOptions& o, int max_iterations) {
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
  a.still_descending = true;
  for (a.iterations = 0; a.iterations < max_iterations; ++a.iterations) {
    a.pos = e.head(3).norm();
    a.ori = rows == 6 ? e.tail(3).norm() / o.orientation_weight_m : 0.0;
    if (a.pos < o.position_tolerance_m && a.ori < o.orientation_tolerance_rad) {
      a.still_descending = false;
      break;
    }
    // `data` holds the FK of q: the last evaluation was error(q) or the accepted trial that became q.
    computeJointJacobian(model, data, J);
    Eigen::MatrixXd Jr = J.topRows(rows);
    if (rows == 6) Jr.bottomRows(3) *= o.orientation_weight_m;
    bool improved = false;
    for (int tries = 0; tries < 30 && !improved; ++tries) {
      // dq = J^T (J J^T + lambda I)^-1 e, then clamp to the limits.
      // Damping at least a tenth of the squared error (after Sugihara, "Solvability-unconcerned inverse kinematics by
      // the Levenberg-Marquardt method", 2011): far from the answer it keeps a near-singular wrist from spinning
      // joints 4 and 6 against each other into another branch or a limit; near it, it vanishes and the steps become
      // Gauss-Newton's.
      Eigen::MatrixXd JJt = Jr * Jr.transpose();
      JJt.diagonal().array() += std::max(lambda, 0.1 * e.squaredNorm());
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
    if (!improved) {  // stuck (local minimum or at a limit): let a restart try elsewhere
      a.still_descending = false;
      break;
    }
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
  const Eigen::VectorXd q_seed_rad_clamped = seed;
  Attempt best;
  bool have_best = false;
  IkResult res;
  for (int attempt = 0; attempt <= options.restarts; ++attempt) {
    // Restarts: first around the given seed with growing spread (the right branch is usually near it; near a
    // singularity the first descent can slide into a neighbouring branch's shallow minimum), then anywhere.
    if ((attempt == 2 || attempt == 3) && have_best) {
      // Out of a saddle: on an elbow or wrist singularity the error can point along the direction the arm cannot
      // move to first order, so Gauss-Newton sees no descent though bending away (either way) descends. Restart from
      // the best pose so far moved 0.1 rad along the Jacobian's weakest direction, one way, then the other.
      forwardKinematics(model, data, params, best.q);
      Eigen::MatrixXd J(6, model.numJoints());
      computeJointJacobian(model, data, J);
      if (options.kind == MeasurementKind::kPosition3D) J.bottomRows(3).setZero();
      J.bottomRows(3) *= options.orientation_weight_m;
      Eigen::JacobiSVD<Eigen::MatrixXd> svd(J, Eigen::ComputeFullV);
      const Eigen::VectorXd weakest = svd.matrixV().col(svd.matrixV().cols() - 1);
      const double sign = attempt == 2 ? 1.0 : -1.0;
      for (int j = 0; j < model.numJoints(); ++j)
        seed[j] = std::clamp(best.q[j] + sign * 0.1 * weakest[j] / weakest.cwiseAbs().maxCoeff(),
                             model.limits[j].lower_rad, model.limits[j].upper_rad);
    } else if (attempt > 3 && attempt <= options.restarts / 2 + 2) {
      std::normal_distribution<double> g(0.0, 0.05 * attempt);
      for (int j = 0; j < model.numJoints(); ++j)
        seed[j] = std::clamp(q_seed_rad[j] + g(rng), model.limits[j].lower_rad, model.limits[j].upper_rad);
    } else if (attempt > 0) {
      for (int j = 0; j < model.numJoints(); ++j)
        seed[j] = std::uniform_real_distribution<double>(std::max(model.limits[j].lower_rad, -kPi),
                                                         std::min(model.limits[j].upper_rad, kPi))(rng);
    }
    Attempt a;
    if (attempt == 1) {
      // Path following from the seed: the pose the seed reaches moved to the target in kContinuationSteps steps, each
      // solved from the last. It keeps the branch the seed is on where one long descent would cross an elbow or wrist
      // singularity into a neighbouring branch (which, on a perturbed arm, may only come near the target).
      const Pose from = forwardKinematics(model, data, params, q_seed_rad_clamped);
      const Eigen::Vector3d dw = logSO3(from.linear().transpose() * target_in_tracker.linear());
      Eigen::VectorXd q = q_seed_rad_clamped;
      for (int k = 1; k < kContinuationSteps; ++k) {
        const double t = static_cast<double>(k) / kContinuationSteps;
        Pose via = Pose::Identity();
        via.translation() = (1 - t) * from.translation() + t * target_in_tracker.translation();
        via.linear() = from.linear() * expSO3(t * dw);
        const Attempt step = descend(model, data, params, via, q, options, 50);
        res.iterations += step.iterations;
        q = step.q;
      }
      a = descend(model, data, params, target_in_tracker, q, options, options.max_iterations);
    } else {
      a = descend(model, data, params, target_in_tracker, seed, options, options.max_iterations);
    }
    res.iterations += a.iterations;
    const double score = a.pos + options.orientation_weight_m * a.ori;
    if (!have_best || score < best.pos + options.orientation_weight_m * best.ori) {
      best = a;
      have_best = true;
    }
    if (a.pos < options.position_tolerance_m && a.ori < options.orientation_tolerance_rad) break;
  }
  // Near a singular configuration the descent converges only linearly: an attempt the iteration budget stopped while
  // it was still descending goes on from where it stopped, with ten times the budget, before anyone is told that the
  // target is out of reach.
  if (!(best.pos < options.position_tolerance_m && best.ori < options.orientation_tolerance_rad) &&
      best.still_descending && options.extend_when_descending) {
    Attempt a = descend(model, data, params, target_in_tracker, best.q, options, 10 * options.max_iterations);
    res.iterations += a.iterations;
    if (a.pos + options.orientation_weight_m * a.ori < best.pos + options.orientation_weight_m * best.ori) best = a;
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
