#include "cellcal/core/identification/pose_plan.hpp"

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/pose_selection.hpp"
#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/model_extension.hpp"

namespace cellcal {
namespace {

// Distance from point p to the segment a-b.
double segmentPointDistance(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& p) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

// Shortest distance between the segments p0-p1 and q0-q1 (closest points on both, clamped).
double segmentDistance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, const Eigen::Vector3d& q0,
                       const Eigen::Vector3d& q1) {
  const Eigen::Vector3d d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  if (a <= 1e-18 && e <= 1e-18) return r.norm();
  if (a <= 1e-18) return segmentPointDistance(q0, q1, p0);
  if (e <= 1e-18) return segmentPointDistance(p0, p1, q0);
  const double c = d1.dot(r), b = d1.dot(d2), denom = a * e - b * b;
  double s = denom > 1e-18 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
  double t = (b * s + f) / e;
  if (t < 0) {
    t = 0;
    s = std::clamp(-c / a, 0.0, 1.0);
  } else if (t > 1) {
    t = 1;
    s = std::clamp((b - c) / a, 0.0, 1.0);
  }
  return ((p0 + s * d1) - (q0 + t * d2)).norm();
}

Eigen::VectorXd inBase(const RobotModel& model, const Eigen::VectorXd& params) {
  Eigen::VectorXd p = params;
  p.segment<6>(model.baseParam(FrameParam::kX)).setZero();
  return p;
}

// Rows whitened, columns over `estimated` scaled by the prior sigmas: the stacked Jacobian of the configurations.
Eigen::MatrixXd scaledJacobian(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                               const std::vector<Eigen::VectorXd>& qs, MeasurementKind kind, double sp, double so,
                               double prior_length_m, double prior_angle_rad) {
  const int rows = kind == MeasurementKind::kPose6D ? 6 : 3;
  const auto m = static_cast<Eigen::Index>(estimated.size());
  Eigen::MatrixXd A(static_cast<Eigen::Index>(qs.size()) * rows, m);
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams());
  for (size_t i = 0; i < qs.size(); ++i) {
    forwardKinematics(model, data, params, qs[i]);
    computePoseJacobian(model, data, J);
    for (Eigen::Index k = 0; k < m; ++k) {
      const double scale = model.isLength(estimated[static_cast<size_t>(k)]) ? prior_length_m : prior_angle_rad;
      A.block(static_cast<Eigen::Index>(i) * rows, k, 3, 1) = J.col(estimated[static_cast<size_t>(k)]).head<3>() * (scale / sp);
      if (rows == 6)
        A.block(static_cast<Eigen::Index>(i) * rows + 3, k, 3, 1) = J.col(estimated[static_cast<size_t>(k)]).tail<3>() * (scale / so);
    }
  }
  return A;
}

}  // namespace

double predictedPositionRms(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                    const Eigen::MatrixXd& P0, const std::vector<Eigen::VectorXd>& qs,
                    const std::vector<Eigen::VectorXd>& volume, const PosePlanOptions& o) {
  if (volume.empty()) return 0;
  // Information: P0^-1 + sum A_i^T A_i with A_i whitened (unscaled columns).
  const Eigen::MatrixXd A = scaledJacobian(model, params, estimated, qs, o.kind, o.sigma_position_m,
                                           o.sigma_orientation_rad, 1.0, 1.0);
  Eigen::MatrixXd info = P0.llt().solve(Eigen::MatrixXd::Identity(P0.rows(), P0.cols()));
  info.noalias() += A.transpose() * A;
  const Eigen::MatrixXd P = info.llt().solve(Eigen::MatrixXd::Identity(info.rows(), info.cols()));
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams()), B(3, static_cast<Eigen::Index>(estimated.size()));
  double sum = 0;
  for (const auto& q : volume) {
    forwardKinematics(model, data, params, q);
    computePoseJacobian(model, data, J);
    for (size_t k = 0; k < estimated.size(); ++k) B.col(static_cast<Eigen::Index>(k)) = J.col(estimated[k]).head<3>();
    sum += (B * P * B.transpose()).trace();
  }
  return std::sqrt(sum / static_cast<double>(volume.size()));
}

namespace {

// Fedorov's exchange after the greedy choice: each chosen pose is swapped for the candidate that lowers the predicted
// position variance over the volume most, trace(M P), while a swap lowers it (passes until none does, at most 10).
// Removing pose i leaves P_i = (J - A_i^T A_i)^-1 (J the information of the set); adding c gives
// trace(M P') = trace(M P_i) - trace((I + A_c P_i A_c^T)^-1 A_c P_i M P_i A_c^T).
void exchange(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
              const Eigen::MatrixXd& P0, const std::vector<Eigen::VectorXd>& candidates, std::vector<int>& chosen,
              const PosePlanOptions& o, int* exchanges) {
  const auto m = static_cast<Eigen::Index>(estimated.size());
  const int rows = o.kind == MeasurementKind::kPose6D ? 6 : 3;
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams());
  std::vector<Eigen::MatrixXd> A;  // whitened rows over `estimated`
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(m, m);
  for (const auto& q : candidates) {
    forwardKinematics(model, data, params, q);
    computePoseJacobian(model, data, J);
    Eigen::MatrixXd a(rows, m), b(3, m);
    for (Eigen::Index k = 0; k < m; ++k) {
      a.col(k).head<3>() = J.col(estimated[static_cast<size_t>(k)]).head<3>() / o.sigma_position_m;
      if (rows == 6) a.col(k).tail<3>() = J.col(estimated[static_cast<size_t>(k)]).tail<3>() / o.sigma_orientation_rad;
      b.col(k) = J.col(estimated[static_cast<size_t>(k)]).head<3>();
    }
    M.noalias() += b.transpose() * b;
    A.push_back(std::move(a));
  }
  const Eigen::MatrixXd I_m = Eigen::MatrixXd::Identity(m, m);
  const Eigen::MatrixXd info0 = P0.llt().solve(I_m);
  auto information = [&](const std::vector<int>& set, int except) {
    Eigen::MatrixXd info = info0;
    for (size_t k = 0; k < set.size(); ++k)
      if (static_cast<int>(k) != except) info.noalias() += A[static_cast<size_t>(set[k])].transpose() * A[static_cast<size_t>(set[k])];
    return info;
  };
  std::vector<bool> in_set(candidates.size(), false);
  for (int c : chosen) in_set[static_cast<size_t>(c)] = true;
  double current = (M * information(chosen, -1).llt().solve(I_m)).trace();
  for (int pass = 0; pass < 10; ++pass) {
    bool swapped = false;
    for (size_t k = 0; k < chosen.size(); ++k) {
      const Eigen::MatrixXd Pi = information(chosen, static_cast<int>(k)).llt().solve(I_m);
      const Eigen::MatrixXd G = Pi * M * Pi;
      const double base = (M * Pi).trace();
      int best = -1;
      double best_value = current * (1 - 1e-9);
      for (size_t c = 0; c < candidates.size(); ++c) {
        if (in_set[c]) continue;
        const Eigen::MatrixXd AP = A[c] * Pi;
        Eigen::MatrixXd S = AP * A[c].transpose();
        S.diagonal().array() += 1.0;
        const double value = base - S.llt().solve(A[c] * G * A[c].transpose()).trace();
        if (value < best_value) {
          best_value = value;
          best = static_cast<int>(c);
        }
      }
      if (best < 0) continue;
      in_set[static_cast<size_t>(chosen[k])] = false;
      in_set[static_cast<size_t>(best)] = true;
      chosen[k] = best;
      current = best_value;
      swapped = true;
      if (exchanges) ++*exchanges;
    }
    if (!swapped) break;
  }
}

}  // namespace

const char* visibilityName(Visibility v) {
  switch (v) {
    case Visibility::kVisible: return "visible";
    case Visibility::kOutOfRange: return "out of the tracker's range";
    case Visibility::kOccluded: return "the beam crosses the robot";
    case Visibility::kFacingAway: return "the target faces away from the tracker";
  }
  return "?";
}

Visibility visibility(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad,
                      const TrackerSetup& tracker) {
  const std::vector<Pose> F = chainFrames(model, inBase(model, params), q_rad);
  const Pose& target = F.back();
  const Eigen::Vector3d beam = tracker.position_in_base_m - target.translation();
  const double range = beam.norm();
  if (range < tracker.min_range_m || range > tracker.max_range_m) return Visibility::kOutOfRange;
  // Links from frame 0 (the base) to frame n: the beam must keep link_radius_m from each but the last two.
  const int n = model.numJoints();
  for (int i = 0; i + 2 < n; ++i)
    if (segmentDistance(tracker.position_in_base_m, target.translation(), F[static_cast<size_t>(i)].translation(),
                        F[static_cast<size_t>(i) + 1].translation()) < tracker.link_radius_m)
      return Visibility::kOccluded;
  if (tracker.acceptance_rad > 0 && target.linear().col(2).dot(beam / range) < std::cos(tracker.acceptance_rad))
    return Visibility::kFacingAway;
  return Visibility::kVisible;
}

ObservabilityIndices observabilityIndices(const RobotModel& model, const Eigen::VectorXd& params,
                                          const std::vector<int>& estimated, const std::vector<Eigen::VectorXd>& qs,
                                          MeasurementKind kind, double sigma_position_m, double sigma_orientation_rad,
                                          double prior_length_m, double prior_angle_rad) {
  ObservabilityIndices o;
  if (qs.empty() || estimated.empty()) return o;
  const Eigen::MatrixXd A = scaledJacobian(model, params, estimated, qs, kind, sigma_position_m, sigma_orientation_rad,
                                           prior_length_m, prior_angle_rad);
  const Eigen::VectorXd s = Eigen::JacobiSVD<Eigen::MatrixXd>(A).singularValues();
  const auto n = std::min(A.rows(), A.cols());
  if (n < A.cols()) return o;  // fewer rows than parameters: nothing is observable in every direction
  double log_sum = 0;
  for (Eigen::Index k = 0; k < n; ++k) log_sum += std::log(std::max(s[k], 1e-300));
  const double s1 = s[0], sn = s[n - 1];
  o.O1 = std::exp(log_sum / static_cast<double>(n)) / std::sqrt(static_cast<double>(A.rows()));
  o.O2 = s1 > 0 ? sn / s1 : 0;
  o.O3 = sn;
  o.O4 = s1 > 0 ? sn * sn / s1 : 0;
  return o;
}

bool PosePlanOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (count < 1) return fail("count must be >= 1");
  if (candidates < count) return fail("candidates must be >= count");
  if (!(sigma_position_m > 0) || !(sigma_orientation_rad > 0)) return fail("the sigmas must be > 0");
  if (!(prior_length_m > 0) || !(prior_angle_rad > 0)) return fail("the prior sigmas must be > 0");
  if (!(range_fraction > 0 && range_fraction <= 1)) return fail("range_fraction must be in (0, 1]");
  if (!(min_radius_m >= 0)) return fail("min_radius_m must be >= 0");
  if (tracker && !(tracker->min_range_m >= 0 && tracker->max_range_m > tracker->min_range_m))
    return fail("the tracker's range must be 0 <= min < max");
  if (tracker && !tracker->position_in_base_m.allFinite()) return fail("the tracker's position must be finite");
  return true;
}

std::string CandidateSet::tooFewText(int count, double min_radius_m) const {
  return "only " + std::to_string(q.size()) + " of " + std::to_string(drawn) + " random configurations can be measured (" +
         std::to_string(near_axis) + " within " + std::to_string(static_cast<int>(min_radius_m * 1e3)) +
         " mm of joint 1's axis, " + std::to_string(out_of_range) + " out of the tracker's range, " +
         std::to_string(occluded) + " with the beam crossing the robot, " + std::to_string(facing_away) +
         " facing away): fewer than the " + std::to_string(count) + " asked; place the tracker elsewhere, widen its "
         "range or draw more candidates";
}

CandidateSet measurableCandidates(const RobotModel& model, const Eigen::VectorXd& params, const PosePlanOptions& o) {
  CandidateSet set;
  std::mt19937_64 rng(o.seed);
  const Eigen::VectorXd p0 = inBase(model, params);
  KinematicsData data(model);
  const int n = model.numJoints();
  for (int k = 0; k < o.candidates; ++k) {
    Eigen::VectorXd q(n);
    for (int j = 0; j < n; ++j) {
      const double lo = std::max(model.limits[static_cast<size_t>(j)].lower_rad, -kPi) * o.range_fraction;
      const double hi = std::min(model.limits[static_cast<size_t>(j)].upper_rad, kPi) * o.range_fraction;
      q[j] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    ++set.drawn;
    if (forwardKinematics(model, data, p0, q).translation().head<2>().norm() < o.min_radius_m) {
      ++set.near_axis;
      continue;
    }
    if (o.tracker) {
      const Visibility v = visibility(model, params, q, *o.tracker);
      if (v == Visibility::kOutOfRange) ++set.out_of_range;
      if (v == Visibility::kOccluded) ++set.occluded;
      if (v == Visibility::kFacingAway) ++set.facing_away;
      if (v != Visibility::kVisible) continue;
    }
    set.q.push_back(q);
  }
  return set;
}

PosePlan planPoses(const RobotModel& model, const Eigen::VectorXd& params, const PosePlanOptions& o) {
  std::string error;
  if (!o.IsValid(&error)) throw std::invalid_argument("PosePlanOptions: " + error);
  PosePlan plan;
  CandidateSet set = measurableCandidates(model, params, o);
  plan.drawn = set.drawn;
  plan.near_axis = set.near_axis;
  plan.out_of_range = set.out_of_range;
  plan.occluded = set.occluded;
  plan.facing_away = set.facing_away;
  plan.feasible = static_cast<int>(set.q.size());
  if (plan.feasible < o.count) throw std::invalid_argument(set.tooFewText(o.count, o.min_radius_m));
  const std::vector<Eigen::VectorXd>& feasible = set.q;
  // The random comparison set is drawn after the candidates, from the same seed's stream as before.
  std::mt19937_64 rng(o.seed);
  rng.discard(static_cast<unsigned long long>(set.drawn) * static_cast<unsigned long long>(model.numJoints()));
  // The uncalibrated robot's prior over what these measurements identify.
  const GaussianPrior prior = diagonalPrior(model, params, model.canonicalParams(), o.prior_length_m, o.prior_angle_rad);
  const RlsCalibrator rls(model, params, prior, o.kind);
  plan.estimated = rls.estimated();
  const Eigen::MatrixXd P0 = rls.covariance();
  PoseSelectionOptions sel;
  sel.criterion = SelectionCriterion::kPredictionVariance;
  sel.kind = o.kind;
  sel.sigma_position_m = o.sigma_position_m;
  sel.sigma_orientation_rad = o.sigma_orientation_rad;
  std::vector<int> chosen = selectInformativePoses(model, params, plan.estimated, P0, feasible, o.count, sel);
  exchange(model, params, plan.estimated, P0, feasible, chosen, o, &plan.exchanges);
  for (int i : chosen) plan.chosen_q.push_back(feasible[static_cast<size_t>(i)]);
  std::vector<Eigen::VectorXd> shuffled = feasible;
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  plan.random_q.assign(shuffled.begin(), shuffled.begin() + o.count);
  plan.chosen = observabilityIndices(model, params, plan.estimated, plan.chosen_q, o.kind, o.sigma_position_m,
                                     o.sigma_orientation_rad, o.prior_length_m, o.prior_angle_rad);
  plan.random = observabilityIndices(model, params, plan.estimated, plan.random_q, o.kind, o.sigma_position_m,
                                     o.sigma_orientation_rad, o.prior_length_m, o.prior_angle_rad);
  plan.chosen_predicted_rms_m = predictedPositionRms(model, params, plan.estimated, P0, plan.chosen_q, feasible, o);
  plan.random_predicted_rms_m = predictedPositionRms(model, params, plan.estimated, P0, plan.random_q, feasible, o);
  plan.prior_covariance = P0;
  plan.feasible_q = std::move(set.q);
  return plan;
}

std::vector<Eigen::VectorXd> configurationsAround(const RobotModel& model, const Eigen::VectorXd& params,
                                                  const Eigen::VectorXd& q_rad, int count, double spread_rad,
                                                  const std::optional<TrackerSetup>& tracker, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::VectorXd> out;
  for (int draw = 0; draw < 50 * count && static_cast<int>(out.size()) < count; ++draw) {
    Eigen::VectorXd q = q_rad;
    for (int j = 0; j < q.size(); ++j) q[j] += spread_rad * u(rng);
    if (!model.withinLimits(q)) continue;
    if (tracker && visibility(model, params, q, *tracker) != Visibility::kVisible) continue;
    out.push_back(q);
  }
  return out;
}

}  // namespace cellcal
