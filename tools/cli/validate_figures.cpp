// `cellcal validate --figures` (validate_figures.hpp).
#include "validate_figures.hpp"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <map>
#include <set>
#include <sstream>

#include "commands.hpp"

namespace cellcal::cli {

using namespace cellcal::components;

// Figures of one robot's calibrations over a recording (gnuplot, PNG): <robot>_accuracy.png, the a-priori
// verification error (each pose predicted by the calibration before it) and the a-posteriori residual against the
// cell time of the reading (stamps times the cell file's time_compression: a simulated cell's hours, not the seconds
// it ran); <robot>_joint_drift.png, each joint's zero offset as identified, minus its nominal value, for the joints
// whose zero the calibrations estimate (the others are held: named in the title, not drawn as flat lines). A version
// without a reading of its own (v1 of an engine started from a calibration file) has no time and is not drawn.
void writeRecordingFigures(const std::string& dir, const std::string& robot, const RobotModel& model,
                           const std::vector<ReceivedCalibration>& all, double time_compression) {
  std::vector<const ReceivedCalibration*> versions;
  for (const auto& v : all)
    if (v.last_measurement_stamp_ns > 0) versions.push_back(&v);
  if (versions.empty()) return;
  const double t0 = static_cast<double>(versions.front()->last_measurement_stamp_ns);
  std::vector<int> drawn, held;  // joints whose zero offset is estimated (in the last version), the others
  for (int j = 0; j < model.numJoints(); ++j) {
    const int i = model.jointParam(j, JointParam::kThetaOffset);
    const auto& est = versions.back()->estimated;
    (est.empty() || std::count(est.begin(), est.end(), i) ? drawn : held).push_back(j);
  }
  std::ostringstream acc, drift, drift_gp;
  acc << std::setprecision(10) << "t_h verification_mm residual_mm\n";
  drift << std::setprecision(10) << "t_h";
  for (int j : drawn) drift << " joint" << j + 1;
  drift << "\n";
  // A pause (no calibration for 20 times the median interval: the robot worked, the cell was off) breaks the lines:
  // gnuplot starts a new segment after a blank line, instead of drawing across hours without data.
  std::vector<double> gaps;
  for (size_t k = 1; k < versions.size(); ++k)
    gaps.push_back(static_cast<double>(versions[k]->last_measurement_stamp_ns - versions[k - 1]->last_measurement_stamp_ns));
  double pause_ns = std::numeric_limits<double>::infinity();
  if (!gaps.empty()) {
    std::vector<double> sorted = gaps;
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
    if (sorted[sorted.size() / 2] > 0) pause_ns = 20 * sorted[sorted.size() / 2];
  }
  for (size_t k = 0; k < versions.size(); ++k) {
    const auto& v = *versions[k];
    if (k > 0 && gaps[k - 1] > pause_ns) {
      acc << '\n';
      drift << '\n';
    }
    const double t_h = (static_cast<double>(v.last_measurement_stamp_ns) - t0) * time_compression / 3.6e12;
    auto num = [](double x) {
      std::ostringstream o;
      o << std::setprecision(10) << x;
      return std::isfinite(x) ? o.str() : std::string("NaN");
    };
    acc << t_h << ' ' << num(v.verification_mean_position_m * 1e3) << ' ' << num(v.residual_rms_position_m * 1e3) << '\n';
    drift << t_h;
    for (int j : drawn) {
      const int i = model.jointParam(j, JointParam::kThetaOffset);
      drift << ' ' << num((v.params[i] - model.nominal[i]) * 180.0 / kPi * 1e3);
    }
    drift << '\n';
  }
  std::string error;
  const std::string time_label = time_compression == 1.0
                                     ? "time of the reading (h since the first calibration)"
                                     : "cell time of the reading (h since the first calibration; x" +
                                           [&] {
                                             std::ostringstream o;
                                             o << time_compression;
                                             return o.str();
                                           }() + " the wall clock)";
  const std::string acc_gp =
      "set title '" + robot + ": accuracy over the recording (" + std::to_string(versions.size()) +
      " calibrations)'\nset xlabel '" + time_label + "'\n"
      "set ylabel 'position error (mm)'\nset logscale y\nset grid\nset key top right\n"
      "plot datafile using 1:($2 > 1e-3 ? $2 : 1/0) skip 1 with lines lw 2 title 'a-priori: each pose predicted before it was used', "
      "datafile using 1:($3 > 1e-3 ? $3 : 1/0) skip 1 with lines lw 1 title 'a-posteriori residual (recent poses)'\n";
  if (!renderGnuplot(dir, robot + "_accuracy", acc.str(), acc_gp, &error)) std::cerr << "warning: " << error << "\n";
  std::string held_text;
  for (int j : held) held_text += (held_text.empty() ? "" : ", ") + std::to_string(j + 1);
  drift_gp << "set title '" << robot << ": identified joint zero offsets over the recording"
           << (held.empty() ? "" : " (joint" + std::string(held.size() > 1 ? "s " : " ") + held_text +
                                       ": not identifiable here, held)")
           << "'\nset xlabel '" << time_label << "'\n"
           << "set ylabel 'zero offset - nominal (millidegrees)'\nset grid\nset key outside right\n";
  if (!drawn.empty()) {
    drift_gp << "plot ";
    for (size_t c = 0; c < drawn.size(); ++c)
      drift_gp << (c ? ", " : "") << "datafile using 1:" << c + 2 << " skip 1 with lines lw 2 title 'joint " << drawn[c] + 1 << "'";
    drift_gp << "\n";
    if (!renderGnuplot(dir, robot + "_joint_drift", drift.str(), drift_gp.str(), &error))
      std::cerr << "warning: " << error << "\n";
  }
}

}  // namespace cellcal::cli
