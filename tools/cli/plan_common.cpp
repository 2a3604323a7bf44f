// Program files and the tracker's options of the `cellcal plan` subcommands (plan_common.hpp).
#include "plan_common.hpp"

#include <fstream>
#include <sstream>

#include "cellcal/core/identification/registration.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {

void writeProgram(const std::string& path, const std::string& comment, int joints, const std::vector<ProgramRow>& rows) {
  std::ostringstream csv;
  std::istringstream lines(comment);
  for (std::string line; std::getline(lines, line);) csv << "# " << line << "\n";
  for (int j = 1; j <= joints; ++j) csv << "q" << j << "_rad,";
  const bool cycles = !rows.empty() && rows.front().cycle > 0;
  csv << (cycles ? "pose,cycle\n" : "pose\n");
  csv.precision(17);
  for (const auto& r : rows) {
    for (int j = 0; j < joints; ++j) csv << (*r.q)[j] << ",";
    csv << r.pose;
    if (cycles) csv << "," << r.cycle;
    csv << "\n";
  }
  std::ofstream out(path);
  if (!out || !(out << csv.str()) || !out.flush()) throw std::runtime_error(path + ": cannot write");
}

void addTrackerOptions(CLI::App& cmd, TrackerArgs& a) {
  cmd.add_option("--tracker-mm", a.tracker_mm,
                 "the tracker's position X,Y,Z in the robot's base frame (default: the tracker frame's origin, when the "
                 "robot file or cell has a registration)");
  cmd.add_option("--range-mm", a.range_mm, "the tracker's range MIN,MAX (default: 0, unlimited)");
  cmd.add_option("--link-radius-mm", a.link_radius_mm, "the beam keeps this far from every link but the last two")
      ->check(nonNegative())
      ->capture_default_str();
  cmd.add_option("--acceptance-deg", a.acceptance_deg,
                 "the target's z axis within this of the direction to the tracker (0: not checked)")
      ->check(nonNegative())
      ->capture_default_str();
}
std::optional<TrackerSetup> trackerSetup(const RobotModel& m, const TrackerArgs& a, std::string* from) {
  const Eigen::Matrix<double, 6, 1> b = m.nominal.segment<6>(m.baseParam(FrameParam::kX));
  if (a.tracker_mm.empty() && b.isZero(0.0)) {
    if (!a.range_mm.empty() || a.acceptance_deg > 0)
      throw ConfigError("--range-mm / --acceptance-deg: the tracker's place is not known: give --tracker-mm, or a robot "
                        "file or cell with its registration");
    return std::nullopt;
  }
  TrackerSetup t;
  if (!a.tracker_mm.empty()) {
    const auto v = parseNumbers(a.tracker_mm, 3, "--tracker-mm", "X,Y,Z in mm");
    t.position_in_base_m = Eigen::Vector3d(v[0], v[1], v[2]) * 1e-3;
    *from = "--tracker-mm";
  } else {
    t.position_in_base_m = poseFromXyzRpy(b[0], b[1], b[2], b[3], b[4], b[5]).inverse().translation();
    *from = "the registration's tracker frame origin";
  }
  if (!a.range_mm.empty()) {
    const auto r = parseNumbers(a.range_mm, 2, "--range-mm", "MIN,MAX in mm");
    if (!(r[0] >= 0 && r[1] > r[0])) throw ConfigError("--range-mm " + a.range_mm + ": expected 0 <= MIN < MAX");
    t.min_range_m = r[0] * 1e-3;
    t.max_range_m = r[1] * 1e-3;
  }
  t.link_radius_m = a.link_radius_mm * 1e-3;
  t.acceptance_rad = degToRad(a.acceptance_deg);
  return t;
}

}  // namespace cellcal::cli
