// What `calibrate` and `diagnose` share: reading a measurement file, splitting it, the drivers of each row and the
// registered start model.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cellcal/core/campaign/campaign_input.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/model_error.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal::cli {

struct InputArgs {
  std::string robot, data, split = "alternate";
  std::vector<std::string> more_data;  // --data given again: further set-ups (only `calibrate` takes them)
  std::vector<std::string> data_files; // every --data, in order (what the option fills)
  double sigma_position_mm = 0.025, sigma_orientation_deg = 0.01;
  double outlier_threshold = OutlierOptions{}.threshold;  // robust sigmas; 0: no screening
  bool position_only = false, skip_bad_rows = false, no_register = false, one_setup = false;
  // A kinematic parameter is estimated only where the data pin it better than this (identifiability.hpp); 0: rank only.
  double plausible_length_mm = kPlausibleLengthM * 1e3, plausible_angle_deg = kPlausibleAngleRad * 180 / kPi;
};

// The identifiability options' plausible ranges from --plausible-length-mm / --plausible-angle-deg (empty: both 0).
Eigen::VectorXd plausibleRanges(const InputArgs& a, const RobotModel& robot);

// The CLI's name for a prepared set-up (campaign_input.hpp).
using LoadedInput = CampaignInput;
// {position_mm, orientation_deg} of the model error added to the rows' sigmas; null when none was added.
nlohmann::json modelErrorJson(const CampaignInput& in);

// --split, --sigma-*, --position-only, --no-register, --outlier-threshold as the core's options.
InputOptions inputOptions(const InputArgs& a);

// --outlier-threshold as options (0: screening off); throws std::runtime_error on a bad value.
OutlierOptions outlierOptions(const InputArgs& a);

// Reads and prepares (prepareCampaignInput: split, registration, the rows' sigmas). Prints skipped rows and ignored columns to stderr. Throws std::runtime_error with the file name on bad input.
LoadedInput loadInput(const InputArgs& a);
// What the set-up search found in the file a set-up came from (findSetupChanges), in one sentence; "" when nothing.
std::string foundSetupsText(const CampaignInput& in);
// One change found: {line, probability, move_mm}.
nlohmann::json foundChangeJson(const FoundSetupChange& f);
// Every set-up of every --data file (a file with a setup column gives one per label, in order of appearance), each
// split and registered on its own as loadInput does. A file whose rows name set-ups must name one on every row.
std::vector<LoadedInput> loadSetups(const InputArgs& a);

// "backlash:3,joint_compliance:2" or "thermal_drift" (lengths only) -> extensions; joints 1-based. Throws
// std::runtime_error naming the item that is not a cause or does not apply to the robot.
std::vector<Extension> parseModel(const std::string& spec, const RobotModel& robot);

// Flagged rows as file lines: "lines 17, 233 and 301" (at most `most` listed, then "and N more").
std::string linesText(const std::vector<int>& rows, const std::vector<int>& lines, size_t most = 12);
nlohmann::json outliersJson(const OutlierScreen& s, const std::vector<int>& lines);

// Parameters held for an excitation deficit: [{name, identification_rms, elsewhere_max}].
nlohmann::json heldJson(const std::vector<ExcitationDeficit>& held);

// {"<prefix>mean_mm", "<prefix>rms_mm", "<prefix>max_mm"} and, with 6D rows, the same in _deg.
nlohmann::json errorStatsJson(const ErrorStats& s, const std::string& prefix = "");

// --robot FILE, or --config CELL (with --robot-id ID when it has several robots): what robotOrCellRobot takes.
void addRobotOrCellOptions(CLI::App& cmd, std::string& robot, std::string& config, std::string& robot_id,
                           const std::string& robot_help);

// The numbers of an option's comma-separated value ("500,0,400"): exactly `count` finite numbers, else ConfigError
// naming the option and what it expects (e.g. "X,Y,Z in mm").
std::vector<double> parseNumbers(const std::string& text, size_t count, const std::string& option,
                                 const std::string& expected);
// A frame given as X,Y,Z,ROLL,PITCH,YAW in mm and deg (parseNumbers' errors, naming `option`).
Pose parseFrameMmDeg(const std::string& text, const std::string& option);

// The robot file of --robot, or of robot `robot_id` of the cell file `config` with that cell's registration (its
// base_in_tracker and tool_in_flange: the frames a tracker user sets up before an acceptance test); robot_id may be
// empty when the cell has one robot. *label names where it came from. Throws ConfigError when neither or both are
// given, or the cell has no such robot.
RobotFile robotOrCellRobot(const std::string& robot, const std::string& config, const std::string& robot_id,
                           std::string* label);

// SHA-256 of a file, hex; throws std::runtime_error naming the file when it cannot be read.
std::string fileSha256(const std::string& path);
// Now as 2026-11-28T21:50:07Z.
std::string utcNow();

// Adds --robot --data --split --sigma-* --position-only --skip-bad-rows --no-register to a subcommand.
void addInputOptions(CLI::App* cmd, InputArgs& a);

}  // namespace cellcal::cli
