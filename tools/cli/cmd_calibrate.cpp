// `cellcal calibrate`: batch calibration of one measurement file.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/outliers.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/identification/setups.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/residual_map.hpp"
#include "commands.hpp"
#include "diagnosis_output.hpp"
#include "measurement_input.hpp"
#include "progress.hpp"

namespace cellcal::cli {
namespace {

struct CalibrateArgs {
  InputArgs input;
  std::string json, model = "geometric", solver = "gn";
  double rank_tolerance = IdentifiabilityOptions{}.rank_tolerance;
  double excitation_ratio = DiagnosisOptions{}.excitation_ratio;
  std::string save_robot;
  bool frames_only = false;
  bool keep_extensions = false;
  bool residual_map = false, no_region_check = false;
  double residual_map_distance = ResidualMapOptions{}.max_distance;
};

// --residual-map: the map of the identification rows' residuals under `fit`, judged on the verification rows: the
// held-out mean with the map where it applies against without it on the same rows, and over every row. Printed; JSON.
// `map` receives the map (saved with --save-robot).
nlohmann::json judgeResidualMap(const RobotModel& robot, const ExtendedFit& fit, const std::vector<Observation>& ident,
                                const std::vector<Drivers>& idr, const std::vector<Observation>& verify,
                                const std::vector<Drivers>& vdr, const CalibrateArgs& a, std::optional<ResidualMap>* out) {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Eigen::VectorXd> q;
  for (const auto& o : ident) q.push_back(o.q_rad);
  ResidualMapOptions o;
  o.max_distance = a.residual_map_distance;
  const ResidualMap& map = out->emplace(fitResidualMap(q, positionResiduals(robot, fit, ident, idr), o));
  const double fit_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
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
  std::string scales;
  for (Eigen::Index j = 0; j < map.lengthScales_rad().size(); ++j)
    scales += (j ? " " : "") + std::to_string(static_cast<int>(std::lround(map.lengthScales_rad()[j] * 180 / kPi)));
  std::printf("residual map: %zu identification rows, length scales %s deg (joints 1-%d), signal %.4f mm, noise %.4f mm "
              "(%.1f s)\n", map.rows(), scales.c_str(), static_cast<int>(map.lengthScales_rad().size()),
              map.signalSigma_m() * 1e3, map.noiseSigma_m() * 1e3, fit_s);
  std::printf("  verification rows within %.2g length scales of an identification row: %d of %zu; their held-out mean "
              "%.4f mm with the map, %.4f mm without (the map's 1 sigma there %.4f mm per axis)\n",
              map.maxDistance(), near, verify.size(), near_with / m, near_without / m, sigma / m);
  std::printf("  every verification row (the map where it applies): %.4f mm, without the map %.4f mm\n", all_with / n,
              all_without / n);
  return {{"rows", map.rows()}, {"fit_time_s", fit_s}, {"max_distance", map.maxDistance()},
          {"length_scales_deg", [&] {
             std::vector<double> v;
             for (Eigen::Index j = 0; j < map.lengthScales_rad().size(); ++j) v.push_back(map.lengthScales_rad()[j] * 180 / kPi);
             return v;
           }()},
          {"signal_sigma_mm", map.signalSigma_m() * 1e3}, {"noise_sigma_mm", map.noiseSigma_m() * 1e3},
          {"verification_rows_near", near}, {"near_mean_with_mm", near_with / m}, {"near_mean_without_mm", near_without / m},
          {"near_sigma_mean_mm", sigma / m}, {"all_mean_with_mm", all_with / n}, {"all_mean_without_mm", all_without / n}};
}

void addOptions(CLI::App& cmd, CalibrateArgs& a) {
  addInputOptions(&cmd, a.input);
  cmd.add_option("--json", a.json, "write the results as JSON")->check(outputFile());
  cmd.add_option("--model", a.model,
                 "geometric | auto (the cause `diagnose` names) | a list of causes with 1-based joints, e.g. "
                 "backlash:2,joint_compliance:3 (thermal_drift alone: lengths only)")
      ->capture_default_str();
  cmd.add_option("--solver", a.solver, "gn (Gauss-Newton, default) | lm (Levenberg-Marquardt, Ceres; geometric model)")
      ->check(CLI::IsMember({"gn", "lm"}))
      ->capture_default_str();
  cmd.add_option("--save-robot", a.save_robot,
                 "write the calibrated model as a robot file: identified kinematics, frames, extensions, the covariance "
                 "and where it came from (not written when the exit status is not 0)")->check(outputFile());
  cmd.add_flag("--frames-only", a.frames_only,
               "keep the robot file's kinematics and extensions (e.g. a calibrated robot file) and register only the "
               "base and tool frames on the identification rows: the tracker or the target was moved");
  cmd.add_flag("--keep-extensions", a.keep_extensions,
               "--frames-only: keep the robot file's extensions where they do not transfer to these rows (by default "
               "the same campaign's geometric calibration, saved beside them, is used instead; both are judged)");
  cmd.add_flag("--residual-map", a.residual_map,
               "learn what the calibrated model leaves at the identification rows (a Gaussian process over the joints, "
               "residual_map.hpp) and judge it on the verification rows: applied only within "
               "--residual-map-distance length scales of an identification row, never beyond");
  cmd.add_option("--residual-map-distance", a.residual_map_distance,
                 "the residual map corrects only this near an identification row (in its fitted length scales)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd.add_flag("--no-region-check", a.no_region_check,
               "--model auto: keep every cause the selection chose; by default each is fitted again on one half of the "
               "workspace and judged on the other, and one that does not lower the error there is left out");
  cmd.add_option("--excitation-ratio", a.excitation_ratio,
                 "hold (and name) a parameter whose excitation on the identification rows is below this fraction of "
                 "its largest on a verification row; 0: off")
      ->check(CLI::Range(0.0, 0.99))
      ->capture_default_str();
  cmd.add_option("--rank-tolerance", a.rank_tolerance,
                 "a parameter is estimated only if its scaled Jacobian column leaves the span of the others by more "
                 "than this sine")
      ->capture_default_str();
}

// The predicted model error on the identification and verification rows (prediction.hpp) and whether the actual
// errors agree: RMS of actual / sqrt(predicted^2 + 3 s^2 sigma_reading^2) over the verification rows.
struct Trust {
  double ident_rms_mm = 0, ident_max_mm = 0, verify_rms_mm = 0, verify_max_mm = 0, ratio_rms = 0;
  int extrapolated = 0;  // verification rows predicted more than 3x the largest identification row
  int beyond_checked = 0;  // verification rows farther beyond a joint's range than its folds judged (BeyondRange)
};

Trust trustOf(const RobotModel& robot, const ExtendedFit& fit, const PredictionModel& pm,
              const std::vector<Observation>& ident, const std::vector<Drivers>& idr,
              const std::vector<Observation>& verify, const std::vector<Drivers>& vdr) {
  Trust t;
  double sq = 0;
  for (size_t i = 0; i < ident.size(); ++i) {
    const double s = predictedPositionSigma(robot, fit, pm, ident[i].q_rad, idr[i]) * 1e3;
    sq += s * s;
    t.ident_max_mm = std::max(t.ident_max_mm, s);
  }
  t.ident_rms_mm = ident.empty() ? 0 : std::sqrt(sq / static_cast<double>(ident.size()));
  sq = 0;
  double ratio_sq = 0;
  KinematicsData data(robot);
  for (size_t i = 0; i < verify.size(); ++i) {
    const double s = predictedPositionSigma(robot, fit, pm, verify[i].q_rad, vdr[i]) * 1e3;
    sq += s * s;
    t.verify_max_mm = std::max(t.verify_max_mm, s);
    if (s > 3 * t.ident_max_mm) ++t.extrapolated;
    for (const BeyondRange& b : pm.beyond)
      if (b.sigma_at_1_rad > 0 && b.beyondRad(verify[i].q_rad[b.joint]) > b.checked_rad) {
        ++t.beyond_checked;
        break;
      }
    const Eigen::VectorXd p = extendedParams(robot, fit.params, fit.extensions, fit.extension_params, verify[i].q_rad, vdr[i]);
    const double actual_mm =
        (forwardKinematics(robot, data, p, verify[i].q_rad).translation() - verify[i].measured_in_tracker.translation()).norm() * 1e3;
    const double noise_mm = std::sqrt(3.0 * pm.variance_factor_position) * verify[i].sigma_position_m * 1e3;
    ratio_sq += actual_mm * actual_mm / (s * s + noise_mm * noise_mm);
  }
  t.verify_rms_mm = verify.empty() ? 0 : std::sqrt(sq / static_cast<double>(verify.size()));
  t.ratio_rms = verify.empty() ? 0 : std::sqrt(ratio_sq / static_cast<double>(verify.size()));
  return t;
}

ExtendedFit asFit(const Eigen::VectorXd& params) {
  ExtendedFit f;
  f.params = params;
  return f;
}

ExtendedFit asFit(const CalibrationResult& r) {
  ExtendedFit f = asFit(r.params);
  f.estimated = r.estimated;
  f.covariance = r.covariance;
  f.converged = r.converged;
  f.iterations = r.iterations;
  f.message = r.message;
  return f;
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


// A column's 1 sigma in the prediction's covariance (what --save-robot writes and predictions use; SI), NaN when the
// prediction does not cover it.
double savedSigma(const PredictionModel& pm, int column) {
  for (size_t k = 0; k < pm.columns.size(); ++k)
    if (pm.columns[k] == column) return std::sqrt(std::max(0.0, pm.covariance(static_cast<Eigen::Index>(k), static_cast<Eigen::Index>(k))));
  return std::nan("");
}

// The fit's sigma of an estimated parameter holds the parameters it did not estimate at their values; the robot file
// saves the covariance over every parameter a prediction depends on, the held ones at their prior width. Where a
// parameter moves with a held one (joint 1's d with the base's z: only their sum is pinned) the saved sigma is that
// of the two together: said beside the fit's, with the held parameter it moves with. `shown`: the fit's, human units.
std::string savedSigmaNote(const RobotModel& robot, const ExtendedFit& fit, const PredictionModel& pm, int column,
                           double shown) {
  const double saved_si = savedSigma(pm, column);
  if (std::isnan(saved_si)) return "";
  const bool kin = column < robot.numParams();
  const double saved = kin ? robot.toHuman(column, saved_si) : saved_si;
  if (!(saved > 2.0 * shown)) return "";
  // The held column it is most correlated with.
  Eigen::Index me = -1;
  for (size_t k = 0; k < pm.columns.size(); ++k)
    if (pm.columns[k] == column) me = static_cast<Eigen::Index>(k);
  std::string partner;
  double best = 0;
  for (size_t k = 0; k < pm.columns.size(); ++k) {
    const int c = pm.columns[k];
    const bool estimated = c < robot.numParams()
                               ? std::count(fit.estimated.begin(), fit.estimated.end(), c) > 0
                               : std::count(fit.estimated_extension.begin(), fit.estimated_extension.end(),
                                            c - robot.numParams()) > 0;
    if (estimated) continue;
    const auto kk = static_cast<Eigen::Index>(k);
    const double r = std::abs(pm.covariance(me, kk)) / std::sqrt(pm.covariance(me, me) * pm.covariance(kk, kk));
    if (r > best) {
      best = r;
      partner = c < robot.numParams() ? robot.paramNameHuman(c) : fit.extension_names[static_cast<size_t>(c - robot.numParams())];
    }
  }
  char buf[240];
  std::snprintf(buf, sizeof buf, kin ? " (%.4f in the robot file: %s%s)" : " (%.3g in the robot file: %s%s)", saved,
                partner.empty() ? "with the parameters it does not estimate at their prior width"
                                : "it moves with ",
                partner.empty() ? "" : (partner + ", which the data leave at its prior width").c_str());
  return buf;
}

// The error table: a header, then one row per (name, stats).
void printErrorTable(const std::vector<std::pair<const char*, const ErrorStats*>>& rows) {
  std::printf("                 position mm: mean     rms     max   orientation deg: mean    rms     max\n");
  for (const auto& [name, e] : rows)
    std::printf("  %-24s %8.4f %7.4f %7.4f %17.4f %7.4f %7.4f\n", name, e->mean_mm, e->rms_mm, e->max_mm, e->mean_deg,
                e->rms_deg, e->max_deg);
}

// The error table of a calibration: before and after on both row sets, and the verification rows without their
// gross errors when there are any; then the gross errors of both by file line.
void printErrorsAndGrossErrors(const ErrorStats& ib, const ErrorStats& ia, const ErrorStats& vb, const ErrorStats& va,
                               const ErrorStats& vbk, const ErrorStats& vak, const OutlierScreen& ident_out,
                               const OutlierScreen& verify_out, double threshold, const LoadedInput& in,
                               const char* between = nullptr) {
  std::vector<std::pair<const char*, const ErrorStats*>> table = {
      {"identification before", &ib}, {"identification after", &ia}, {"verification before", &vb}, {"verification after", &va}};
  if (!verify_out.rows.empty()) {
    table.push_back({"  without gross errors", &vbk});
    table.push_back({"  without gross errors", &vak});
  }
  printErrorTable(table);
  if (between) std::printf("%s", between);
  if (ident_out.rows.empty() && verify_out.rows.empty()) return;
  std::printf("gross errors (more than %.0f robust sigmas of %.4f mm per axis):\n", threshold,
              ident_out.sigma_position_m * 1e3);
  if (!ident_out.rows.empty())
    std::printf("  identification: %zu rows left out of the fit: %s\n", ident_out.rows.size(),
                linesText(ident_out.rows, in.identification_lines).c_str());
  if (!verify_out.rows.empty())
    std::printf("  verification:   %zu rows: %s\n", verify_out.rows.size(),
                linesText(verify_out.rows, in.verification_lines).c_str());
}

// The last line of a calibration: deploy this model or not, and why (before/after: the held-out rows without their
// gross errors).
std::string recommendation(bool converged, const std::string& unusable, const ErrorStats& before,
                           const ErrorStats& after, const std::string& model, bool frames_only, double variance_factor,
                           int extrapolated) {
  char buf[640];
  if (!converged) return "recommendation: do not deploy: the solver did not converge (exit 3)";
  if (!unusable.empty()) return "recommendation: do not deploy: " + unusable + " (exit 4)";
  const double gain = before.mean_mm > 0 ? 100.0 * (1.0 - after.mean_mm / before.mean_mm) : 0.0;
  if (frames_only)
    std::snprintf(buf, sizeof buf, "recommendation: deploy the robot file's model with these frames: held-out mean "
                  "%.4f mm", after.mean_mm);
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

// Exit 3 (not converged) or 4 (not usable) with what was not written; 0 to go on.
int failedExit(bool converged, const std::string& unusable, const std::string& save_robot) {
  if (!converged) {
    if (!save_robot.empty()) std::printf("%s not written: the solver did not converge\n", save_robot.c_str());
    return 3;
  }
  if (!unusable.empty()) {
    std::printf("not usable: %s (exit 4)\n", unusable.c_str());
    if (!save_robot.empty()) std::printf("%s not written\n", save_robot.c_str());
    return 4;
  }
  return 0;
}

// --model auto: `diagnose` on a file's rows with calibrate's identifiability, gross-error and excitation settings; a
// progress bar (tens of fits on a large file; drawn only on a terminal) named `what`.
DiagnosisResult diagnoseForAuto(const CalibrateArgs& a, const LoadedInput& in, const OutlierOptions& outliers,
                                const std::string& what) {
  DiagnosisOptions o;
  o.identifiability.rank_tolerance = a.rank_tolerance;
  o.identifiability.prior_sigma = plausibleRanges(a.input, in.robot);
  o.outliers = outliers;
  o.excitation_ratio = a.excitation_ratio;
  o.region_check = !a.no_region_check;
  ProgressBar bar(what);
  o.progress = [&bar](int done, int total) {
    bar.update(static_cast<double>(done) / total, std::to_string(done) + "/" + std::to_string(total) + " fits");
  };
  DiagnosisResult d = diagnose(in.robot, in.start, in.data, o);
  bar.done();
  return d;
}

// --model auto with several set-ups: `diagnose` on each set-up's rows (as for one file); the causes it chooses must be
// the same in every set-up (the model is the robot's), else the user names the model (ConfigError, exit 2, with each
// set-up's choice).
std::vector<Extension> causesNamedInEverySetUp(const CalibrateArgs& a, const std::vector<LoadedInput>& ins) {
  std::vector<std::string> labels;
  std::vector<Extension> first;
  std::string first_label;
  bool same = true;
  for (size_t s = 0; s < ins.size(); ++s) {
    const DiagnosisResult d = diagnoseForAuto(a, ins[s], outlierOptions(a.input),
                                              "calibrate --model auto, set-up " + std::to_string(s + 1));
    std::vector<Extension> chosen = d.best().fit.extensions;
    for (auto& e : chosen) e.time_constant_h = 0;  // searched per fit; the joint fit takes the cause itself
    std::sort(chosen.begin(), chosen.end(),
              [](const Extension& x, const Extension& y) { return extensionSpec(x) < extensionSpec(y); });
    const std::string label = chosen.empty() ? "geometric" : modelLabel(chosen);
    labels.push_back("set-up " + std::to_string(s + 1) + ": " + label);
    if (s == 0) {
      first = chosen;
      first_label = label;
    }
    same = same && label == first_label;
  }
  std::string all;
  for (const auto& l : labels) all += (all.empty() ? "" : "; ") + l;
  if (!same)
    throw ConfigError("--model auto: the set-ups name different models (" + all +
                      "); name the one to fit with --model (a usage error, exit 2)");
  std::printf("--model auto: every set-up names %s (diagnose on each set-up's rows)\n",
              first.empty() ? "no cause: geometric" : first_label.c_str());
  return first;
}

// Several set-ups (--data given again, or a file whose setup column names several): one kinematic model and one set
// of model-extension parameters (--model: the robot's), a base and a tool frame per set-up (setups.hpp), errors per
// set-up. Every set-up registered and split on its own.
int runCalibrateSetups(const CalibrateArgs& a, std::vector<LoadedInput> ins) {
  if (a.frames_only) throw ConfigError("--frames-only takes one set-up (a usage error, exit 2)");
  std::vector<std::string> files;
  for (const auto& in : ins) files.push_back(in.name);
  const RobotModel& robot = ins[0].robot;
  SetupsProblem pr;
  pr.model = &robot;
  pr.identifiability.rank_tolerance = a.rank_tolerance;
  pr.identifiability.prior_sigma = plausibleRanges(a.input, robot);
  if (a.model == "auto")
    pr.extensions = causesNamedInEverySetUp(a, ins);
  else if (a.model != "geometric")
    pr.extensions = parseModel(a.model, robot);
  for (const auto& in : ins) {
    pr.starts.push_back(in.start);
    pr.observations.push_back(in.data.identification);
    pr.drivers.push_back(in.data.identification_drivers);
  }
  std::string why;
  if (!pr.IsValid(&why)) throw ConfigError("several set-ups: " + why + " (a usage error, exit 2)");
  const auto t1 = std::chrono::steady_clock::now();
  const OutlierOptions outliers = outlierOptions(a.input);
  std::vector<OutlierScreen> ident_screens;
  const SetupsFit fit = fitSetupsRobust(pr, {}, outliers, &ident_screens);
  const std::vector<std::string> ext_names = extensionParamNames(robot, pr.extensions);
  const double solve_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  const int f0 = robot.baseParam(FrameParam::kX), np = robot.numParams();
  std::printf("%zu set-ups, one kinematic model (%s), a base and a tool frame per set-up: %zu kinematic, %zu frame "
              "and %zu extension parameters estimated, %s after %d iterations (%.1f ms)\n",
              files.size(), modelLabel(pr.extensions).c_str(), fit.estimated_kinematic.size(),
              fit.estimated.size() - fit.estimated_kinematic.size() - fit.estimated_extension.size(),
              fit.estimated_extension.size(), fit.converged ? "converged" : "NOT converged", fit.iterations,
              solve_s * 1e3);
  if (!pr.extensions.empty()) {
    std::printf("extension parameters (every set-up's):");
    for (int k : fit.estimated_extension) std::printf(" %s=%.6g", ext_names[k].c_str(), fit.extension_params[k]);
    for (size_t k = 0; k < ext_names.size(); ++k)
      if (!std::count(fit.estimated_extension.begin(), fit.estimated_extension.end(), static_cast<int>(k)))
        std::printf(" %s held at 0 (not separable from the geometric parameters on these rows)", ext_names[k].c_str());
    std::printf("\n");
  }
  {  // What the rows leave open: kinematic parameters (held for all set-ups) and frame parameters (per set-up).
    std::string held;
    const auto& cand = robot.canonicalParams();
    for (int c : cand) {
      if (std::count(fit.estimated.begin(), fit.estimated.end(), c)) continue;
      held += " " + (c < f0 ? robot.paramNameHuman(c) : "set-up1." + robot.paramNameHuman(c));
    }
    for (size_t s = 1; s < ins.size(); ++s)
      for (int k = 0; k < 12; ++k) {
        const int col = np + 12 * static_cast<int>(s - 1) + k;
        if (std::count(cand.begin(), cand.end(), f0 + k) && !std::count(fit.estimated.begin(), fit.estimated.end(), col))
          held += " set-up" + std::to_string(s + 1) + "." + robot.paramNameHuman(f0 + k);
      }
    if (!held.empty()) std::printf("not identifiable from these data (held at their start value):%s\n", held.c_str());
  }
  nlohmann::json per = nlohmann::json::array();
  std::string unusable;
  for (size_t s = 0; s < ins.size(); ++s) {
    const LoadedInput& in = ins[s];
    const auto& d = in.data;
    const ExtendedFit before = asFit(in.start), after = setupFit(pr, fit, s);
    const ErrorStats ib = errorStats(robot, before, d.identification, d.identification_drivers),
                     ia = errorStats(robot, after, d.identification, d.identification_drivers),
                     vb = errorStats(robot, before, d.verification, d.verification_drivers),
                     va = errorStats(robot, after, d.verification, d.verification_drivers);
    // Gross errors as for one set-up: the identification rows the fit left out, the verification rows judged against
    // the calibrated model, each set-up against its own robust scale; the figures without them.
    const OutlierScreen& ident_out = ident_screens[s];
    const OutlierScreen verify_out = screenRows(robot, after, d.verification, d.verification_drivers, outliers);
    const std::vector<int> vk = keptRows(static_cast<int>(d.verification.size()), verify_out.rows),
                           ik = keptRows(static_cast<int>(d.identification.size()), ident_out.rows);
    const ErrorStats vbk = errorStats(robot, before, subset(d.verification, vk), subset(d.verification_drivers, vk)),
                     vak = errorStats(robot, after, subset(d.verification, vk), subset(d.verification_drivers, vk)),
                     iak = errorStats(robot, after, subset(d.identification, ik), subset(d.identification_drivers, ik));
    std::printf("\nset-up %zu: %s: %zu rows (%s split: %zu identify, %zu verify), %s; registration rms %.3f mm\n",
                s + 1, files[s].c_str(), in.file.rows.size(), a.input.split.c_str(), d.identification.size(),
                d.verification.size(), in.measurementText().c_str(), in.registration_rms_mm);
    if (!in.setup_hint.empty()) std::printf("WARNING: %s\n", in.setup_hint.c_str());
    if (in.model_error_added) std::printf("%s\n", in.modelErrorText().c_str());
    if (after.rows_left_out > 0)
      std::printf("%d identification row(s) before the backlash joint first moved in this set-up left out of the fit "
                  "(which side of the gap it rested on is unknown); they are predicted at the middle of the gap\n",
                  after.rows_left_out);
    printErrorsAndGrossErrors(ib, ia, vb, va, vbk, vak, ident_out, verify_out, outliers.threshold, in);
    const std::string why = unusableFit(vbk, vak, iak);
    if (!why.empty()) unusable += (unusable.empty() ? "" : "; ") + ("set-up " + std::to_string(s + 1) + ": " + why);
    nlohmann::json frames = nlohmann::json::object();
    for (int k = 0; k < 12; ++k) frames[robot.paramNameHuman(f0 + k)] = robot.toHuman(f0 + k, fit.params[s][f0 + k]);
    per.push_back({{"data", files[s]}, {"rows", in.file.rows.size()}, {"measurement", in.measurementJson()},
                   {"registration_rms_mm", in.registration_rms_mm}, {"model_error_sigma", in.modelErrorJson()},
                   {"rows_left_out_backlash", after.rows_left_out},
                   {"identification", {{"before", errorStatsJson(ib)}, {"after", errorStatsJson(ia)}}},
                   {"verification", {{"before", errorStatsJson(vb)}, {"after", errorStatsJson(va)}}},
                   {"verification_without_outliers", {{"before", errorStatsJson(vbk)}, {"after", errorStatsJson(vak)}}},
                   {"outliers", {{"identification", outliersJson(ident_out, in.identification_lines)},
                                 {"verification", outliersJson(verify_out, in.verification_lines)},
                                 {"threshold_robust_sigmas", outliers.threshold}}},
                   {"frames", frames}});
  }
  std::printf("\n('before': the robot file's kinematics with each set-up's registered frames; 'after': the common "
              "kinematics%s with each set-up's fitted frames)\n",
              pr.extensions.empty() ? "" : " and extension parameters");
  if (!a.json.empty()) {
    nlohmann::json params = nlohmann::json::array();
    for (int i = 0; i < f0; ++i) {
      const bool est = std::count(fit.estimated_kinematic.begin(), fit.estimated_kinematic.end(), i) > 0;
      params.push_back({{"name", robot.paramNameHuman(i)}, {"initial", robot.toHuman(i, ins[0].start[i])},
                        {"value", robot.toHuman(i, fit.params[0][i])}, {"estimated", est}});
    }
    nlohmann::json ext = nlohmann::json::object();
    for (int k : fit.estimated_extension) ext[ext_names[k]] = fit.extension_params[k];
    std::ofstream(a.json) << nlohmann::json{{"robot", robot.name}, {"setups", per}, {"parameters", params},
                                            {"model", a.model}, {"model_fitted", modelLabel(pr.extensions)},
                                            {"extension_params", ext},
                                            {"converged", fit.converged}, {"iterations", fit.iterations},
                                            {"unusable", unusable.empty() ? nlohmann::json(nullptr) : nlohmann::json(unusable)}}
                                 .dump(2)
                          << "\n";
  }
  if (const int code = failedExit(fit.converged, unusable, a.save_robot)) return code;
  if (!a.save_robot.empty()) {
    // The kinematics with the frames of the set-up given last (the newest placement). Its covariance is that of a
    // fit on that set-up's rows alone (the other set-ups pin the kinematics further: conservative).
    const size_t last = ins.size() - 1;
    ExtendedFit f = setupFit(pr, fit, last);
    f.estimated = fit.estimated_kinematic;
    f.estimated_extension = fit.estimated_extension;
    for (int c : fit.estimated) {
      const int k = c < np ? c - f0 : (c - np) % 12;
      const size_t owner = c < f0 ? SIZE_MAX : c < np ? 0 : static_cast<size_t>((c - np) / 12 + 1);
      if (owner == last) f.estimated.push_back(f0 + k);
    }
    std::sort(f.estimated.begin(), f.estimated.end());
    const auto& d = ins[last].data;
    const std::vector<int> kept = keptRows(static_cast<int>(d.identification.size()), ident_screens[last].rows);
    RobotCalibration cal = robotCalibration(
        robot, f, predictionModel(robot, f, subset(d.identification, kept), subset(d.identification_drivers, kept)));
    std::string all;
    for (const auto& file : files) all += (all.empty() ? "" : ", ") + file;
    cal.provenance = {{"date_utc", utcNow()},          {"tool", "cellcal calibrate (several set-ups)"},
                      {"robot_file", a.input.robot},   {"data_files", all},
                      {"data_sha256", fileSha256(files[last].substr(0, files[last].find(" [setup ")))}, {"frames_of", files[last]},
                      {"split", a.input.split},        {"model", modelLabel(pr.extensions)}};
    saveRobotFile(a.save_robot, robot.withParams(fit.params[last]), &cal,
                  "Calibrated " + robot.name + ": written by `cellcal calibrate` from " + std::to_string(files.size()) +
                      " set-ups (" + all + "); base and tool frames of " + files[last], &ins.front().source);
    std::printf("calibrated robot file: %s (frames of set-up %zu)\n", a.save_robot.c_str(), last + 1);
  }
  return 0;
}

int runCalibrate(const CalibrateArgs& a) {
  std::vector<LoadedInput> setups = loadSetups(a.input);  // --data given again, or a file with a setup column
  if (setups.size() > 1) return runCalibrateSetups(a, std::move(setups));
  const LoadedInput in = std::move(setups.front());
  const RobotModel& robot = in.robot;
  const auto& ident = in.data.identification;
  const auto& verify = in.data.verification;
  const Eigen::VectorXd& start = in.start;
  using Clock = std::chrono::steady_clock;
  const auto t1 = Clock::now();
  const auto& idr = in.data.identification_drivers;
  const auto& vdr = in.data.verification_drivers;
  CalibrationProblem p{&robot, start, ident, std::nullopt, {}, {}};
  p.outliers = outlierOptions(a.input);
  CalibrationResult r;
  ExtendedFit after;
  std::vector<ExcitationDeficit> held_after;
  OutlierScreen ident_outliers;
  std::string model_label, message;
  std::string region_text;                       // --model auto: the region check (diagnosis_output.hpp)
  nlohmann::json region_json = nullptr;
  nlohmann::json drift_json = nullptr;            // --model auto: the drift check
  std::optional<CarriedComparison> carried_check;  // --frames-only: the file's extensions against its geometric fit
  bool converged = false;
  int iterations = 0;
  size_t estimated = 0;
  if (a.frames_only) {
    // The robot file's kinematics and model extensions as they are; only where the robot stands in the tracker
    // frame and where the target sits on the flange are registered on these rows.
    if (a.model != "geometric") throw std::runtime_error("--frames-only keeps the robot file's model: no --model");
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
    after.converged = converged = true;
    iterations = rr.iterations;
    estimated = 12;
    model_label = "the robot file's (" + modelLabel(after.extensions) + "), frames only";
    // Its extensions against the same campaign's geometric calibration, both carried to these rows: the better one.
    if (in.calibration && in.calibration->geometric_params.size() == robot.numParams() && !after.extensions.empty()) {
      carried_check = compareCarried(robot, after, in.calibration->geometric_params, ident, idr, verify, vdr);
      if (!carried_check->extensions_transfer && !a.keep_extensions) {
        after = carried_check->geometric;
        model_label = "the campaign's geometric calibration (the robot file's extensions do not transfer), frames only";
      }
    }
    ident_outliers = screenRows(robot, after, ident, idr, p.outliers);
  } else {
    const std::vector<Extension> named =
        a.model == "geometric" || a.model == "auto" ? std::vector<Extension>{} : parseModel(a.model, robot);
    // Parameters the identification rows leave unexcited where a verification row excites them: held, and said.
    const std::vector<ExcitationDeficit> held =
        a.excitation_ratio > 0 ? excitationDeficits(robot, start, named, ident, idr, verify, vdr, a.excitation_ratio)
                               : std::vector<ExcitationDeficit>{};
    p.identifiability.rank_tolerance = a.rank_tolerance;
    p.identifiability.prior_sigma = plausibleRanges(a.input, robot);
    for (const auto& h : held)
      if (h.column < robot.numParams()) p.identifiability.held.push_back(h.column);
    std::string why;
    if (!p.IsValid(&why)) throw std::runtime_error(why);
    r = a.solver == "lm" ? solveLevenbergMarquardt(p) : solveGaussNewton(p);
    after = asFit(r);
    held_after = held;
    ident_outliers = r.outliers;
    model_label = "geometric";
    converged = r.converged;
    iterations = r.iterations;
    estimated = r.estimated.size();
    message = r.message;
    if (a.model != "geometric") {
      if (a.model == "auto") {
        const DiagnosisResult d = diagnoseForAuto(a, in, p.outliers, "calibrate --model auto");
        region_text = regionCheckText(d);
        if (const std::string t = driftCheckText(d); !t.empty()) region_text += (region_text.empty() ? "" : "\n") + t;
        region_json = regionCheckJson(d);
        drift_json = driftCheckJson(d);
        after = d.best().fit;
        held_after = d.best().held;
        ident_outliers = d.identification_outliers;
      } else {
        IdentifiabilityOptions io = p.identifiability;
        io.noise_scale = r.identifiability.noise_scale;  // the geometric fit's: what the model leaves counts as noise
        io.held = heldColumns(held);
        after = fitExtendedRobust(robot, start, ident, idr, named, {}, io, &r.params, p.outliers, &ident_outliers);
      }
      model_label = after.extensions.empty() ? "geometric (auto: no cause found)" : modelLabel(after.extensions);
      // The extended model stands on the geometric fit (its start, its rows' screen): both must have converged.
      if (!r.converged) message = "the geometric fit beneath did not converge: " + r.message;
      converged = r.converged && after.converged;
      iterations = after.iterations;
      estimated = after.estimated.size() + after.estimated_extension.size();
      if (r.converged) message = after.message;
    }
  }
  const auto t2 = Clock::now();
  const double reg_s = in.registration_s, solve_s = std::chrono::duration<double>(t2 - t1).count();
  const ExtendedFit before = asFit(start);
  const ErrorStats ib = errorStats(robot, before, ident, idr), ia = errorStats(robot, after, ident, idr);
  const ErrorStats vb = errorStats(robot, before, verify, vdr), va = errorStats(robot, after, verify, vdr);
  // Gross errors among the verification rows, judged against the calibrated model, and the figures without them.
  const OutlierScreen verify_outliers = screenRows(robot, after, verify, vdr, p.outliers);
  const std::vector<int> vk = keptRows(static_cast<int>(verify.size()), verify_outliers.rows);
  const std::vector<Observation> verify_kept = subset(verify, vk);
  const std::vector<Drivers> vdr_kept = subset(vdr, vk);
  const ErrorStats vbk = errorStats(robot, before, verify_kept, vdr_kept), vak = errorStats(robot, after, verify_kept, vdr_kept);
  const std::vector<int> ik = keptRows(static_cast<int>(ident.size()), ident_outliers.rows);
  const std::vector<Observation> ident_kept = subset(ident, ik);
  const std::vector<Drivers> idr_kept = subset(idr, ik);
  const ErrorStats iak = errorStats(robot, after, ident_kept, idr_kept);
  // The frames' own uncertainty with --frames-only: their covariance on these rows, the kinematics as the file has
  // them, scaled by what the frames leave (the kinematics' error on this set-up is in that residual).
  double frames_variance_factor = 1;
  if (a.frames_only) {  // a frame parameter these rows do not determine (a tool rotation from points) is not estimated
    after.estimated = conditionalCovariance(robot, after, ident_kept, idr_kept, after.estimated, &after.covariance,
                                            &frames_variance_factor);
    estimated = after.estimated.size();
  }
  // What the extensions are worth beyond their data (prediction.hpp): measured on region folds of the identification
  // rows, saved in the robot file, carried by --frames-only.
  std::optional<ExtensionTransfer> transfer;
  if (!a.frames_only && !after.extensions.empty() && after.converged) {
    DiagnosisOptions o;
    o.identifiability = p.identifiability;
    o.identifiability.noise_scale = r.identifiability.noise_scale;
    o.excitation_ratio = a.excitation_ratio;
    transfer = extensionTransfer(robot, start, after, ident_kept, idr_kept, o);
  }
  // Carried with --frames-only where the robot file's extensions are kept.
  const std::vector<BeyondRange> beyond = transfer ? transfer->beyond()
                                          : a.frames_only && in.calibration && !after.extensions.empty()
                                              ? in.calibration->beyond_data
                                              : std::vector<BeyondRange>{};
  // How far the model can be trusted: its predicted position error on every kept row, against the actual one. With
  // --frames-only, the robot file's covariance carried to these rows less what the new frames take up of it
  // (carriedPrediction); a robot file without a calibration section carries the priors of a model no one calibrated.
  const PredictionModel pm = [&] {
    if (!a.frames_only) {
      PredictionModel own = predictionModel(robot, after, ident_kept, idr_kept);
      own.beyond = beyond;
      return own;
    }
    PredictionModel carried;
    if (in.calibration) {
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
    carried.beyond = beyond;  // what the extensions may do beyond the campaign's joint ranges (its region folds)
    return carriedPrediction(robot, after, carried, ident_kept, idr_kept, after.estimated,
                             residualVarianceFactors(robot, after, ident_kept, idr_kept,
                                                     static_cast<int>(after.estimated.size())));
  }();
  const Trust trust = trustOf(robot, after, pm, ident_kept, idr_kept, verify_kept, vdr_kept);
  // With --frames-only the start is the same model with its frames registered in closed form: no baseline to beat,
  // only the extrapolation rule applies.
  const std::string unusable = unusableFit(a.frames_only ? vak : vbk, vak, iak);
  const std::vector<std::string> implausible = implausibleParameters(robot, start, after);
  std::printf("%s: %zu rows (%s split: %zu identify, %zu verify), %s, robot %s\n", a.input.data.c_str(),
              in.file.rows.size(), a.input.split.c_str(), ident.size(), verify.size(),
              in.measurementText().c_str(), robot.name.c_str());
  if (!a.input.no_register)
    std::printf("registration of base and tool frames: rms %.3f mm (%.1f ms)\n", in.registration_rms_mm, reg_s * 1e3);
  if (!in.setup_hint.empty()) std::printf("WARNING: %s\n", in.setup_hint.c_str());
  if (in.model_error_added) std::printf("%s\n", in.modelErrorText().c_str());
  std::printf("calibration, model %s (%s): %s after %d iterations, %zu parameters estimated (%.1f ms)\n",
              model_label.c_str(), a.model == "geometric" && a.solver == "lm" ? "Levenberg-Marquardt" : "Gauss-Newton",
              converged ? "converged" : "NOT converged", iterations, estimated, solve_s * 1e3);
  if (!converged) std::printf("  solver: %s\n", message.c_str());
  std::printf("%s\n", region_text.c_str());
  if (transfer) {
    std::string t = transfer->text;
    for (size_t at = t.find('\n'); at != std::string::npos; at = t.find('\n', at + 3)) t.replace(at, 1, "\n  ");
    std::printf("beyond its data (region folds):\n  %s\n", t.c_str());
  }
  if (a.frames_only)
    for (const auto& b : beyond)
      std::printf("carried beyond the campaign's data: joint %d outside [%.1f, %.1f] deg, a further joint error of %.3g deg%s "
                  "(the robot file's beyond_data)\n",
                  b.joint + 1, b.lower_rad * 180 / kPi, b.upper_rad * 180 / kPi, b.sigma_at_1_rad * 180 / kPi,
                  b.growthText());
  if (carried_check)
    std::printf("%s%s\n", carried_check->text.c_str(),
                carried_check->extensions_transfer ? ""
                : a.keep_extensions                 ? ": kept (--keep-extensions)"
                                                    : ": the geometric calibration is used (--keep-extensions keeps them)");
  printErrorsAndGrossErrors(
      ib, ia, vb, va, vbk, vak, ident_outliers, verify_outliers, p.outliers.threshold, in,
      a.frames_only ? "\n('before': the robot file's kinematics, no extensions, frames registered in closed form; 'after': "
                      "its kinematics and extensions with the frames fitted)\n"
                    : "\n('before': the robot file's kinematics with the registered frames; 'after': every identifiable "
                      "parameter)\n");
  // The estimated parameters: value, change from the start (the robot file's, frames registered) and 1 sigma.
  // The readings' sigmas weight the fit; the residual says how far they hold: the sigmas are scaled by the square root
  // of the a-posteriori variance factor (1 when the readings' sigmas and the model are right).
  const double vf = std::sqrt(std::max(1.0, a.frames_only ? frames_variance_factor : pm.variance_factor));
  std::printf("\nestimated parameters: value, change from the start, 1 sigma (the fit's, x %.2f: the root of the "
              "variance factor)\n", vf);
  for (int i : after.estimated) {
    const double sd = after.paramStddev(i), shown = std::isnan(sd) ? 0.0 : vf * robot.toHuman(i, sd);
    std::printf("  %-24s %12.4f %+10.4f  sigma %.4f%s\n", robot.paramNameHuman(i).c_str(), robot.toHuman(i, after.params[i]),
                robot.toHuman(i, after.params[i] - start[i]), shown,
                a.frames_only ? "" : savedSigmaNote(robot, after, pm, i, shown).c_str());
  }
  for (int k : after.estimated_extension) {
    const double shown = vf * after.extensionStddev(k);
    std::printf("  %-24s %12.6g %+10.3g  sigma %.3g%s\n", after.extension_names[k].c_str(), after.extension_params[k],
                after.extension_params[k], shown,
                a.frames_only ? "" : savedSigmaNote(robot, after, pm, robot.numParams() + k, shown).c_str());
  }
  for (const auto& h : held_after) std::printf("held: %s\n", deficitText(h).c_str());
  // Two different figures: how uncertain the fitted parameters are (small with many rows), and what the model leaves
  // (the residual it cannot explain, which no amount of data shrinks).
  std::printf("uncertainty of the calibrated model (1 sigma, position%s): %.4f mm RMS on the verification rows (max "
              "%.4f; identification rows %.4f, max %.4f): how far the fitted parameters may lie from the best this "
              "model can do on these data\n",
              a.frames_only ? (in.calibration ? "; the robot file's covariance less what the new frames take up"
                                              : "; the priors of an uncalibrated model less what the new frames take up")
                            : "",
              trust.verify_rms_mm, trust.verify_max_mm, trust.ident_rms_mm, trust.ident_max_mm);
  std::printf("what the model leaves: %.4f mm RMS on the verification rows, the readings' position sigmas x %.1f "
              "(position variance factor %.2f)%s\n",
              va.rms_mm, std::sqrt(pm.variance_factor_position), pm.variance_factor_position,
              pm.variance_factor_position > 4 ? ": effects the model does not hold, or readings noisier than their "
                                                "sigmas (`cellcal diagnose` looks for the cause)"
                                              : ": about the readings' noise");
  std::printf("check: the verification errors against that uncertainty and the residual together: RMS ratio %.2f (1: "
              "the predicted errors can be trusted)\n", trust.ratio_rms);
  if (trust.beyond_checked > 0)
    std::printf("  %d verification rows lie farther beyond a joint's calibrated range than the region folds judged: the "
                "error beyond it is held at its value there, itself an extrapolation\n", trust.beyond_checked);
  if (trust.extrapolated > 0)
    std::printf("  %d verification rows lie outside the calibrated region (predicted error more than 3x the largest on "
                "the identification rows)\n", trust.extrapolated);
  for (const auto& w : implausible)
    std::printf("implausible: %s: a target offset or frame the robot file does not have (a gauge with its own frame?), "
                "or too little excitation\n", w.c_str());
  // What the model leaves, learnt at the identification rows and applied to the verification rows near them.
  nlohmann::json residual_map_json = nullptr;
  std::optional<ResidualMap> residual_map;
  if (a.residual_map)
    residual_map_json = judgeResidualMap(robot, after, ident_kept, idr_kept, verify_kept, vdr_kept, a, &residual_map);
  // Held: what the rows do not separate (rank), and what they pin no better than its plausible range.
  std::string rank_held, prior_held;
  for (const auto& d : r.identifiability.dropped) {
    if (!d.below_prior) {
      rank_held += " " + robot.paramNameHuman(d.index);
      continue;
    }
    char buf[200];
    if (d.prior_sigma_si > 0 && d.data_sigma_si >= d.prior_sigma_si)
      std::snprintf(buf, sizeof buf, " %s (+-%.3g, plausible +-%.3g)", robot.paramNameHuman(d.index).c_str(),
                    std::abs(robot.toHuman(d.index, d.data_sigma_si)), std::abs(robot.toHuman(d.index, d.prior_sigma_si)));
    else  // pinned itself, but fitted with the kept ones it would loosen one of them beyond its range
      std::snprintf(buf, sizeof buf, " %s (would loosen a kept parameter beyond its range)", robot.paramNameHuman(d.index).c_str());
    prior_held += buf;
  }
  if (!rank_held.empty()) std::printf("not identifiable from these data (held at their start value):%s\n", rank_held.c_str());
  if (!prior_held.empty())
    std::printf("held at their start value: the data (at %.2fx the readings' sigmas, what the fit leaves) pin them "
                "no better than their plausible deviation (--plausible-length-mm, --plausible-angle-deg):%s\n",
                r.identifiability.noise_scale, prior_held.c_str());
  if (!a.json.empty()) {
    // Every model alike: names and values in mm and deg (the unit in the name), stddev from the fit's covariance
    // (reading sigmas), null where the parameter was not estimated.
    nlohmann::json params = nlohmann::json::array();
    for (int i = 0; i < robot.numParams(); ++i) {
      const double sd = after.paramStddev(i), saved = savedSigma(pm, i);
      params.push_back({{"name", robot.paramNameHuman(i)}, {"initial", robot.toHuman(i, start[i])},
                        {"value", robot.toHuman(i, after.params[i])},
                        {"stddev", std::isnan(sd) ? nlohmann::json(nullptr) : nlohmann::json(robot.toHuman(i, sd))},
                        {"stddev_saved", std::isnan(saved) ? nlohmann::json(nullptr) : nlohmann::json(robot.toHuman(i, saved))},
                        {"estimated", !std::isnan(sd)}});
    }
    nlohmann::json ext = nlohmann::json::object(), ext_sd = nlohmann::json::object();
    for (int k : after.estimated_extension) {
      ext[after.extension_names[k]] = after.extension_params[k];
      ext_sd[after.extension_names[k]] = after.extensionStddev(k);
    }
    nlohmann::json j = {{"data", a.input.data}, {"robot", robot.name}, {"rows", in.file.rows.size()},
                        {"skipped_rows", in.file.skipped_rows}, {"split", a.input.split},
                        {"identification_rows", ident.size()}, {"verification_rows", verify.size()},
                        {"measurement", in.measurementJson()},
                        {"model", a.model}, {"model_fitted", model_label}, {"region_check", region_json}, {"drift_check", drift_json}, {"solver", a.solver},
                        {"converged", converged}, {"iterations", iterations},
                        {"registration_rms_mm", in.registration_rms_mm}, {"model_error_sigma", in.modelErrorJson()},
                        {"setup_change", in.setup_hint.empty() ? nlohmann::json(nullptr)
                                                               : nlohmann::json{{"line", in.setup_change_line}, {"text", in.setup_hint}}}, {"registration_time_s", reg_s},
                        {"solve_time_s", solve_s},
                        {"identification", {{"before", errorStatsJson(ib)}, {"after", errorStatsJson(ia)}}},
                        {"verification", {{"before", errorStatsJson(vb)}, {"after", errorStatsJson(va)}}},
                        {"verification_without_outliers", {{"before", errorStatsJson(vbk)}, {"after", errorStatsJson(vak)}}},
                        {"outliers", {{"identification", outliersJson(ident_outliers, in.identification_lines)},
                                      {"verification", outliersJson(verify_outliers, in.verification_lines)},
                                      {"threshold_robust_sigmas", p.outliers.threshold}}},
                        {"parameters", params}, {"extension_params", ext}, {"extension_stddev", ext_sd},
                        {"held", heldJson(held_after)},
                        {"identifiability", [&] {
                           nlohmann::json rank = nlohmann::json::array(), plausible = nlohmann::json::array();
                           for (const auto& d : r.identifiability.dropped) {
                             if (!d.below_prior) {
                               rank.push_back(robot.paramNameHuman(d.index));
                               continue;
                             }
                             plausible.push_back({{"name", robot.paramNameHuman(d.index)},
                                                  {"data_sigma", std::isfinite(d.data_sigma_si)
                                                                     ? nlohmann::json(std::abs(robot.toHuman(d.index, d.data_sigma_si)))
                                                                     : nlohmann::json(nullptr)},
                                                  {"plausible_sigma", std::abs(robot.toHuman(d.index, d.prior_sigma_si))}});
                           }
                           return nlohmann::json{{"noise_scale", r.identifiability.noise_scale},
                                                 {"not_identifiable", rank}, {"held_within_plausible", plausible}};
                         }()},
                        {"prediction", nlohmann::json{
                                        {"identification_rms_mm", trust.ident_rms_mm},
                                        {"identification_max_mm", trust.ident_max_mm},
                                        {"verification_rms_mm", trust.verify_rms_mm},
                                        {"verification_max_mm", trust.verify_max_mm},
                                        {"variance_factor_position", pm.variance_factor_position},
                                        {"variance_factor_orientation", pm.variance_factor_orientation},
                                        {"actual_over_predicted_rms", trust.ratio_rms},
                                        {"verification_rows_outside_calibrated_region", trust.extrapolated},
                                        {"verification_rows_beyond_checked_range", trust.beyond_checked}}},
                        {"frames_variance_factor", a.frames_only ? nlohmann::json(frames_variance_factor) : nlohmann::json(nullptr)},
                        {"carried_extensions",
                         carried_check ? nlohmann::json{{"extensions", modelLabel(carried_check->extended.extensions)},
                                                        {"mean_extended_mm", carried_check->mean_extended_mm},
                                                        {"mean_geometric_mm", carried_check->mean_geometric_mm},
                                                        {"z", carried_check->z},
                                                        {"transfer", carried_check->extensions_transfer},
                                                        {"used", after.extensions.empty() ? "geometric" : "extended"},
                                                        {"text", carried_check->text}}
                                       : nlohmann::json(nullptr)},
                        {"beyond_data", [&] {
                           nlohmann::json j = nlohmann::json::array();
                           for (const auto& b : beyond)
                             j.push_back({{"joint", b.joint + 1}, {"lower_deg", b.lower_rad * 180 / kPi},
                                          {"upper_deg", b.upper_rad * 180 / kPi},
                                          {"sigma_at_1_rad_deg", b.sigma_at_1_rad * 180 / kPi}, {"growth", b.growth}});
                           nlohmann::json folds = nlohmann::json::array();
                           if (transfer)
                             for (const auto& t : transfer->joints)
                               folds.push_back({{"joint", t.beyond.joint + 1}, {"folds", t.folds},
                                                {"judged_rows", t.judged_rows}, {"ratio_rms_without", t.ratio_rms_without},
                                                {"ratio_rms_with", t.ratio_rms_with}});
                           return nlohmann::json{{"ranges", j}, {"carried", a.frames_only}, {"folds", folds},
                                                 {"not_measured", transfer ? transfer->not_measured : std::vector<std::string>{}},
                                                 {"text", transfer ? transfer->text : ""}};
                         }()},
                        {"implausible", implausible},
                        {"residual_map", residual_map_json},
                        {"unusable", unusable.empty() ? nlohmann::json(nullptr) : nlohmann::json(unusable)}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  std::printf("%s\n", recommendation(converged, unusable, vbk, vak, model_label, a.frames_only,
                                       pm.variance_factor_position, trust.extrapolated).c_str());
  if (const int code = failedExit(converged, unusable, a.save_robot)) return code;
  if (!a.save_robot.empty()) {
    RobotCalibration cal = robotCalibration(robot, after, pm);
    cal.residual_map = residual_map;
    if (!after.extensions.empty()) cal.beyond_data = beyond;
    // Beside an extended model, the same campaign's geometric calibration (a new set-up judges the extensions by it).
    if (!after.extensions.empty())
      cal.geometric_params = !a.frames_only ? r.params
                             : carried_check ? carried_check->geometric.params
                                             : in.calibration ? in.calibration->geometric_params : Eigen::VectorXd();
    if (a.frames_only) {  // estimated: the new frames, and what the robot file's own calibration estimated
      for (size_t k = 0; k < cal.columns.size(); ++k) {
        if (cal.estimated[k] || !in.calibration) continue;
        const auto& kc = in.calibration->columns;
        const auto it = std::find(kc.begin(), kc.end(), cal.columns[k]);
        cal.estimated[k] = it != kc.end() && in.calibration->estimated[static_cast<size_t>(it - kc.begin())];
      }
    }
    auto fixed = [](double v, int digits) {
      char b[64];
      std::snprintf(b, sizeof b, "%.*f", digits, v);
      return std::string(b);
    };
    if (a.frames_only && in.calibration)
      for (const auto& kv : in.calibration->provenance) cal.provenance.emplace_back("kinematics_" + kv.first, kv.second);
    cal.provenance = [&] {
      std::vector<std::pair<std::string, std::string>> pv = {
          {"date_utc", utcNow()},
          {"tool", a.frames_only ? "cellcal calibrate --frames-only" : "cellcal calibrate"},
          {"robot_file", a.input.robot},
          {"data_file", a.input.data},
          {"data_sha256", fileSha256(a.input.data)},
          {"rows", std::to_string(in.file.rows.size())},
          {"split", a.input.split},
          {"identification_rows", std::to_string(ident.size())},
          {"verification_rows", std::to_string(verify.size())},
          {"measurement", in.measurementJson()},
          {"model", a.frames_only ? "frames only" : model_label},
          {"verification_before_mean_mm", fixed(vbk.mean_mm, 4)},
          {"verification_mean_mm", fixed(vak.mean_mm, 4)},
          {"verification_rms_mm", fixed(vak.rms_mm, 4)},
          {"verification_max_mm", fixed(vak.max_mm, 4)},
          {"identification_max_mm", fixed(iak.max_mm, 4)}};
      pv.emplace_back("predicted_verification_rms_mm", fixed(trust.verify_rms_mm, 4));
      for (auto& kv : cal.provenance) pv.push_back(kv);
      return pv;
    }();
    saveRobotFile(a.save_robot, robot.withParams(after.params), &cal,
                  "Calibrated " + robot.name + ": written by `cellcal calibrate" + (a.frames_only ? " --frames-only" : "") +
                      "` from " + a.input.data + " (docs/robot-file.md, calibrated robot files)", &in.source);
    std::printf("calibrated robot file: %s\n", a.save_robot.c_str());
  }
  return 0;
}

}  // namespace

Runner addCalibrateCommand(CLI::App& app) { return addCommand(app, "calibrate", addOptions, runCalibrate); }

}  // namespace cellcal::cli
