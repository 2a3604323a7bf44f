// What `cellcal calibrate` prints of a campaign's report.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "calibrate_report.hpp"
#include "diagnosis_output.hpp"

namespace cellcal::cli {
namespace {

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

// The error table of a calibration: before and after on both row sets, and the verification rows without their
// gross errors when there are any; then the gross errors of both by file line.
void printErrorsAndGrossErrors(const CampaignErrors& e, double threshold, const CampaignInput& in,
                               const char* between = nullptr) {
  std::vector<std::pair<const char*, const ErrorStats*>> table = {
      {"identification before", &e.identification_before}, {"identification after", &e.identification_after},
      {"verification before", &e.verification_before}, {"verification after", &e.verification_after}};
  if (!e.verification_outliers.rows.empty()) {
    table.push_back({"  without gross errors", &e.verification_kept_before});
    table.push_back({"  without gross errors", &e.verification_kept_after});
  }
  std::printf("                 position mm: mean     rms   99.7%%     max   orientation deg: mean    rms   99.7%%     max\n");
  for (const auto& [name, s] : table)
    std::printf("  %-24s %8.4f %7.4f %7.4f %7.4f %17.4f %7.4f %7.4f %7.4f\n", name, s->mean_mm, s->rms_mm, s->p997_mm,
                s->max_mm, s->mean_deg, s->rms_deg, s->p997_deg, s->max_deg);
  if (between) std::printf("%s", between);
  const OutlierScreen &io = e.identification_outliers, &vo = e.verification_outliers;
  if (io.rows.empty() && vo.rows.empty()) return;
  std::printf("gross errors (more than %.0f robust sigmas of %.4f mm per axis):\n", threshold, io.sigma_position_m * 1e3);
  if (!io.rows.empty())
    std::printf("  identification: %zu rows left out of the fit: %s\n", io.rows.size(),
                linesText(io.rows, in.identification_lines).c_str());
  if (!vo.rows.empty())
    std::printf("  verification:   %zu rows: %s\n", vo.rows.size(), linesText(vo.rows, in.verification_lines).c_str());
}

void printSetups(const CalibrateArgs& a, const CampaignProblem& problem, const CampaignReport& rep) {
  const auto& ins = problem.setups;
  const SetupsFit& fit = rep.setups_fit;
  if (problem.model == CampaignModel::kAuto)
    std::printf("--model auto: every set-up names %s (diagnose on each set-up's rows)\n",
                rep.extensions.empty() ? "no cause: geometric" : rep.model_label.c_str());
  std::printf("%zu set-ups, one kinematic model (%s), a base and a tool frame per set-up: %zu kinematic, %zu frame "
              "and %zu extension parameters estimated, %s after %d iterations (%.1f ms)\n",
              ins.size(), rep.model_label.c_str(), fit.estimated_kinematic.size(),
              fit.estimated.size() - fit.estimated_kinematic.size() - fit.estimated_extension.size(),
              fit.estimated_extension.size(), fit.converged ? "converged" : "NOT converged", fit.iterations,
              rep.solve_s * 1e3);
  if (!rep.extensions.empty()) {
    std::printf("extension parameters (every set-up's):");
    for (int k : fit.estimated_extension)
      std::printf(" %s=%.6g", rep.extension_names[k].c_str(), fit.extension_params[k]);
    for (size_t k = 0; k < rep.extension_names.size(); ++k)
      if (!std::count(fit.estimated_extension.begin(), fit.estimated_extension.end(), static_cast<int>(k)))
        std::printf(" %s held at 0 (not separable from the geometric parameters on these rows)",
                    rep.extension_names[k].c_str());
    std::printf("\n");
  }
  if (!rep.held_names.empty()) {
    std::string held, gauge_held;
    std::vector<std::string> gauge;
    for (int c : frameGauge(problem.setups.front().robot, problem.setups.front().start))
      gauge.push_back(problem.setups.front().robot.paramNameHuman(c));
    for (const auto& h : rep.held_names) (std::count(gauge.begin(), gauge.end(), h) ? gauge_held : held) += " " + h;
    if (!gauge_held.empty())
      std::printf("held at their start value, carried by every set-up's base and tool frames (no data tell them from "
                  "the frames):%s\n", gauge_held.c_str());
    if (!held.empty()) std::printf("not identifiable from these data (held at their start value):%s\n", held.c_str());
  }
  for (size_t s = 0; s < ins.size(); ++s) {
    const CampaignInput& in = ins[s];
    if (in.found_block == 1) std::printf("\nNOTE: %s\n", foundSetupsText(in).c_str());
    std::printf("\nset-up %zu: %s: %zu rows (%s split: %zu identify, %zu verify), %s; registration rms %.3f mm\n",
                s + 1, in.name.c_str(), in.file.rows.size(), a.input.split.c_str(), in.data.identification.size(),
                in.data.verification.size(), in.measurementText().c_str(), in.registration_rms_mm);
    if (!in.setup_hint.empty()) std::printf("WARNING: %s\n", in.setup_hint.c_str());
    if (!in.registration_note.empty()) std::printf("NOTE: %s\n", in.registration_note.c_str());
    if (in.model_error_added) std::printf("%s\n", in.modelErrorText().c_str());
    if (rep.setups[s].rows_left_out_backlash > 0)
      std::printf("%d identification row(s) before the backlash joint first moved in this set-up left out of the fit "
                  "(which side of the gap it rested on is unknown); they are predicted at the middle of the gap\n",
                  rep.setups[s].rows_left_out_backlash);
    printErrorsAndGrossErrors(rep.setups[s].errors, problem.outliers.threshold, in);
  }
  std::printf("\n('before': the robot file's kinematics with each set-up's registered frames; 'after': the common "
              "kinematics%s with each set-up's fitted frames)\n",
              rep.extensions.empty() ? "" : " and extension parameters");
}

// The estimated parameters: value, change from the start (the robot file's, frames registered) and 1 sigma.
void printParameters(const CalibrateArgs& a, const CampaignInput& in, const CampaignReport& rep) {
  const RobotModel& robot = in.robot;
  const ExtendedFit& after = rep.after;
  const Eigen::VectorXd& start = in.start;
  const PredictionModel& pm = rep.prediction;
  // The readings' sigmas weight the fit; the residual says how far they hold: the sigmas are scaled by the square root
  // of the a-posteriori variance factor (1 when the readings' sigmas and the model are right).
  const double vf = std::sqrt(std::max(1.0, a.frames_only ? rep.frames_variance_factor : pm.variance_factor));
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
}

// The residual map: what the model leaves, learnt at the identification rows, applied near them.
void printResidualMap(const CampaignReport& rep) {
  const ResidualMap& map = *rep.residual_map;
  const ResidualMapCheck& c = rep.residual_map_check;
  std::string scales;
  for (Eigen::Index j = 0; j < map.lengthScales_rad().size(); ++j)
    scales += (j ? " " : "") + std::to_string(static_cast<int>(std::lround(map.lengthScales_rad()[j] * 180 / kPi)));
  std::printf("residual map: %zu identification rows, length scales %s deg (joints 1-%d), signal %.4f mm, noise %.4f mm "
              "(%.1f s)\n", map.rows(), scales.c_str(), static_cast<int>(map.lengthScales_rad().size()),
              map.signalSigma_m() * 1e3, map.noiseSigma_m() * 1e3, c.fit_time_s);
  std::printf("  verification rows within %.2g length scales of an identification row: %d of %d; their held-out mean "
              "%.4f mm with the map, %.4f mm without (the map's 1 sigma there %.4f mm per axis)\n",
              map.maxDistance(), c.verification_rows_near, c.verification_rows, c.near_mean_with_mm,
              c.near_mean_without_mm, c.near_sigma_mean_mm);
  std::printf("  every verification row (the map where it applies): %.4f mm, without the map %.4f mm\n",
              c.all_mean_with_mm, c.all_mean_without_mm);
}

// Held: what the frames stand for, what the rows do not separate (rank), and what they pin no better than its
// plausible range.
void printHeld(const RobotModel& robot, const Eigen::VectorXd& start, const CampaignReport& rep) {
  std::string gauge_held, rank_held, prior_held;
  const IdentifiabilityReport& ir = rep.geometric.identifiability;
  const std::vector<int> gauge = frameGauge(robot, start);
  for (const auto& d : ir.dropped) {
    if (std::binary_search(gauge.begin(), gauge.end(), d.index)) {
      gauge_held += " " + robot.paramNameHuman(d.index);
      continue;
    }
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
  if (!gauge_held.empty())
    std::printf("held at their start value, carried by the base and tool frames (no data tell them from the frames):%s\n",
                gauge_held.c_str());
  if (!rank_held.empty()) std::printf("not identifiable from these data (held at their start value):%s\n", rank_held.c_str());
  if (!prior_held.empty())
    std::printf("held at their start value: the data (at %.2fx the readings' sigmas, what the fit leaves) pin them "
                "no better than their plausible deviation (--plausible-length-mm, --plausible-angle-deg):%s\n",
                ir.noise_scale, prior_held.c_str());
}

}  // namespace

void printCampaignReport(const CalibrateArgs& a, const CampaignProblem& problem, const CampaignReport& rep) {
  if (rep.several_setups) return printSetups(a, problem, rep);
  const CampaignInput& in = problem.setups.front();
  const RobotModel& robot = in.robot;
  const PredictionModel& pm = rep.prediction;
  const PredictionCheck& trust = rep.check;
  std::printf("%s: %zu rows (%s split: %zu identify, %zu verify), %s, robot %s\n", a.input.data.c_str(),
              in.file.rows.size(), a.input.split.c_str(), in.data.identification.size(), in.data.verification.size(),
              in.measurementText().c_str(), robot.name.c_str());
  if (!a.input.no_register)
    std::printf("registration of base and tool frames: rms %.3f mm (%.1f ms)\n", in.registration_rms_mm,
                in.registration_s * 1e3);
  if (!in.setup_hint.empty()) std::printf("WARNING: %s\n", in.setup_hint.c_str());
  if (!in.registration_note.empty()) std::printf("NOTE: %s\n", in.registration_note.c_str());
  if (in.model_error_added) std::printf("%s\n", in.modelErrorText().c_str());
  std::printf("calibration, model %s (%s): %s after %d iterations, %zu parameters estimated (%.1f ms)\n",
              rep.model_label.c_str(), a.model == "geometric" && a.solver == "lm" ? "Levenberg-Marquardt" : "Gauss-Newton",
              rep.converged ? "converged" : "NOT converged", rep.iterations, rep.estimated, rep.solve_s * 1e3);
  if (!rep.converged) std::printf("  solver: %s\n", rep.message.c_str());
  std::string region_text;  // --model auto: the region and drift checks
  if (rep.diagnosis) {
    region_text = regionCheckText(*rep.diagnosis);
    if (const std::string t = driftCheckText(*rep.diagnosis); !t.empty())
      region_text += (region_text.empty() ? "" : "\n") + t;
  }
  std::printf("%s\n", region_text.c_str());
  if (rep.transfer) {
    std::string t = rep.transfer->text;
    for (size_t at = t.find('\n'); at != std::string::npos; at = t.find('\n', at + 3)) t.replace(at, 1, "\n  ");
    std::printf("beyond its data (region folds):\n  %s\n", t.c_str());
  }
  if (a.frames_only)
    for (const auto& b : rep.beyond)
      std::printf("carried beyond the campaign's data: joint %d outside %s%s%s, a further joint error of %.3g deg%s, "
                  "judged up to %.1f deg beyond (the robot file's beyond_data)\n",
                  b.joint + 1, b.rangeText().c_str(), b.gaps_rad.empty() ? "" : " or in its gaps", b.gapsText().c_str(),
                  b.sigma_at_1_rad * 180 / kPi, b.growthText(), b.checked_rad * 180 / kPi);
  if (a.frames_only)
    for (const auto& d : rep.beyond_drivers)
      std::printf("carried beyond the campaign's data: %s outside %s, a further position error of %.3g mm%s, %s "
                  "(the robot file's beyond_drivers)\n",
                  extensionLabel(d.extension).c_str(), d.rangeText().c_str(), d.sigma_at_1_m * 1e3,
                  d.growthText().c_str(), d.judgedText().c_str());
  if (rep.carried)
    std::printf("%s%s\n", rep.carried->text.c_str(),
                rep.carried->extensions_transfer ? ""
                : a.keep_extensions              ? ": kept (--keep-extensions)"
                                                 : ": the geometric calibration is used (--keep-extensions keeps them)");
  if (!rep.frames_held.empty()) {
    std::string held;
    for (const auto& [c, sigma] : rep.frames_held) {
      char buf[120];
      if (std::isfinite(sigma))
        std::snprintf(buf, sizeof buf, " %s (the rows: +-%.3g)", in.robot.paramNameHuman(c).c_str(), in.robot.toHuman(c, sigma));
      else
        std::snprintf(buf, sizeof buf, " %s (the rows: not at all)", in.robot.paramNameHuman(c).c_str());
      held += buf;
    }
    std::printf("held at the robot file's values, where its calibration put the target (these rows cannot tell them "
                "from the base frame: one tool orientation, or nearly; a re-mounted target needs rows at several "
                "orientations):%s\n", held.c_str());
  }
  if (const auto& n = rep.against_nominal)
    std::printf("the robot file's calibration against its nominal kinematics, registered alike on these rows: %.4f mm "
                "held-out mean against %.4f mm (%.1f standard errors %s)%s\n",
                n->mean_carried_mm, n->mean_nominal_mm, std::abs(n->z), n->z <= 0 ? "better" : "worse",
                rep.nominalDeployed() ? ": the nominal kinematics are used"
                : n->nominal_better   ? ": kept (--keep-extensions), not to be deployed"
                                      : "");
  printErrorsAndGrossErrors(
      rep.errors, problem.outliers.threshold, in,
      a.frames_only && rep.against_nominal
          ? "\n('before': the kinematics the robot file's calibration started from, at their least-squares frames; "
            "'after': the model deployed, with the frames fitted)\n"
      : a.frames_only ? "\n('before': the robot file's kinematics, no extensions, at their least-squares frames; 'after': "
                        "its kinematics and extensions with the frames fitted)\n"
                    : "\n('before': the robot file's kinematics at their least-squares frames; 'after': every "
                      "identifiable parameter)\n");
  printParameters(a, in, rep);
  for (const auto& h : rep.held) std::printf("held: %s\n", deficitText(h).c_str());
  // Two different figures: how uncertain the fitted parameters are (small with many rows), and what the model leaves
  // (the residual it cannot explain, which no amount of data shrinks).
  std::printf("uncertainty of the calibrated model (1 sigma, position%s): %.4f mm RMS on the verification rows (max "
              "%.4f; identification rows %.4f, max %.4f): how far the fitted parameters may lie from the best this "
              "model can do on these data\n",
              a.frames_only ? (in.calibration ? "; the robot file's covariance less what the new frames take up"
                                              : "; the priors of an uncalibrated model less what the new frames take up")
                            : "",
              trust.verification_rms_mm, trust.verification_max_mm, trust.identification_rms_mm,
              trust.identification_max_mm);
  std::printf("what the model leaves: %.4f mm RMS on the verification rows, the readings' position sigmas x %.1f "
              "(position variance factor %.2f)%s\n",
              rep.errors.verification_after.rms_mm, std::sqrt(pm.variance_factor_position), pm.variance_factor_position,
              pm.variance_factor_position > 4 ? ": effects the model does not hold, or readings noisier than their "
                                                "sigmas (`cellcal diagnose` looks for the cause)"
                                              : ": about the readings' noise");
  std::printf("check: the verification errors against that uncertainty and the residual together: RMS ratio %.2f (1: "
              "the predicted errors can be trusted)\n", trust.ratio_rms);
  if (trust.beyond_checked > 0)
    std::printf("  %d verification rows lie farther beyond a joint's calibrated range than the region folds judged the "
                "model's extensions: what they do there was never tested, their predicted error there is an "
                "extrapolation\n", trust.beyond_checked);
  if (trust.extrapolated > 0)
    std::printf("  %d verification rows lie outside the calibrated region (predicted error more than 3x the largest on "
                "the identification rows)\n", trust.extrapolated);
  for (const auto& w : rep.implausible)
    std::printf("implausible: %s: a target offset or frame the robot file does not have (a gauge with its own frame?), "
                "or too little excitation\n", w.c_str());
  if (rep.residual_map) printResidualMap(rep);
  printHeld(robot, in.start, rep);
}

}  // namespace cellcal::cli
