// `cellcal diagnose --report`: report.md and the cause's signature figure.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "commands.hpp"
#include "diagnosis_output.hpp"

namespace cellcal::cli {

void writeDiagnosisReport(const std::string& dir, const InputArgs& input, const LoadedInput& in, const DiagnosisResult& d) {
  namespace fs = std::filesystem;
  fs::create_directories(dir);
  std::ofstream md(dir + "/report.md");
  if (!md) throw std::runtime_error(dir + "/report.md: cannot write");
  const CandidateResult& g = d.geometric;
  const CandidateResult& b = d.best();
  char buf[512];
  md << "# cellcal diagnose: " << in.robot.name << "\n\n";
  md << "Data: `" << input.data << "`, " << in.file.rows.size() << " rows (" << input.split << " split: "
     << in.data.identification.size() << " identify, " << in.data.verification.size() << " verify), "
     << in.measurementText() << ". Thermal driver: "
     << (in.data.has_thermal ? in.data.thermal_source : std::string("none")) << ".\n\n";
  md << "## Finding\n\n**" << describeVerdict(d) << "**\n\n";
  if (d.selection.empty()) {
    md << "No cause in the library explains the verification residual better than the geometric model.\n\n";
  } else {
    std::snprintf(buf, sizeof buf,
                  "**%s**: verification mean position error %.4f -> %.4f mm (gain %.1f %%), RMS %.4f -> %.4f mm; "
                  "%.1f standard errors better than the geometric model on the verification rows.\n\n",
                  modelLabel(b.fit.extensions).c_str(), g.verification.mean_mm, b.verification.mean_mm, d.gain_pct,
                  g.verification.rms_mm, b.verification.rms_mm, d.selection.front().z);
    md << buf;
    if (d.selection.size() > 1) {
      md << "Causes in the order forward selection added them:\n\n";
      for (const auto& st : d.selection) {
        std::snprintf(buf, sizeof buf, "- %s: verification mean %.4f mm (gain %.1f %%, z %.1f)\n",
                      extensionLabel(st.added).c_str(), st.result.verification.mean_mm, st.gain_pct, st.z);
        md << buf;
      }
      md << "\n";
    }
  }
  if (const std::string r = regionCheckText(d); !r.empty())
    md << "Beyond the rows fitted (docs/diagnosis.md, \"Regions the fit never saw\"):\n\n```\n" << r << "```\n\n";
  if (const std::string r = driftCheckText(d); !r.empty())
    md << "A drift or the frame (docs/diagnosis.md, \"A drift or the frame\"):\n\n```\n" << r << "```\n\n";
  if (d.noise.from_repeats)
    std::snprintf(buf, sizeof buf,
                  "Still unexplained: %.4f mm RMS beyond the reading noise (%.4f mm RMS, estimated from the %s).\n\n",
                  d.unexplained_rms_mm, d.noise_rms_mm, d.noise.source.c_str());
  else
    std::snprintf(buf, sizeof buf,
                  "The reading noise is not measured (no pose measured twice): the %s leaves %.4f mm RMS, the readings' "
                  "noise and what the model misses together.\n\n",
                  d.noise.source.c_str(), d.noise_rms_mm);
  md << buf;
  if (!d.identification_outliers.rows.empty() || !d.verification_outliers.rows.empty())
    md << "Gross errors left out: identification " << d.identification_outliers.rows.size() << " rows, verification "
       << d.verification_outliers.rows.size() << " rows (more than " << OutlierOptions{}.threshold
       << " robust sigmas; listed by `cellcal diagnose`).\n\n";
  md << "## Residual structure (verification rows)\n\nShare of the position residual's variance each driver explains "
        "beyond what the model's own parameters could (partial R^2; * = beyond noise, F-test, family-wise 0.1 %).\n\n"
        "| driver | geometric | "
     << (d.selection.empty() ? "-" : "final") << " |\n|---|---|---|\n";
  for (const auto& s : d.structure_before) {
    const DriverStructure* after = nullptr;
    for (const auto& t : d.structure_after)
      if (t.driver == s.driver) after = &t;
    std::snprintf(buf, sizeof buf, "| %s | %.1f %%%s | %.1f %%%s |\n", s.driver.c_str(), 100 * s.share,
                  s.significant ? " *" : "", after ? 100 * after->share : 0.0, after && after->significant ? " *" : "");
    md << buf;
  }
  md << "\n## Candidates (best score first)\n\n| cause | parameters | verify mean mm | verify RMS mm | z |\n"
        "|---|---|---|---|---|\n";
  std::snprintf(buf, sizeof buf, "| geometric | 0 | %.4f | %.4f | |\n", g.verification.mean_mm, g.verification.rms_mm);
  md << buf;
  for (const auto& c : d.candidates) {
    std::snprintf(buf, sizeof buf, "| %s | %d | %.4f | %.4f | %.1f |\n", extensionLabel(c.fit.extensions.back()).c_str(),
                  c.fit.numEstimatedExtension(), c.verification.mean_mm, c.verification.rms_mm, c.z);
    md << buf;
  }
  if (!d.selection.empty()) {
    const CauseSignature sig = causeSignature(in.robot, g.fit, b.fit, in.data.verification,
                                              in.data.verification_drivers, in.data.thermal_source);
    // Rendered by gnuplot (SVG): two panels sharing the axes, the residual before and after the extension.
    std::ostringstream data, gp;
    data << "x before after\n";
    double lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < sig.x.size(); ++i) {
      data << std::setprecision(10) << sig.x[i] << ' ' << sig.y_before[i] << ' ' << sig.y_after[i] << '\n';
      lo = std::min({lo, sig.y_before[i], sig.y_after[i]});
      hi = std::max({hi, sig.y_before[i], sig.y_after[i]});
    }
    const double pad = 0.05 * std::max(hi - lo, 1e-12);
    // The extended model's name (up to three causes) spans the figure above both panels: a panel's half width cut it.
    gp << "set multiplot layout 1,2 title 'verification rows: geometric model (left), with " << modelLabel(b.fit.extensions)
       << " (right)' font ',11'\nset grid\nset key off\nset xlabel '" << sig.x_label << "'\nset ylabel '"
       << sig.y_label << "'\nset yrange [" << lo - pad << ":" << hi + pad << "]\n"
       << "set title 'geometric model'\nplot datafile using 1:2 skip 1 with points pt 7 ps 0.4 lc rgb '#1f77b4'\n"
       << "set title 'extended model'\nplot datafile using 1:3 skip 1 with points pt 7 ps 0.4 lc rgb '#d62728'\n"
          "unset multiplot\n";
    std::string plot_error;
    for (const char* format : {"svg", "png"})  // SVG for the report, PNG for pages that take images only
      if (!renderGnuplot(dir, "signature", data.str(), gp.str(), &plot_error, format))
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

}  // namespace cellcal::cli
