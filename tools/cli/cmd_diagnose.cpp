// `cellcal diagnose`: what the geometric model gets wrong in a measurement file, which physical cause explains it,
// the extended model and its gain on held-out rows.
#include <iomanip>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "commands.hpp"
#include "diagnosis_output.hpp"
#include "measurement_input.hpp"
#include "progress.hpp"

namespace cellcal::cli {
namespace {

struct DiagnoseArgs {
  InputArgs input;
  std::string json, report;
  bool no_progress = false, no_region_check = false;
};

void addOptions(CLI::App& cmd, DiagnoseArgs& a) {
  addInputOptions(&cmd, a.input);
  cmd.add_option("--json", a.json, "write the results as JSON")->check(outputFile());
  cmd.add_flag("--no-progress", a.no_progress, "no progress bar (it is drawn only when stderr is a terminal)");
  cmd.add_flag("--no-region-check", a.no_region_check,
               "keep every cause the selection chose; by default each is fitted again on one half of the workspace and "
               "judged on the other, and one that does not lower the error there is left out (with those after it)");
  cmd.add_option("--report", a.report, "write report.md and the cause's signature (signature.svg, signature.png; gnuplot) into this directory");
}

const char* verdictName(Verdict v) {
  switch (v) {
    case Verdict::kNoise: return "noise";
    case Verdict::kNamed: return "named";
    case Verdict::kPartlyExplained: return "partly_explained";
    case Verdict::kUnexplained: return "unexplained";
    case Verdict::kUnusable: return "unusable";
  }
  return "?";
}

nlohmann::json jointsJson(const Extension& e) {
  nlohmann::json j = nlohmann::json::array();
  if (e.joint >= 0) j.push_back(e.joint + 1);
  return j;
}

nlohmann::json fitJson(const CandidateResult& c) {
  nlohmann::json j = errorStatsJson(c.verification, "verify_");
  j.update(errorStatsJson(c.identification, "ident_"));
  j["converged"] = c.fit.converged;
  return j;
}

nlohmann::json paramsJson(const ExtendedFit& f, bool stddev = false) {
  nlohmann::json p = nlohmann::json::object();
  for (int k : f.estimated_extension) p[f.extension_names[k]] = stddev ? f.extensionStddev(k) : f.extension_params[k];
  return p;
}

nlohmann::json structureJson(const std::vector<DriverStructure>& s) {
  nlohmann::json a = nlohmann::json::array();
  for (const auto& d : s)
    a.push_back({{"driver", d.driver}, {"share", d.share}, {"p_value", d.p_value}, {"significant", d.significant}});
  return a;
}

// The drivers with structure beyond noise (share of the residual variance), or "none beyond noise".
std::string structureLine(const std::vector<DriverStructure>& s, size_t n) {
  std::string o;
  char b[96];
  size_t shown = 0;
  for (const auto& d : s) {
    if (!d.significant || shown == n) continue;
    std::snprintf(b, sizeof b, "%s%s %.0f %%", shown++ ? ", " : "", d.driver.c_str(), 100 * d.share);
    o += b;
  }
  return o.empty() ? "none beyond noise" : o;
}

// The gross errors and the table of single causes, with the forward selection when it took more than one.
void printCandidates(const LoadedInput& in, const DiagnosisResult& d, const DiagnosisOptions& options) {
  const CandidateResult& g = d.geometric;
  const auto& io = d.identification_outliers;
  const auto& vo = d.verification_outliers;
  if (!io.rows.empty() || !vo.rows.empty()) {
    std::printf("gross errors (more than %.0f robust sigmas; left out of fits and scores):\n", options.outliers.threshold);
    if (!io.rows.empty())
      std::printf("  identification: %zu rows, %s\n", io.rows.size(), linesText(io.rows, in.identification_lines).c_str());
    if (!vo.rows.empty())
      std::printf("  verification:   %zu rows, %s\n", vo.rows.size(), linesText(vo.rows, in.verification_lines).c_str());
  }
  std::printf("\n%-44s %6s %12s %12s %8s\n", "single causes (verification rows)", "params", "mean mm", "rms mm", "z");
  std::printf("%-44s %6s %12.4f %12.4f\n", "geometric", "-", g.verification.mean_mm, g.verification.rms_mm);
  for (size_t i = 0; i < d.candidates.size(); ++i) {
    const auto& c = d.candidates[i];
    std::printf("%-44s %6d %12.4f %12.4f %8.1f%s\n", extensionLabel(c.fit.extensions.back()).c_str(),
                c.fit.numEstimatedExtension(), c.verification.mean_mm, c.verification.rms_mm, c.z,
                static_cast<int>(i) != d.chosen ? (c.screened ? "   (screened: one linearized step)" : "")
                // Candidates are in score order; a later one is chosen for fewer parameters (diagnosis.cpp's
                // chooseCandidate), which the table would otherwise leave unsaid.
                : i == 0 ? "   <- first chosen (best score)"
                         : "   <- first chosen (fewer parameters than those above it, not significantly worse)");
  }
  if (d.selection.size() > 1) {
    std::printf("\nforward selection (each added cause fitted with the ones before it):\n");
    for (const auto& st : d.selection)
      std::printf("  + %-40s verification mean %.4f mm, gain %.1f %%, z %.1f\n", extensionLabel(st.added).c_str(),
                  st.result.verification.mean_mm, st.gain_pct, st.z);
  }
}

// The cause named (or not), what it gains, the noise and what is left unexplained.
void printCause(const LoadedInput& in, const DiagnosisResult& d) {
  const CandidateResult& g = d.geometric;
  const CandidateResult& b = d.best();
  const auto& vo = d.verification_outliers;
  if (const std::string r = regionCheckText(d); !r.empty()) std::printf("\n%s", r.c_str());
  if (const std::string r = driftCheckText(d); !r.empty()) std::printf("\n%s", r.c_str());
  std::printf("\nresidual structure, geometric model: %s\n", structureLine(d.structure_before, 4).c_str());
  if (!d.selection.empty()) std::printf("residual structure, final model:     %s\n", structureLine(d.structure_after, 4).c_str());
  std::printf("\ncause: %s\n", describeVerdict(d).c_str());
  for (const auto& st : d.selection)
    if (!st.alike.empty()) {
      std::string alike;
      for (const auto& e : st.alike) alike += (alike.empty() ? "" : ", ") + extensionLabel(e);
      std::printf("  %s: these data tell it only weakly from %s\n", extensionLabel(st.added).c_str(), alike.c_str());
    }
  std::printf("  held-out (verification rows): mean %.4f -> %.4f mm (gain %.1f %%), 99.7%% %.4f -> %.4f mm, max %.4f -> "
              "%.4f mm", g.verification.mean_mm, b.verification.mean_mm, d.gain_pct, g.verification.p997_mm,
              b.verification.p997_mm, g.verification.max_mm, b.verification.max_mm);
  if (!vo.rows.empty())
    std::printf("; with the gross errors (%zu rows): %.4f -> %.4f mm", vo.rows.size(), d.geometric_verification_all_rows.mean_mm,
                d.verification_all_rows.mean_mm);
  std::printf("\n");
  if (d.noise.from_repeats) {
    std::printf("reading noise: %.4f mm per axis (%.4f mm RMS), estimated from the %s\n", d.noise.sigma_position_mm,
                d.noise_rms_mm, d.noise.source.c_str());
    std::printf("unexplained: %.4f mm RMS beyond that noise (diagnosis %.2f s)\n", d.unexplained_rms_mm, d.solve_time_s);
  } else {  // without repeated poses the noise is the model's residual: nothing is 'beyond' it
    std::printf("reading noise: not measured (no pose measured twice); the %s leaves %.4f mm per axis (%.4f mm RMS), "
                "the readings' noise and what the model misses together (diagnosis %.2f s)\n",
                d.noise.source.c_str(), d.noise.sigma_position_mm, d.noise_rms_mm, d.solve_time_s);
  }
  {
    // Kinematic parameters held at the robot file's value: the rows pin them no better than their plausible range.
    std::string held;
    for (int c : in.robot.canonicalParams())
      if (c < 5 * in.robot.numJoints() && std::find(g.fit.estimated.begin(), g.fit.estimated.end(), c) == g.fit.estimated.end())
        held += " " + in.robot.paramNameHuman(c);
    if (!held.empty())
      std::printf("kinematic parameters held at the robot file's value (not identifiable, or pinned no better than "
                  "their plausible deviation at %.2fx the readings' sigmas):%s\n",
                  d.identifiability_noise_scale, held.c_str());
  }
  for (const auto& h : b.held) std::printf("held: %s\n", deficitText(h).c_str());
}

// What the calibration engine takes (its topics carry no temperature: thermal drift stays with its drift model);
// nothing when the model is not usable. Returns the extensions for the cell file.
std::vector<std::string> printEngineAdvice(const DiagnosisResult& d) {
  std::vector<std::string> cell_extensions;
  bool thermal = false;
  for (const auto& e : d.unusable.empty() ? d.causes() : std::vector<Extension>{}) {
    if (followsThermalDriver(e.cause)) thermal = true;
    else cell_extensions.push_back(extensionSpec(e));
  }
  if (!cell_extensions.empty()) {
    std::string list;
    for (const auto& e : cell_extensions) list += (list.empty() ? "" : ", ") + e;
    std::printf("calibration engine: add `extensions: [%s]` to this robot in the cell file (RLS state with the extension)\n",
                list.c_str());
    if (const DriverStructure* left = d.structureLeft())
      std::printf("  warning: this leaves structure against %s (%.0f %% of the residual) that no cause in the library "
                  "explains; the extension improves the model but is not the whole story\n",
                  left->driver.c_str(), 100 * left->share);
  }
  if (thermal)
    std::printf("calibration engine: thermal_drift is left to the engine's drift model (the cell's topics carry no "
                "temperature)\n");
  return cell_extensions;
}

void writeDiagnoseJson(const DiagnoseArgs& a, const LoadedInput& in, const DiagnosisResult& d,
                       const DiagnosisOptions& options, const std::vector<std::string>& cell_extensions) {
  const CandidateResult& g = d.geometric;
  const CandidateResult& b = d.best();
  const auto& io = d.identification_outliers;
  const auto& vo = d.verification_outliers;
  nlohmann::json cands = nlohmann::json::array();
  for (const auto& c : d.candidates)
    cands.push_back({{"cause", causeName(c.fit.extension().cause)}, {"joints", jointsJson(c.fit.extension())},
                     {"label", extensionLabel(c.fit.extensions.back())},
                     {"verify_mean_mm", c.verification.mean_mm}, {"verify_rms_mm", c.verification.rms_mm},
                     {"num_params", c.fit.numEstimatedExtension()}, {"params", paramsJson(c.fit)}, {"z", c.z},
                     {"score_m2", c.score}, {"screened", c.screened}});
  nlohmann::json causes = nlohmann::json::array();
  for (const auto& st : d.selection)
    causes.push_back({{"cause", causeName(st.added.cause)}, {"joints", jointsJson(st.added)},
                      {"label", extensionLabel(st.added)}, {"verify_mean_mm", st.result.verification.mean_mm},
                      {"alike", [&] {
                         nlohmann::json a = nlohmann::json::array();
                         for (const auto& e : st.alike) a.push_back(extensionLabel(e));
                         return a;
                       }()},
                      {"gain_pct", st.gain_pct}, {"z", st.z},
                      {"time_constant_h", followsThermalDriver(st.added.cause) && st.added.time_constant_h > 0 &&
                                                  std::isfinite(st.added.time_constant_h)
                                              ? nlohmann::json(st.added.time_constant_h)
                                              : nlohmann::json(nullptr)}});
  const DriverStructure* left = d.structureLeft();
  nlohmann::json found = nlohmann::json::array();
  for (const auto& f : in.found_changes) found.push_back(foundChangeJson(f));
  nlohmann::json j = {{"data", a.input.data}, {"robot", in.robot.name}, {"rows", in.file.rows.size()},
                      {"setup_changes_found", found}, {"rows_diagnosed", in.name},
                      {"split", a.input.split}, {"measurement", in.measurementName()}, {"model_error_sigma", modelErrorJson(in)},
                      {"thermal_driver", in.data.has_thermal ? in.data.thermal_source : "none"},
                      {"constant_temperature_c", in.data.constant_temperature_c ? nlohmann::json(*in.data.constant_temperature_c) : nlohmann::json(nullptr)},
                      {"verdict", verdictName(d.verdict)}, {"verdict_text", describeVerdict(d)},
                      {"structure_left", left ? nlohmann::json({{"driver", left->driver}, {"share", left->share},
                                                                {"p_value", left->p_value}})
                                              : nlohmann::json(nullptr)},
                      {"cause", causeName(d.cause)}, {"joints", d.chosen >= 0 ? jointsJson(d.selection.front().added) : nlohmann::json::array()},
                      {"causes", causes}, {"region_check", regionCheckJson(d)}, {"drift_check", driftCheckJson(d)},
                      {"geometric", fitJson(g)}, {"extended", fitJson(b)}, {"gain_pct", d.gain_pct},
                      {"verification_all_rows", {{"geometric", errorStatsJson(d.geometric_verification_all_rows)},
                                                 {"extended", errorStatsJson(d.verification_all_rows)}}},
                      {"outliers", {{"identification", outliersJson(io, in.identification_lines)},
                                    {"verification", outliersJson(vo, in.verification_lines)},
                                    {"threshold_robust_sigmas", options.outliers.threshold}}},
                      {"extension_params", !d.selection.empty() ? paramsJson(b.fit) : nlohmann::json::object()},
                      {"extension_stddev", !d.selection.empty() ? paramsJson(b.fit, true) : nlohmann::json::object()},
                      {"cell_extensions", cell_extensions}, {"candidates", cands}, {"structure_before", structureJson(d.structure_before)},
                      {"structure_after", structureJson(d.structure_after)},
                      {"noise", {{"sigma_position_mm", d.noise.sigma_position_mm}, {"dof", d.noise.dof},
                                 {"from_repeats", d.noise.from_repeats}, {"source", d.noise.source}}},
                      {"noise_rms_mm", d.noise_rms_mm},
                      {"identifiability_noise_scale", d.identifiability_noise_scale},
                      {"unexplained_rms_mm", d.noise.from_repeats ? nlohmann::json(d.unexplained_rms_mm) : nlohmann::json(nullptr)}, {"diagnosis_time_s", d.solve_time_s},
                      {"held", heldJson(b.held)},
                      {"unusable", d.unusable.empty() ? nlohmann::json(nullptr) : nlohmann::json(d.unusable)}};
  std::ofstream o(a.json);
  if (!o) throw std::runtime_error(a.json + ": cannot write");
  o << j.dump(2) << "\n";
}

// The plain answer: which model to deploy, and why; the exit code.
int recommend(const DiagnosisResult& d) {
  const CandidateResult& g = d.geometric;
  const CandidateResult& b = d.best();
  const bool converged = g.fit.converged && b.fit.converged;
  if (!converged) {
    std::printf("recommendation: deploy neither: the %s fit did not converge (%s; exit 3)\n",
                g.fit.converged ? "extended" : "geometric", (g.fit.converged ? b.fit : g.fit).message.c_str());
    return 3;
  }
  if (!d.unusable.empty()) {
    std::printf("recommendation: deploy neither: %s (exit 4)\n", d.unusable.c_str());
    return 4;
  }
  if (d.selection.empty()) {
    std::printf("recommendation: deploy the geometric model (`cellcal calibrate`): no cause in the library improves its "
                "held-out mean %.4f mm", g.verification.mean_mm);
    if (const DriverStructure* left = d.structureLeft())
      std::printf("; structure against %s (%.0f %% of the residual) is left that no cause in the library explains",
                  left->driver.c_str(), 100 * left->share);
    std::printf("\n");
  } else {
    std::printf("recommendation: deploy the extended model %s (`cellcal calibrate --model auto`): held-out mean %.4f mm "
                "against %.4f mm for the geometric model (%.1f %% better)%s\n",
                modelLabel(b.fit.extensions).c_str(), b.verification.mean_mm, g.verification.mean_mm, d.gain_pct,
                d.structureLeft() ? "; it explains only part of what the geometric model leaves" : "");
    std::printf("  to the cell's compensation publisher (it carries the extensions); a URDF or a controller's kinematics "
                "file cannot: `cellcal robot export` writes the geometric calibration the saved robot file keeps beside "
                "it (docs/robot-file.md)\n");
  }
  return 0;
}

int runDiagnose(const DiagnoseArgs& a) {
  const LoadedInput in = loadInput(a.input);
  DiagnosisOptions options;
  options.outliers = outlierOptions(a.input);
  options.identifiability.prior_sigma = plausibleRanges(a.input, in.robot);
  options.region_check = !a.no_region_check;
  ProgressBar bar("diagnose", !a.no_progress);
  options.progress = [&bar](int done, int total) {
    bar.update(static_cast<double>(done) / total, std::to_string(done) + "/" + std::to_string(total) + " model fits");
  };
  if (!in.setup_hint.empty()) std::printf("WARNING: %s\n", in.setup_hint.c_str());
  if (in.found_block > 0)
    std::printf("WARNING: %s. diagnose takes one: it diagnoses %s, the largest; `cellcal calibrate` fits them all\n",
                foundSetupsText(in).c_str(), in.name.c_str());
  if (!in.registration_note.empty()) std::printf("NOTE: %s\n", in.registration_note.c_str());
  if (in.model_error_added) std::printf("%s\n", in.modelErrorText().c_str());
  const DiagnosisResult d = diagnose(in.robot, in.start, in.data, options);
  bar.done();
  std::printf("%s: %zu rows (%s split: %zu identify, %zu verify), %s, robot %s, thermal driver: %s\n",
              a.input.data.c_str(), in.file.rows.size(), a.input.split.c_str(), in.data.identification.size(),
              in.data.verification.size(), in.measurementText().c_str(),
              in.robot.name.c_str(), in.data.thermalText().c_str());
  printCandidates(in, d, options);
  printCause(in, d);
  const std::vector<std::string> cell_extensions = printEngineAdvice(d);
  if (!a.json.empty()) writeDiagnoseJson(a, in, d, options, cell_extensions);
  if (!a.report.empty()) {
    writeDiagnosisReport(a.report, a.input, in, d);
    std::printf("report: %s/report.md\n", a.report.c_str());
  }
  return recommend(d);
}

}  // namespace

Runner addDiagnoseCommand(CLI::App& app) { return addCommand(app, "diagnose", addOptions, runDiagnose); }

}  // namespace cellcal::cli
