// `cellcal calibrate --report DIR`: report.md and its figures for one set-up: the held-out rows' position errors
// before and after (a histogram), along each joint's angle and over the workspace (reach and height in the robot's
// base frame), and the parameters with their sigmas. The rows are the verification rows without their gross errors:
// the figures the text and --json give as "held-out".
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include "calibrate_report.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

// The held-out rows kept, with their errors before and after (mm), joints and place in the robot's base frame.
struct HeldOut {
  std::vector<double> before_mm, after_mm, reach_mm, height_mm;
  std::vector<Eigen::VectorXd> q_rad;
};

HeldOut heldOut(const CampaignInput& in, const CampaignReport& r) {
  const RobotModel& m = in.robot;
  const auto& rows = in.data.verification;
  const auto& drivers = in.data.verification_drivers;
  const std::vector<Eigen::Vector3d> before = positionResiduals(m, r.before, rows, drivers);
  const std::vector<Eigen::Vector3d> after = positionResiduals(m, r.after, rows, drivers);
  const auto b = r.after.params.segment<6>(m.baseParam(FrameParam::kX));
  const Pose base_inv = poseFromXyzRpy(b[0], b[1], b[2], b[3], b[4], b[5]).inverse();
  HeldOut h;
  for (size_t i = 0; i < rows.size(); ++i) {
    if (r.errors.verification_outliers.flagged(static_cast<int>(i))) continue;
    h.before_mm.push_back(before[i].norm() * 1e3);
    h.after_mm.push_back(after[i].norm() * 1e3);
    const Eigen::Vector3d p = base_inv * rows[i].measured_in_tracker.translation();
    h.reach_mm.push_back(p.head<2>().norm() * 1e3);
    h.height_mm.push_back(p.z() * 1e3);
    h.q_rad.push_back(rows[i].q_rad);
  }
  return h;
}

// SVG for the report, PNG for pages that take images only.
void render(const std::string& dir, const std::string& name, const std::string& data, const std::string& script) {
  std::string error;
  for (const char* format : {"svg", "png"})
    if (!renderGnuplot(dir, name, data, script, &error, format)) std::cerr << "warning: " << error << "\n";
}

// The errors before and after, binned alike (30 bins up to the largest).
void histogramFigure(const std::string& dir, const HeldOut& h) {
  std::ostringstream data, gp;
  data << "# before_mm after_mm\n";
  for (size_t i = 0; i < h.before_mm.size(); ++i) data << h.before_mm[i] << ' ' << h.after_mm[i] << '\n';
  const double top = std::max(*std::max_element(h.before_mm.begin(), h.before_mm.end()),
                              *std::max_element(h.after_mm.begin(), h.after_mm.end()));
  gp << "binwidth = " << std::max(top / 30, 1e-6) << "\nbin(x) = binwidth * floor(x / binwidth) + binwidth / 2\n"
     << "set title 'held-out rows: position error before and after the calibration'\nset grid\n"
     << "set xlabel 'position error (mm)'\nset ylabel 'rows'\nset style fill transparent solid 0.5 noborder\n"
     << "plot datafile using (bin($1)):(1.0) smooth freq with boxes lc rgb '#1f77b4' title 'before', \\\n"
     << "     datafile using (bin($2)):(1.0) smooth freq with boxes lc rgb '#d62728' title 'after'\n";
  render(dir, "histogram", data.str(), gp.str());
}

// The errors against each joint's angle: a panel per joint.
void jointsFigure(const std::string& dir, const RobotModel& m, const HeldOut& h) {
  const int n = m.numJoints(), cols = 3, rows = (n + cols - 1) / cols;
  std::ostringstream data, gp;
  data << "# before_mm after_mm q1_deg ... qN_deg\n";
  for (size_t i = 0; i < h.before_mm.size(); ++i) {
    data << h.before_mm[i] << ' ' << h.after_mm[i];
    for (int j = 0; j < n; ++j) data << ' ' << radToDeg(h.q_rad[i][j]);
    data << '\n';
  }
  gp << "set multiplot layout " << rows << "," << cols
     << " title 'held-out rows: position error along each joint (blue before, red after)'\nset grid\nset key off\n"
     << "set ylabel 'error (mm)'\n";
  for (int j = 0; j < n; ++j) {
    double lo = INFINITY, hi = -INFINITY;  // ticks at most five across the angles the rows visit
    for (const auto& q : h.q_rad) lo = std::min(lo, radToDeg(q[j])), hi = std::max(hi, radToDeg(q[j]));
    double step = 15;
    for (double s : {15.0, 30.0, 45.0, 90.0, 180.0})
      if ((step = s) * 5 >= hi - lo) break;
    gp << "set xtics " << step << "\nset xlabel 'joint " << j + 1 << " (deg)'\nplot datafile using " << j + 3
       << ":1 with points pt 7 ps 0.3 lc rgb '#1f77b4', datafile using " << j + 3
       << ":2 with points pt 7 ps 0.3 lc rgb '#d62728'\n";
  }
  gp << "unset multiplot\n";
  render(dir, "joints", data.str(), gp.str());
}

// The errors over the workspace: against the target's reach (distance from the base's z axis) and height.
void workspaceFigure(const std::string& dir, const HeldOut& h) {
  std::ostringstream data, gp;
  data << "# before_mm after_mm reach_mm height_mm\n";
  for (size_t i = 0; i < h.before_mm.size(); ++i)
    data << h.before_mm[i] << ' ' << h.after_mm[i] << ' ' << h.reach_mm[i] << ' ' << h.height_mm[i] << '\n';
  gp << "set multiplot layout 1,2 title 'held-out rows: position error over the workspace, in the robot base frame "
        "(blue before, red after)'\nset grid\nset key off\nset ylabel 'error (mm)'\n";
  for (const auto& [col, label] : {std::pair{3, "reach: distance from the base z axis (mm)"}, {4, "height (mm)"}})
    gp << "set xlabel '" << label << "'\nplot datafile using " << col
       << ":1 with points pt 7 ps 0.3 lc rgb '#1f77b4', datafile using " << col
       << ":2 with points pt 7 ps 0.3 lc rgb '#d62728'\n";
  gp << "unset multiplot\n";
  render(dir, "workspace", data.str(), gp.str());
}

void parameterTable(std::ostream& md, const CampaignInput& in, const CampaignReport& r) {
  const RobotModel& m = in.robot;
  char buf[256];
  md << "## Parameters\n\nEstimated ones (units in the names; 1σ from the fit's covariance at the readings' "
        "sigmas):\n\n| parameter | start | calibrated | change | 1σ |\n|---|---|---|---|---|\n";
  for (int i = 0; i < m.numParams(); ++i) {
    const double sd = r.after.paramStddev(i);
    if (std::isnan(sd)) continue;
    const double start = m.toHuman(i, in.start[i]), value = m.toHuman(i, r.after.params[i]);
    std::snprintf(buf, sizeof buf, "| %s | %.4f | %.4f | %+.4f | %.4f |\n", m.paramNameHuman(i).c_str(), start, value,
                  value - start, std::abs(m.toHuman(i, sd)));
    md << buf;
  }
  for (int k : r.after.estimated_extension) {
    std::snprintf(buf, sizeof buf, "| %s | 0 | %.6g | %+.6g | %.2g |\n", r.after.extension_names[k].c_str(),
                  r.after.extension_params[k], r.after.extension_params[k], r.after.extensionStddev(k));
    md << buf;
  }
  md << "\n";
}

}  // namespace

void writeCalibrationReport(const std::string& dir, const CalibrateArgs& a, const CampaignProblem& p,
                            const CampaignReport& r) {
  if (r.several_setups) throw ConfigError("--report takes one set-up (a usage error, exit 2)");
  namespace fs = std::filesystem;
  fs::create_directories(dir);
  std::ofstream md(dir + "/report.md");
  if (!md) throw std::runtime_error(dir + "/report.md: cannot write");
  const CampaignInput& in = p.setups.front();
  const HeldOut h = heldOut(in, r);
  if (h.after_mm.empty()) throw std::runtime_error("--report: no held-out row is left to show");
  char buf[512];
  md << "# cellcal calibrate: " << in.robot.name << "\n\nData: `" << a.input.data << "`, " << in.file.rows.size()
     << " rows (" << a.input.split << " split: " << in.data.identification.size() << " identify, "
     << in.data.verification.size() << " verify), " << in.measurementText() << ". Model: " << r.model_label << ".\n\n"
     << recommendationText(r) << "\n\n## Held-out error\n\nThe " << h.after_mm.size()
     << " verification rows without their gross errors: the model was not fitted on them. Position error (mm):\n\n"
     << "| | mean | RMS | 99.7 % | max |\n|---|---|---|---|---|\n";
  // The campaign's own figures of these rows (the text's and --json's "without gross errors").
  for (const auto& [label, s] : {std::pair{"before", &r.errors.verification_kept_before},
                                 {"after", &r.errors.verification_kept_after}}) {
    std::snprintf(buf, sizeof buf, "| %s | %.4f | %.4f | %.4f | %.4f |\n", label, s->mean_mm, s->rms_mm, s->p997_mm,
                  s->max_mm);
    md << buf;
  }
  md << "\n![histogram](histogram.svg)\n\n## Along each joint\n\nWhat depends on a joint's angle (a cyclic error, a "
        "scale, a stiffness) shows as a pattern in its panel after the calibration.\n\n![joints](joints.svg)\n\n"
        "## Over the workspace\n\nWhat grows with reach or height (a sag, a tracker's scale) shows as a slope.\n\n"
        "![workspace](workspace.svg)\n\n";
  parameterTable(md, in, r);
  histogramFigure(dir, h);
  jointsFigure(dir, in.robot, h);
  workspaceFigure(dir, h);
}

}  // namespace cellcal::cli
