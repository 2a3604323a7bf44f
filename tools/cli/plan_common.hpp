// What the `cellcal plan` subcommands share (cmd_plan.cpp: iso9283 and poses; cmd_plan_cover.cpp: cover): the
// program files they write and the tracker's place and sight they take from the options.
#pragma once
#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/identification/pose_plan.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "commands.hpp"

namespace cellcal::cli {

// A robot program (CSV v1's joint columns in radians to the last digit, pose, and cycle when given), written whole.
struct ProgramRow {
  const Eigen::VectorXd* q;
  std::string pose;
  int cycle = 0;  // 0: no cycle column
};
// `comment`'s lines first as '#' lines. Throws std::runtime_error naming the path when it cannot be written.
void writeProgram(const std::string& path, const std::string& comment, int joints, const std::vector<ProgramRow>& rows);

// Where the tracker stands and what it can see (--tracker-mm, --range-mm, --link-radius-mm, --acceptance-deg): the
// tracker frame's origin of the model's registration unless --tracker-mm places it; none when neither is known.
struct TrackerArgs {
  std::string tracker_mm, range_mm;
  double link_radius_mm = 60, acceptance_deg = 0;
};
void addTrackerOptions(CLI::App& cmd, TrackerArgs& a);
// *from says where the place came from. Throws ConfigError on a bad value, or a range or acceptance angle given
// where the tracker's place is not known.
std::optional<TrackerSetup> trackerSetup(const RobotModel& m, const TrackerArgs& a, std::string* from);

// `cellcal plan cover` on the `plan` command (cmd_plan_cover.cpp).
Runner addPlanCoverCommand(CLI::App& plan);

}  // namespace cellcal::cli
