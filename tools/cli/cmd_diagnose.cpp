// `cellcal diagnose`: what the geometric model gets wrong in a measurement file, which physical cause explains it,
// the extended model and its gain on held-out rows.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/diagnosis.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"
#include "progress.hpp"

namespace cellcal::cli {
namespace {

struct DiagnoseArgs {
  InputArgs input;
  std::string json, report;
  bool no_progress = false;
};

std::string causeLabel(const Extension& e) {
  std::string s = causeName(e.cause);
  if (e.cause == Cause::kThermalDrift && e.joint < 0) return s + " (lengths)";
  if (e.joint >= 0) s += " joint " + std::to_string(e.joint + 1);
  return s;
}

nlohmann::json jointsJson(const Extension& e) {
  nlohmann::json j = nlohmann::json::array();
  if (e.joint >= 0) j.push_back(e.joint + 1);
  return j;
}

nlohmann::json fitJson(const CandidateResult& c) {
  nlohmann::json j = errorStatsJson(c.verification, "verify_");
  j.update(errorStatsJson(c.identification, "ident_"));
  return j;
}

nlohmann::json paramsJson(const ExtendedFit& f, bool stddev = false) {
  nlohmann::json p = nlohmann::json::object();
  for (int k : f.estimated_extension) p[f.extension_names[k]] = stddev ? f.extensionStddev(k) : f.extension_params[k];
  return p;
}

nlohmann::json structureJson(const std::vector<DriverStructure>& s) {
  nlohmann::json a = nlohmann::json::array();
  for (const auto& d : s) a.push_back({{"driver", d.driver}, {"r2_adjusted", d.r2_adjusted}});
  return a;
}

std::string structureLine(const std::vector<DriverStructure>& s, size_t n) {
  std::string o;
  char b[96];
  for (size_t i = 0; i < std::min(n, s.size()); ++i) {
    std::snprintf(b, sizeof b, "%s%s %.0f %%", i ? ", " : "", s[i].driver.c_str(), 100 * std::max(0.0, s[i].r2_adjusted));
    o += b;
  }
  return o;
}

void writeReport(const DiagnoseArgs& a, const LoadedInput& in, const DiagnosisResult& d) {
  namespace fs = std::filesystem;
  fs::create_directories(a.report);
  std::ofstream md(a.report + "/report.md");
  if (!md) throw std::runtime_error(a.report + "/report.md: cannot write");
  const CandidateResult& g = d.geometric;
  const CandidateResult& b = d.best();
  char buf[512];
  md << "# cellcal diagnose: " << in.robot.name << "\n\n";
  md << "Data: `" << a.input.data << "`, " << in.file.rows.size() << " rows (" << a.input.split << " split: "
     << in.data.identification.size() << " identify, " << in.data.verification.size() << " verify), "
     << in.measurementText() << ". Thermal driver: "
     << (in.data.has_thermal ? in.data.thermal_source : std::string("none")) << ".\n\n";
  md << "## Finding\n\n";
  if (d.chosen < 0) {
    md << "**none**: no cause in the library explains the verification residual better than the geometric model "
          "(it is noise, or structure none of the causes has).\n\n";
  } else {
    std::snprintf(buf, sizeof buf,
                  "**%s**: verification mean position error %.4f -> %.4f mm (gain %.1f %%), RMS %.4f -> %.4f mm; "
                  "%.1f standard errors better than the geometric model on the verification rows.\n\n",
                  causeLabel(b.fit.extension()).c_str(), g.verification.mean_mm, b.verification.mean_mm, d.gain_pct,
                  g.verification.rms_mm, b.verification.rms_mm, b.z);
    md << buf;
  }
  std::snprintf(buf, sizeof buf,
                "Still unexplained: %.4f mm RMS beyond the expected measurement noise (%.4f mm RMS from "
                "--sigma-position-mm).\n\n",
                d.unexplained_rms_mm, d.noise_rms_mm);
  md << buf;
  md << "## Residual structure (verification rows)\n\nShare of the position residual each driver explains "
        "(adjusted R^2 of a small regression on it; 0 = none).\n\n| driver | geometric | "
     << (d.chosen >= 0 ? "extended" : "-") << " |\n|---|---|---|\n";
  for (const auto& s : d.structure_before) {
    double after = 0;
    for (const auto& t : d.structure_after)
      if (t.driver == s.driver) after = t.r2_adjusted;
    std::snprintf(buf, sizeof buf, "| %s | %.1f %% | %.1f %% |\n", s.driver.c_str(), 100 * std::max(0.0, s.r2_adjusted),
                  100 * std::max(0.0, after));
    md << buf;
  }
  md << "\n## Candidates (best score first)\n\n| cause | parameters | verify mean mm | verify RMS mm | z |\n"
        "|---|---|---|---|---|\n";
  std::snprintf(buf, sizeof buf, "| geometric | 0 | %.4f | %.4f | |\n", g.verification.mean_mm, g.verification.rms_mm);
  md << buf;
  for (const auto& c : d.candidates) {
    std::snprintf(buf, sizeof buf, "| %s | %d | %.4f | %.4f | %.1f |\n", causeLabel(c.fit.extension()).c_str(),
                  c.fit.numEstimatedExtension(), c.verification.mean_mm, c.verification.rms_mm, c.z);
    md << buf;
  }
  if (d.chosen >= 0) {
    const CauseSignature sig = causeSignature(in.robot, g.fit, b.fit, in.data.verification,
                                              in.data.verification_drivers, in.data.thermal_source);
    // Rendered by gnuplot (SVG): two panels sharing the axes, the residual before and after the extension.
    std::ostringstream data, gp;
    data << "x before after\n";
    double lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < sig.x.size(); ++i) {
      data << sig.x[i] << ' ' << sig.y_before[i] << ' ' << sig.y_after[i] << '\n';
      lo = std::min({lo, sig.y_before[i], sig.y_after[i]});
      hi = std::max({hi, sig.y_before[i], sig.y_after[i]});
    }
    const double pad = 0.05 * std::max(hi - lo, 1e-12);
    gp << "set multiplot layout 1,2\nset grid\nset key off\nset xlabel '" << sig.x_label << "'\nset ylabel '"
       << sig.y_label << "'\nset yrange [" << lo - pad << ":" << hi + pad << "]\n"
       << "set title 'geometric model'\nplot datafile using 1:2 skip 1 with points pt 7 ps 0.4 lc rgb '#1f77b4'\n"
       << "set title 'with " << causeLabel(b.fit.extension())
       << "'\nplot datafile using 1:3 skip 1 with points pt 7 ps 0.4 lc rgb '#d62728'\nunset multiplot\n";
    std::string plot_error;
    for (const char* format : {"svg", "png"})  // SVG for the report, PNG for pages that take images only
      if (!renderGnuplot(a.report, "signature", data.str(), gp.str(), &plot_error, format))
        std::cerr << "warning: " << plot_error << "\n";
    md << "\n## The cause in the data\n\nVerification rows: the residual as the cause's own quantity against its "
          "driver, before and after the extension.\n\n![signature](signature.svg)\n\nExtension parameters:\n\n";
    for (int k : b.fit.estimated_extension) {
      std::snprintf(buf, sizeof buf, "- `%s` = %.6g (1σ %.2g, from the reading sigmas)\n", b.fit.extension_names[k].c_str(),
                    b.fit.extension_params[k], b.fit.extensionStddev(k));
      md << buf;
    }
  }
}

int runDiagnose(const DiagnoseArgs& a) {
  const LoadedInput in = loadInput(a.input);
  DiagnosisOptions options;
  ProgressBar bar("diagnose", !a.no_progress);
  options.progress = [&bar](int done, int total) {
    bar.update(static_cast<double>(done) / total, std::to_string(done) + "/" + std::to_string(total) + " model fits");
  };
  const DiagnosisResult d = diagnose(in.robot, in.start, in.data, options);
  bar.done();
  const CandidateResult& g = d.geometric;
  const CandidateResult& b = d.best();
  std::printf("%s: %zu rows (%s split: %zu identify, %zu verify), %s, robot %s, thermal driver: %s\n",
              a.input.data.c_str(), in.file.rows.size(), a.input.split.c_str(), in.data.identification.size(),
              in.data.verification.size(), in.measurementText().c_str(),
              in.robot.name.c_str(), in.data.has_thermal ? in.data.thermal_source.c_str() : "none");
  std::printf("\n%-34s %6s %12s %12s %8s\n", "model (verification rows)", "params", "mean mm", "rms mm", "z");
  std::printf("%-34s %6s %12.4f %12.4f\n", "geometric", "-", g.verification.mean_mm, g.verification.rms_mm);
  for (const auto& c : d.candidates)
    std::printf("%-34s %6d %12.4f %12.4f %8.1f%s\n", causeLabel(c.fit.extension()).c_str(), c.fit.numEstimatedExtension(),
                c.verification.mean_mm, c.verification.rms_mm, c.z, &c == &b ? "   <- chosen" : "");
  std::printf("\nresidual structure before (adjusted R^2): %s\n", structureLine(d.structure_before, 4).c_str());
  if (d.chosen >= 0) std::printf("residual structure after:                  %s\n", structureLine(d.structure_after, 4).c_str());
  std::printf("\ncause: %s", d.chosen >= 0 ? causeLabel(b.fit.extension()).c_str() : "none");
  std::printf("  (verification mean %.4f -> %.4f mm, gain %.1f %%)\n", g.verification.mean_mm, b.verification.mean_mm,
              d.gain_pct);
  std::printf("unexplained: %.4f mm RMS beyond the expected noise of %.4f mm RMS (diagnosis %.2f s)\n",
              d.unexplained_rms_mm, d.noise_rms_mm, d.solve_time_s);
  // What the calibration engine takes (its topics carry no temperature: thermal drift stays with its drift model).
  std::vector<std::string> cell_extensions;
  bool thermal = false;
  if (d.chosen >= 0)
    for (const auto& e : b.fit.extensions) {
      if (e.cause == Cause::kThermalDrift) thermal = true;
      else cell_extensions.push_back(extensionSpec(e));
    }
  if (!cell_extensions.empty()) {
    std::string list;
    for (const auto& e : cell_extensions) list += (list.empty() ? "" : ", ") + e;
    std::printf("calibration engine: add `extensions: [%s]` to this robot in the cell file (RLS state with the extension)\n",
                list.c_str());
  }
  if (thermal)
    std::printf("calibration engine: thermal_drift is left to the engine's drift model (the cell's topics carry no "
                "temperature)\n");
  if (!a.json.empty()) {
    nlohmann::json cands = nlohmann::json::array();
    for (const auto& c : d.candidates)
      cands.push_back({{"cause", causeName(c.fit.extension().cause)}, {"joints", jointsJson(c.fit.extension())},
                       {"verify_mean_mm", c.verification.mean_mm}, {"verify_rms_mm", c.verification.rms_mm},
                       {"num_params", c.fit.numEstimatedExtension()}, {"params", paramsJson(c.fit)}, {"z", c.z},
                       {"score_m2", c.score}});
    nlohmann::json j = {{"data", a.input.data}, {"robot", in.robot.name}, {"rows", in.file.rows.size()},
                        {"split", a.input.split}, {"measurement", in.measurementJson()},
                        {"thermal_driver", in.data.has_thermal ? in.data.thermal_source : "none"},
                        {"cause", causeName(d.cause)}, {"joints", d.chosen >= 0 ? jointsJson(b.fit.extension()) : nlohmann::json::array()},
                        {"geometric", fitJson(g)}, {"extended", fitJson(b)}, {"gain_pct", d.gain_pct},
                        {"extension_params", d.chosen >= 0 ? paramsJson(b.fit) : nlohmann::json::object()},
                        {"extension_stddev", d.chosen >= 0 ? paramsJson(b.fit, true) : nlohmann::json::object()},
                        {"cell_extensions", cell_extensions}, {"candidates", cands}, {"structure_before", structureJson(d.structure_before)},
                        {"structure_after", structureJson(d.structure_after)}, {"noise_rms_mm", d.noise_rms_mm},
                        {"unexplained_rms_mm", d.unexplained_rms_mm}, {"diagnosis_time_s", d.solve_time_s}};
    std::ofstream o(a.json);
    if (!o) throw std::runtime_error(a.json + ": cannot write");
    o << j.dump(2) << "\n";
  }
  if (!a.report.empty()) {
    writeReport(a, in, d);
    std::printf("report: %s/report.md\n", a.report.c_str());
  }
  return 0;
}

}  // namespace

Runner addDiagnoseCommand(CLI::App& app) {
  auto a = std::make_shared<DiagnoseArgs>();
  CLI::App* cmd = app.add_subcommand(
      "diagnose",
      "What the geometric model gets wrong in a measurement file (CSV v1): fits it, measures the residual structure "
      "against each driver (joint angles, gravity torques, temperature or time, motion direction, workspace), tries "
      "each physical cause (joint_compliance, thermal_drift, cyclic_transmission, joint_scale, backlash) on each joint, "
      "and names the one that wins on the verification rows, or none. See docs/diagnosis.md");
  cmd->footer(cliFooter("  cellcal diagnose --robot config/robots/ur10.yaml --data a.csv --report report --json diag.json\n",
                        "  --report DIR: report.md, signature.svg and signature.png (gnuplot; docs/figures.md)\n"));
  addInputOptions(cmd, a->input);
  cmd->add_option("--json", a->json, "write the results as JSON");
  cmd->add_flag("--no-progress", a->no_progress, "no progress bar (it is drawn only when stderr is a terminal)");
  cmd->add_option("--report", a->report, "write report.md and the cause's signature (signature.svg, signature.png; gnuplot) into this directory");
  return [a, cmd]() -> int {
    if (!*cmd) return 0;
    return runDiagnose(*a);
  };
}

}  // namespace cellcal::cli
