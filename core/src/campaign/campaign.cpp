// calibrateCampaign for one set-up; several set-ups are in campaign_setups.cpp.
#include "cellcal/core/campaign/campaign.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/outliers.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "campaign_internal.hpp"

namespace cellcal {

bool CampaignProblem::IsValid(std::string* why) const {
  auto fail = [why](const std::string& s) {
    if (why) *why = s;
    return false;
  };
  if (setups.empty()) return fail("no set-up");
  for (size_t s = 0; s < setups.size(); ++s) {
    if (setups[s].data.identification.empty()) return fail("set-up " + std::to_string(s + 1) + ": no identification rows");
    if (setups[s].robot.numJoints() != setups[0].robot.numJoints() || setups[s].start.size() != setups[0].start.size())
      return fail("set-up " + std::to_string(s + 1) + ": another robot than set-up 1's");
  }
  if (model == CampaignModel::kNamed && extensions.empty()) return fail("model: named causes, but none given");
  if (frames_only && setups.size() > 1) return fail("frames only: one set-up");
  if (frames_only && model != CampaignModel::kGeometric) return fail("frames only keeps the robot file's model");
  if (solver == CampaignSolver::kLevenbergMarquardt && setups.size() > 1)
    return fail("the Levenberg-Marquardt solver takes one set-up");
  if (excitation_ratio < 0 || excitation_ratio >= 1) return fail("excitation_ratio: in [0, 1)");
  if (residual_map && !residual_map_options.IsValid(why)) return false;
  return outliers.IsValid(why);
}

double savedSigma(const PredictionModel& pm, int column) {
  for (size_t k = 0; k < pm.columns.size(); ++k)
    if (pm.columns[k] == column)
      return std::sqrt(std::max(0.0, pm.covariance(static_cast<Eigen::Index>(k), static_cast<Eigen::Index>(k))));
  return std::nan("");
}

namespace internal {

DiagnosisResult diagnoseForAuto(const CampaignProblem& problem, const CampaignInput& in, const std::string& stage) {
  DiagnosisOptions o;
  o.identifiability.rank_tolerance = problem.identifiability.rank_tolerance;
  o.identifiability.prior_sigma = problem.identifiability.prior_sigma;
  o.outliers = problem.outliers;
  o.excitation_ratio = problem.excitation_ratio;
  o.region_check = problem.region_check;
  if (problem.progress) o.progress = [&](int done, int total) { problem.progress(stage, done, total); };
  return diagnose(in.robot, in.start, in.data, o);
}

CampaignErrors campaignErrors(const RobotModel& robot, const ExtendedFit& before, const ExtendedFit& after,
                              const DiagnosisData& d, const OutlierScreen& identification_outliers,
                              const OutlierOptions& outliers) {
  CampaignErrors e;
  e.identification_before = errorStats(robot, before, d.identification, d.identification_drivers);
  e.identification_after = errorStats(robot, after, d.identification, d.identification_drivers);
  e.verification_before = errorStats(robot, before, d.verification, d.verification_drivers);
  e.verification_after = errorStats(robot, after, d.verification, d.verification_drivers);
  // Gross errors among the verification rows, judged against the calibrated model, and the figures without them.
  e.identification_outliers = identification_outliers;
  e.verification_outliers = screenRows(robot, after, d.verification, d.verification_drivers, outliers);
  const std::vector<int> vk = keptRows(static_cast<int>(d.verification.size()), e.verification_outliers.rows),
                         ik = keptRows(static_cast<int>(d.identification.size()), identification_outliers.rows);
  e.verification_kept_before = errorStats(robot, before, subset(d.verification, vk), subset(d.verification_drivers, vk));
  e.verification_kept_after = errorStats(robot, after, subset(d.verification, vk), subset(d.verification_drivers, vk));
  e.identification_kept_after =
      errorStats(robot, after, subset(d.identification, ik), subset(d.identification_drivers, ik));
  return e;
}

}  // namespace internal

namespace {

PredictionCheck checkPrediction(const RobotModel& robot, const ExtendedFit& fit, const PredictionModel& pm,
                                const std::vector<Observation>& ident, const std::vector<Drivers>& idr,
                                const std::vector<Observation>& verify, const std::vector<Drivers>& vdr) {
  PredictionCheck t;
  double sq = 0;
  for (size_t i = 0; i < ident.size(); ++i) {
    const double s = predictedPositionSigma(robot, fit, pm, ident[i].q_rad, idr[i]) * 1e3;
    sq += s * s;
    t.identification_max_mm = std::max(t.identification_max_mm, s);
  }
  t.identification_rms_mm = ident.empty() ? 0 : std::sqrt(sq / static_cast<double>(ident.size()));
  sq = 0;
  double ratio_sq = 0;
  KinematicsData data(robot);
  for (size_t i = 0; i < verify.size(); ++i) {
    const double s = predictedPositionSigma(robot, fit, pm, verify[i].q_rad, vdr[i]) * 1e3;
    sq += s * s;
    t.verification_max_mm = std::max(t.verification_max_mm, s);
    if (s > 3 * t.identification_max_mm) ++t.extrapolated;
    if (firstUnjudged(pm.beyond, verify[i].q_rad) ||
        firstUnjudged(robot, fit.params, pm.beyond_drivers, verify[i].q_rad, vdr[i], nullptr))
      ++t.beyond_checked;
    const Eigen::VectorXd p = extendedParams(robot, fit.params, fit.extensions, fit.extension_params, verify[i].q_rad, vdr[i]);
    const double actual_mm =
        (forwardKinematics(robot, data, p, verify[i].q_rad).translation() - verify[i].measured_in_tracker.translation()).norm() * 1e3;
    const double noise_mm = std::sqrt(3.0 * pm.variance_factor_position) * verify[i].sigma_position_m * 1e3;
    ratio_sq += actual_mm * actual_mm / (s * s + noise_mm * noise_mm);
  }
  t.verification_rms_mm = verify.empty() ? 0 : std::sqrt(sq / static_cast<double>(verify.size()));
  t.ratio_rms = verify.empty() ? 0 : std::sqrt(ratio_sq / static_cast<double>(verify.size()));
  return t;
}

// Joint parameters the fit moved further from the robot file than a robot that was built to its drawing could be:
// lengths 5 mm, angles 0.5 deg (base and tool frames are registered, not nominal).
std::vector<std::string> implausibleParameters(const RobotModel& robot, const Eigen::VectorXd& start,
                                               const ExtendedFit& fit) {
  std::vector<std::string> out;
  for (int i : fit.estimated) {
    if (i >= 5 * robot.numJoints()) continue;
    const double moved = robot.toHuman(i, fit.params[i] - start[i]);
    const double limit = robot.isLength(i) ? 5.0 : 0.5;
    if (std::abs(moved) > limit) {
      char buf[200];
      std::snprintf(buf, sizeof buf, "%s moved %+.3f %s from the robot file (more than %.1f)",
                    robot.paramNameHuman(i).c_str(), moved, robot.isLength(i) ? "mm" : "deg", limit);
      out.push_back(buf);
    }
  }
  return out;
}

// What the model leaves at the identification rows, learnt as a residual map and judged on the verification rows.
void judgeResidualMap(const RobotModel& robot, const ExtendedFit& fit, const std::vector<Observation>& ident,
                      const std::vector<Drivers>& idr, const std::vector<Observation>& verify,
                      const std::vector<Drivers>& vdr, const ResidualMapOptions& options, CampaignReport* report) {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Eigen::VectorXd> q;
  for (const auto& o : ident) q.push_back(o.q_rad);
  const ResidualMap& map = report->residual_map.emplace(fitResidualMap(q, positionResiduals(robot, fit, ident, idr), options));
  ResidualMapCheck& c = report->residual_map_check;
  c.fit_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const std::vector<Eigen::Vector3d> rv = positionResiduals(robot, fit, verify, vdr);
  double near_with = 0, near_without = 0, all_with = 0, all_without = 0, sigma = 0;
  int near = 0;
  for (size_t i = 0; i < verify.size(); ++i) {
    const ResidualMap::Prediction p = map.predict(verify[i].q_rad, true);
    const double without = rv[i].norm() * 1e3, with = (rv[i] - p.correction_m).norm() * 1e3;
    all_without += without;
    all_with += with;
    if (!p.applies) continue;
    ++near;
    near_with += with;
    near_without += without;
    sigma += p.sigma_m * 1e3;
  }
  const double n = static_cast<double>(std::max<size_t>(1, verify.size())), m = std::max(1, near);
  c.verification_rows = static_cast<int>(verify.size());
  c.verification_rows_near = near;
  c.near_mean_with_mm = near_with / m;
  c.near_mean_without_mm = near_without / m;
  c.near_sigma_mean_mm = sigma / m;
  c.all_mean_with_mm = all_with / n;
  c.all_mean_without_mm = all_without / n;
}

std::string fixed(double v, int digits) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}

// With frames only, the tool frame's translation (or rotation) that these rows leave open in some direction beyond
// kToolUnpinned (one tool orientation, or nearly: the target's place cannot be told from the base's) is held at the
// robot file's values, where its calibration put the target on the flange, and named with what the rows would give
// each parameter. A tool rotation that position readings do not see at all stays as it is (not estimated, not named).
constexpr double kToolUnpinnedM = 1e-3, kToolUnpinnedRad = 0.1 * kPi / 180;
void holdUnpinnedTool(const CampaignInput& in, CampaignReport& rep) {
  const RobotModel& robot = in.robot;
  ExtendedFit& after = rep.after;
  Eigen::MatrixXd cov;
  double variance_factor = 1;
  const std::vector<int> determined = conditionalCovariance(robot, after, in.data.identification,
                                                            in.data.identification_drivers, after.estimated, &cov,
                                                            &variance_factor);
  const double scale = std::sqrt(std::max(1.0, variance_factor));
  // The translation's three parameters, and the rotation's, share what the rows leave open (the flange's one
  // orientation turns them alike): each block is held whole when its weakest direction is unpinned.
  std::vector<int> held;
  for (const bool length : {true, false}) {
    std::vector<int> block;
    for (int k = length ? 0 : 3; k < (length ? 3 : 6); ++k) block.push_back(robot.toolParam(static_cast<FrameParam>(k)));
    std::vector<Eigen::Index> at;
    for (int c : block) {
      const auto it = std::find(determined.begin(), determined.end(), c);
      if (it != determined.end()) at.push_back(static_cast<Eigen::Index>(it - determined.begin()));
    }
    if (!length && at.empty()) continue;  // a rotation position readings do not see: not estimated, not named
    const double weakest = at.size() < block.size()
                               ? std::numeric_limits<double>::infinity()
                               : std::sqrt(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(cov(at, at)).eigenvalues().maxCoeff()) * scale;
    if (!(weakest > (length ? kToolUnpinnedM : kToolUnpinnedRad))) continue;
    for (size_t k = 0; k < block.size(); ++k) {
      const auto it = std::find(determined.begin(), determined.end(), block[k]);
      const double sigma = it == determined.end()
                               ? std::numeric_limits<double>::infinity()
                               : std::sqrt(cov(it - determined.begin(), it - determined.begin())) * scale;
      held.push_back(block[k]);
      rep.frames_held.emplace_back(block[k], sigma);
    }
  }
  if (held.empty()) return;
  Eigen::VectorXd p = after.params;
  for (int c : held) p[c] = robot.nominal[c];
  after.params = refineFrames(robot, p, after.extensions, after.extension_params, in.data.identification,
                              in.data.identification_drivers, 20, held).params;
  std::vector<int> estimated;
  for (int c : after.estimated)
    if (std::find(held.begin(), held.end(), c) == held.end()) estimated.push_back(c);
  after.estimated = estimated;
  rep.estimated = estimated.size();
}

// With frames only: the robot file's kinematics and extensions carried to these rows, its frames registered on them.
void registerFrames(const CampaignProblem& problem, const CampaignInput& in, CampaignReport& rep,
                    OutlierScreen* ident_outliers) {
  const RobotModel& robot = in.robot;
  const Eigen::VectorXd& start = in.start;
  const auto& ident = in.data.identification;
  const auto& verify = in.data.verification;
  const auto& idr = in.data.identification_drivers;
  const auto& vdr = in.data.verification_drivers;
  ExtendedFit& after = rep.after;
  // The robot file's kinematics and model extensions as they are; only where the robot stands in the tracker
  // frame and where the target sits on the flange are registered on these rows.
  after.extensions = in.calibration ? in.calibration->extensions : std::vector<Extension>{};
  after.extension_params = in.calibration ? in.calibration->extension_params : Eigen::VectorXd();
  after.extension_names = extensionParamNames(robot, after.extensions);
  const RegistrationResult rr = refineFrames(robot, start, after.extensions, after.extension_params, ident, idr);
  after.params = rr.params;
  for (int k = 0; k < 6; ++k) {
    after.estimated.push_back(robot.baseParam(static_cast<FrameParam>(k)));
    after.estimated.push_back(robot.toolParam(static_cast<FrameParam>(k)));
  }
  std::sort(after.estimated.begin(), after.estimated.end());
  after.converged = rep.converged = true;
  rep.iterations = rr.iterations;
  rep.estimated = 12;
  rep.model_label = "the robot file's (" + modelLabel(after.extensions) + "), frames only";
  // Its extensions against the same campaign's geometric calibration, both carried to these rows: the better one.
  if (in.calibration && in.calibration->geometric_params.size() == robot.numParams() && !after.extensions.empty()) {
    rep.carried = compareCarried(robot, after, in.calibration->geometric_params, ident, idr, verify, vdr);
    if (!rep.carried->extensions_transfer && !problem.keep_extensions) {
      after = rep.carried->geometric;
      rep.model_label =
          "the campaign's geometric calibration (the robot file's extensions do not transfer), frames only";
    }
  }
  // The carried model against the kinematics it started from, registered alike on the same rows: the better one.
  if (in.calibration && in.calibration->nominal_params.size() == robot.numParams()) {
    rep.against_nominal = compareWithNominal(robot, after, in.calibration->nominal_params, ident, idr, verify, vdr);
    rep.nominal_deployed = rep.against_nominal->nominal_better && !problem.keep_extensions;
    if (rep.nominal_deployed) {
      after = rep.against_nominal->nominal;
      rep.model_label = "the nominal kinematics (the robot file's calibration does worse on these rows), frames only";
    }
  }
  if (in.calibration) holdUnpinnedTool(in, rep);
  *ident_outliers = screenRows(robot, after, ident, idr, problem.outliers);
}

// The geometric calibration (rep.geometric), then the model asked for on top of it (rep.after).
void fitModel(const CampaignProblem& problem, const CampaignInput& in, CalibrationProblem& p, CampaignReport& rep,
              OutlierScreen* ident_outliers) {
  const RobotModel& robot = in.robot;
  const Eigen::VectorXd& start = in.start;
  const auto& ident = in.data.identification;
  const auto& verify = in.data.verification;
  const auto& idr = in.data.identification_drivers;
  const auto& vdr = in.data.verification_drivers;
  CalibrationResult& r = rep.geometric;
  ExtendedFit& after = rep.after;
  const std::vector<Extension> named =
      problem.model == CampaignModel::kNamed ? problem.extensions : std::vector<Extension>{};
  // Parameters the identification rows leave unexcited where a verification row excites them: held, and said.
  const std::vector<ExcitationDeficit> held =
      problem.excitation_ratio > 0
          ? excitationDeficits(robot, start, named, ident, idr, verify, vdr, problem.excitation_ratio)
          : std::vector<ExcitationDeficit>{};
  p.identifiability.rank_tolerance = problem.identifiability.rank_tolerance;
  p.identifiability.prior_sigma = problem.identifiability.prior_sigma;
  for (const auto& h : held)
    if (h.column < robot.numParams()) p.identifiability.held.push_back(h.column);
  std::string why;
  if (!p.IsValid(&why)) throw std::runtime_error(why);
  r = problem.solver == CampaignSolver::kLevenbergMarquardt ? solveLevenbergMarquardt(p) : solveGaussNewton(p);
  after = geometricFit(r);
  rep.held = held;
  *ident_outliers = r.outliers;
  rep.model_label = "geometric";
  rep.converged = r.converged;
  rep.iterations = r.iterations;
  rep.estimated = r.estimated.size();
  rep.message = r.message;
  if (problem.model != CampaignModel::kGeometric) {
    if (problem.model == CampaignModel::kAuto) {
      const DiagnosisResult& d = rep.diagnosis.emplace(internal::diagnoseForAuto(problem, in, ""));
      after = d.best().fit;
      rep.held = d.best().held;
      *ident_outliers = d.identification_outliers;
    } else {
      IdentifiabilityOptions io = p.identifiability;
      io.noise_scale = r.identifiability.noise_scale;  // the geometric fit's: what the model leaves counts as noise
      io.held = heldColumns(held);
      after = fitExtendedRobust(robot, start, ident, idr, named, {}, io, &r.params, p.outliers, ident_outliers);
    }
    rep.model_label = after.extensions.empty() ? "geometric (auto: no cause found)" : modelLabel(after.extensions);
    // The extended model stands on the geometric fit (its start, its rows' screen): both must have converged.
    if (!r.converged) rep.message = "the geometric fit beneath did not converge: " + r.message;
    rep.converged = r.converged && after.converged;
    rep.iterations = after.iterations;
    rep.estimated = after.estimated.size() + after.estimated_extension.size();
    if (r.converged) rep.message = after.message;
  }
}

// How far the model can be trusted: its predicted position error on every kept row, against the actual one. With
// frames only, the robot file's covariance carried to these rows less what the new frames take up of it
// (carriedPrediction); a robot file without a calibration section carries the priors of a model no one calibrated.
PredictionModel campaignPrediction(const CampaignProblem& problem, const CampaignInput& in, const CampaignReport& rep,
                                   const std::vector<Observation>& ident_kept, const std::vector<Drivers>& idr_kept) {
  const RobotModel& robot = in.robot;
  const ExtendedFit& after = rep.after;
  if (!problem.frames_only) {
    PredictionModel own = predictionModel(robot, after, ident_kept, idr_kept);
    own.beyond = rep.beyond;
    own.beyond_drivers = rep.beyond_drivers;
    return own;
  }
  PredictionModel carried;
  if (in.calibration && !rep.nominalDeployed()) {
    // Over the kinematic parameters alone where the extensions were left for the geometric calibration (its own
    // covariance is not in the file: the extended fit's, marginal, stands for it).
    const auto& kc = in.calibration->columns;
    std::vector<Eigen::Index> keep;
    for (size_t k = 0; k < kc.size(); ++k)
      if (!after.extensions.empty() || kc[k] < robot.numParams()) keep.push_back(static_cast<Eigen::Index>(k));
    for (Eigen::Index k : keep) carried.columns.push_back(kc[static_cast<size_t>(k)]);
    carried.covariance = in.calibration->covariance(keep, keep);
  } else {
    carried = predictionModel(robot, after, {}, {});
  }
  // The readings' noise on these rows as the frames leave it, position and orientation rows apart (their sigmas may
  // not be the campaign's, and a tracker may understate one kind).
  carried.beyond = rep.beyond;  // what the extensions may do beyond the campaign's joint ranges (its region folds)
  carried.beyond_drivers = rep.beyond_drivers;  // and its drivers' ranges
  return carriedPrediction(robot, after, carried, ident_kept, idr_kept, after.estimated,
                           residualVarianceFactors(robot, after, ident_kept, idr_kept,
                                                   static_cast<int>(after.estimated.size())));
}

// What a robot file saves (rep.calibration), once the calibration is usable.
void saveCalibration(const CampaignProblem& problem, const CampaignInput& in, CampaignReport& rep) {
  const RobotModel& robot = in.robot;
  const auto& ident = in.data.identification;
  const auto& verify = in.data.verification;
  const ExtendedFit& after = rep.after;
  const CalibrationResult& r = rep.geometric;
  const CampaignErrors& e = rep.errors;
  const PredictionModel& pm = rep.prediction;
  RobotCalibration& cal = rep.calibration;
  cal = robotCalibration(robot, after, pm);
  cal.residual_map = rep.residual_map;
  if (!after.extensions.empty()) cal.beyond_data = rep.beyond, cal.beyond_drivers = rep.beyond_drivers;
  // Beside an extended model, the same campaign's geometric calibration (a new set-up judges the extensions by it).
  if (!after.extensions.empty())
    cal.geometric_params = !problem.frames_only ? r.params
                           : rep.carried        ? rep.carried->geometric.params
                           : in.calibration     ? in.calibration->geometric_params
                                                : Eigen::VectorXd();
  // The kinematics it started from: a recalibration or a carried model keeps the robot file's.
  cal.nominal_params = in.calibration && in.calibration->nominal_params.size() == robot.numParams()
                           ? in.calibration->nominal_params
                           : problem.frames_only ? Eigen::VectorXd() : Eigen::VectorXd(robot.nominal);
  if (problem.frames_only && !rep.nominalDeployed()) {  // estimated: the new frames, and what the file's calibration estimated
    for (size_t k = 0; k < cal.columns.size(); ++k) {
      if (cal.estimated[k] || !in.calibration) continue;
      const auto& kc = in.calibration->columns;
      const auto it = std::find(kc.begin(), kc.end(), cal.columns[k]);
      cal.estimated[k] = it != kc.end() && in.calibration->estimated[static_cast<size_t>(it - kc.begin())];
    }
  }
  if (problem.frames_only && in.calibration && !rep.nominalDeployed())
    for (const auto& kv : in.calibration->provenance) cal.provenance.emplace_back("kinematics_" + kv.first, kv.second);
  std::vector<std::pair<std::string, std::string>> pv = problem.provenance;
  for (const auto& kv : std::vector<std::pair<std::string, std::string>>{
           {"rows", std::to_string(in.file.rows.size())},
           {"split", in.split},
           {"identification_rows", std::to_string(ident.size())},
           {"verification_rows", std::to_string(verify.size())},
           {"measurement", in.measurementName()},
           {"model", !problem.frames_only ? rep.model_label
                     : rep.nominalDeployed() ? "nominal kinematics, frames only"
                                             : "frames only"},
           {"verification_before_mean_mm", fixed(e.verification_kept_before.mean_mm, 4)},
           {"verification_mean_mm", fixed(e.verification_kept_after.mean_mm, 4)},
           {"verification_rms_mm", fixed(e.verification_kept_after.rms_mm, 4)},
           {"verification_max_mm", fixed(e.verification_kept_after.max_mm, 4)},
           {"identification_max_mm", fixed(e.identification_kept_after.max_mm, 4)},
           {"predicted_verification_rms_mm", fixed(rep.check.verification_rms_mm, 4)}})
    pv.push_back(kv);
  for (auto& kv : cal.provenance) pv.push_back(kv);
  cal.provenance = pv;
}

CampaignReport calibrateOne(const CampaignProblem& problem) {
  CampaignReport rep;
  rep.frames_only = problem.frames_only;
  const CampaignInput& in = problem.setups.front();
  const RobotModel& robot = in.robot;
  const auto& ident = in.data.identification;
  const auto& verify = in.data.verification;
  const Eigen::VectorXd& start = in.start;
  using Clock = std::chrono::steady_clock;
  const auto t1 = Clock::now();
  const auto& idr = in.data.identification_drivers;
  const auto& vdr = in.data.verification_drivers;
  CalibrationProblem p{&robot, start, ident, std::nullopt, {}, {}};
  p.outliers = problem.outliers;
  CalibrationResult& r = rep.geometric;
  ExtendedFit& after = rep.after;
  OutlierScreen ident_outliers;
  if (problem.frames_only) registerFrames(problem, in, rep, &ident_outliers);
  else fitModel(problem, in, p, rep, &ident_outliers);
  rep.solve_s = std::chrono::duration<double>(Clock::now() - t1).count();
  // 'before': the nominal kinematics at their least-squares frames (with frames only, the carried model's nominal
  // when the robot file keeps it).
  rep.before = rep.against_nominal ? rep.against_nominal->nominal : geometricFit(start);
  rep.errors = internal::campaignErrors(robot, rep.before, after, in.data, ident_outliers, p.outliers);
  const CampaignErrors& e = rep.errors;
  const std::vector<int> vk = keptRows(static_cast<int>(verify.size()), e.verification_outliers.rows);
  const std::vector<Observation> verify_kept = subset(verify, vk);
  const std::vector<Drivers> vdr_kept = subset(vdr, vk);
  const std::vector<int> ik = keptRows(static_cast<int>(ident.size()), ident_outliers.rows);
  const std::vector<Observation> ident_kept = subset(ident, ik);
  const std::vector<Drivers> idr_kept = subset(idr, ik);
  // The frames' own uncertainty with frames only: their covariance on these rows, the kinematics as the file has
  // them, scaled by what the frames leave (the kinematics' error on this set-up is in that residual).
  if (problem.frames_only) {  // a frame parameter these rows do not determine (a tool rotation from points) is not estimated
    after.estimated = conditionalCovariance(robot, after, ident_kept, idr_kept, after.estimated, &after.covariance,
                                            &rep.frames_variance_factor);
    rep.estimated = after.estimated.size();
  }
  // What the extensions are worth beyond their data (prediction.hpp): measured on region folds of the identification
  // rows, saved in the robot file, carried by frames only.
  if (!problem.frames_only && !after.extensions.empty() && after.converged) {
    DiagnosisOptions o;
    o.identifiability = p.identifiability;
    o.identifiability.noise_scale = r.identifiability.noise_scale;
    o.excitation_ratio = problem.excitation_ratio;
    rep.transfer = extensionTransfer(robot, start, after, ident_kept, idr_kept, o);
  }
  // Carried with frames only where the robot file's extensions are kept.
  rep.beyond = rep.transfer ? rep.transfer->beyond()
               : problem.frames_only && in.calibration && !after.extensions.empty() ? in.calibration->beyond_data
                                                                                  : std::vector<BeyondRange>{};
  rep.beyond_drivers = rep.transfer ? rep.transfer->beyondDrivers()
                       : problem.frames_only && in.calibration && !after.extensions.empty()
                           ? in.calibration->beyond_drivers
                           : std::vector<DriverRange>{};
  rep.prediction = campaignPrediction(problem, in, rep, ident_kept, idr_kept);
  const PredictionModel& pm = rep.prediction;
  rep.check = checkPrediction(robot, after, pm, ident_kept, idr_kept, verify_kept, vdr_kept);
  // With frames only the start is the same model with its frames registered in closed form: no baseline to beat,
  // only the extrapolation rule applies.
  rep.unusable = unusableFit(problem.frames_only ? e.verification_kept_after : e.verification_kept_before,
                             e.verification_kept_after, e.identification_kept_after);
  if (rep.against_nominal && rep.against_nominal->nominal_better && !rep.nominal_deployed && rep.unusable.empty()) {
    char buf[300];
    std::snprintf(buf, sizeof buf,
                  "the robot file's model, kept by --keep-extensions, does worse on these rows than its nominal "
                  "kinematics registered alike (%.4f mm held-out mean against %.4f mm)",
                  rep.against_nominal->mean_carried_mm, rep.against_nominal->mean_nominal_mm);
    rep.unusable = buf;
  }
  rep.implausible = implausibleParameters(robot, start, after);
  if (problem.residual_map)
    judgeResidualMap(robot, after, ident_kept, idr_kept, verify_kept, vdr_kept, problem.residual_map_options, &rep);
  if (rep.exitCode() != 0) return rep;

  saveCalibration(problem, in, rep);
  rep.saved_params = after.params;
  return rep;
}

}  // namespace

// The last line of a calibration (campaign.hpp).
std::string recommendationText(const CampaignReport& rep) {
  if (rep.several_setups) return "";
  const ErrorStats& before = rep.errors.verification_kept_before;
  const ErrorStats& after = rep.errors.verification_kept_after;
  const std::string& model = rep.model_label;
  const bool frames_only = rep.frames_only;
  const double variance_factor = rep.prediction.variance_factor_position;
  const int extrapolated = rep.check.extrapolated;
  char buf[640];
  if (!rep.converged) return "recommendation: do not deploy: the solver did not converge (exit 3)";
  if (!rep.unusable.empty()) return "recommendation: do not deploy: " + rep.unusable + " (exit 4)";
  const double gain = before.mean_mm > 0 ? 100.0 * (1.0 - after.mean_mm / before.mean_mm) : 0.0;
  if (frames_only && rep.nominalDeployed())
    std::snprintf(buf, sizeof buf, "recommendation: deploy the nominal kinematics with these frames: held-out mean "
                  "%.4f mm against %.4f mm for the robot file's calibration registered alike (it does not hold on these "
                  "rows: calibrate again)", rep.against_nominal->mean_nominal_mm, rep.against_nominal->mean_carried_mm);
  else if (frames_only && rep.against_nominal)
    std::snprintf(buf, sizeof buf, "recommendation: deploy the robot file's model with these frames: held-out mean "
                  "%.4f mm against %.4f mm for its nominal kinematics registered alike",
                  rep.against_nominal->mean_carried_mm, rep.against_nominal->mean_nominal_mm);
  else if (frames_only)
    std::snprintf(buf, sizeof buf, "recommendation: deploy the robot file's model with these frames: held-out mean "
                  "%.4f mm (not judged against its nominal kinematics: the robot file does not keep them)", after.mean_mm);
  else
    std::snprintf(buf, sizeof buf, "recommendation: deploy the %s model: held-out mean %.4f mm against %.4f mm before "
                  "(%.0f %% better)", model.c_str(), after.mean_mm, before.mean_mm, gain);
  std::string out = buf;
  if (extrapolated > 0) out += "; outside the calibrated region (" + std::to_string(extrapolated) + " verification rows) "
                               "it extrapolates: measure poses there";
  if (variance_factor > 4 && model.rfind("geometric", 0) == 0 && !frames_only)
    out += "; it leaves more than noise: `cellcal diagnose` names the cause and the extended model to deploy instead";
  return out;
}

CampaignReport calibrateCampaign(const CampaignProblem& problem) {
  std::string why;
  if (!problem.IsValid(&why)) throw ConfigError("calibration campaign: " + why);
  return problem.setups.size() > 1 ? internal::calibrateSetups(problem) : calibrateOne(problem);
}

}  // namespace cellcal
