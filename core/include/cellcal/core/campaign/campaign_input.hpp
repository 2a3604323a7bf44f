// A campaign's rows as calibration takes them: one set-up of a measurement file split into identification and
// verification rows with their drivers, its frames registered, its rows' sigmas completed. What `calibrate`,
// `diagnose` and a program that links cellcal::core share (campaign.hpp calibrates them).
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/model_error.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

// How a file's rows become a campaign's (SI; the CLI's --split, --sigma-*, --position-only, --no-register).
struct InputOptions {
  // 'alternate': even rows (0-based) identify, odd rows verify; 'halves': the first half identifies; 'positions':
  // rows within kPositionRadiusMm of a position's first row form that position, alternate positions identify (no
  // verification row has an identification row that near).
  std::string split = "alternate";
  double sigma_position_m = 25e-6, sigma_orientation_rad = 0.01 * kPi / 180;  // a row without its own sigmas
  bool position_only = false;                 // positions only, even where orientations are given
  bool register_frames = true;                // false: trust the robot file's base and tool frames as the start
  OutlierOptions outliers;                    // the geometric fit beneath the model error component
  // A file without a setup column is searched for set-up changes (findSetupChanges); false: its rows are one set-up.
  bool find_setup_changes = true;
  bool IsValid(std::string* why) const;
};

constexpr double kPositionRadiusMm = 20.0;

// A set-up change found in a file's rows from their structure (setup_change.hpp): the tracker or the target moved
// between two rows, and no setup column says so.
struct FoundSetupChange {
  int first_row = -1;       // index into the file's rows: the first row of the new set-up
  int line = -1;            // its file line
  double probability = 1;   // that rows of one set-up give a split as clear (the scan's law)
  double move_mm = 0;       // how far the new set-up's frames move the target, RMS over its rows
  // A change no registration of both sides fits (RMS above 5 mm): one registration's RMS, then each side's (mm);
  // empty when the scan found it.
  std::vector<double> registration_rms_mm;
};

struct CampaignInput {
  std::string name;  // the file, with " [setup <label>]" for one set-up of a file with a setup column ("[lines a-b]"
                     // for a block of one whose set-ups were found)
  std::string path;  // the file
  std::string split;  // the rule its rows were split by (InputOptions::split)
  RobotModel robot;
  std::optional<RobotCalibration> calibration;  // the robot file's calibration section (a calibrated robot file)
  std::vector<std::pair<std::string, std::string>> source;  // the robot file's source (a URDF's), kept when saved
  MeasurementFile file;
  MeasurementKind kind = MeasurementKind::kPose6D;  // kPosition3D when no row used has an orientation
  int oriented_rows = 0, position_rows = 0;          // rows used as 6D poses / as points
  std::string measurementText() const;               // "6D", "position only", "mixed: 30 6D, 12 position-only rows"
  std::string measurementName() const;               // "pose6d", "position3d", "mixed"
  DiagnosisData data;        // identification / verification rows with their drivers (computed in visiting order)
  std::vector<int> identification_lines, verification_lines;  // the file line of each of those rows
  Eigen::VectorXd start;     // nominal kinematics with registered base and tool frames (or the file's)
  double registration_rms_mm = 0;  // NaN without registration
  // What the registration could not take from the rows, in words (empty: nothing): positions on a line leave the
  // base's turn about it open.
  std::string registration_note;
  // When one registration cannot fit the file (RMS above kSetupHintRmsMm) and its rows split into two set-ups that
  // each register: where they change and what each side leaves (empty otherwise).
  std::string setup_hint;
  int setup_change_line = -1;         // file line of the first row of the second set-up
  // When the set-up is a block of a file whose rows were found to be several set-ups (findSetupChanges): every change
  // found in that file, and the block's number (1-based; 0: not such a block).
  std::vector<FoundSetupChange> found_changes;
  int found_block = 0;
  double registration_s = 0;
  // Rows with the tracker's own sigmas (sigma_position_mm / sigma_orientation_deg columns): the error a geometric
  // fit leaves beyond them (model_error.hpp), added to every row's sigmas before any fit; zero without such rows.
  // Set-ups beside one with own sigmas get theirs too (model_error_added), so that they weigh alike.
  bool own_sigmas = false, model_error_added = false;
  ModelErrorSigma model_error;
  std::string modelErrorText() const;  // "" when none was added
};

// A file's rows per set-up label, in order of first appearance (one group, unlabelled, when it has no setup column).
std::vector<std::pair<std::string, MeasurementFile>> splitBySetup(const MeasurementFile& file);

// The set-up changes in a file's rows without a setup column, in row order: the rows calibrated as one set-up
// (registered, then a geometric fit of every row) and scanned (scanSetupChange, with the rows' stamps as the drift's
// clock and their temperatures as a drift's shape when every row has them); rows one registration cannot fit (RMS
// above 5 mm) are split where each side registers best (findSetupChange). Where a change is found, each side is
// searched again, up to kMaxFoundSetups set-ups. Empty when the rows are too few (40), the fit does not converge, or
// nothing is found.
constexpr int kMaxFoundSetups = 8;
std::vector<FoundSetupChange> findSetupChanges(const RobotModel& robot, const MeasurementFile& file,
                                               const InputOptions& options);

// Block b (0 .. found.size()) of a file's rows, between the changes found in it, and the name it goes by:
// "<path> [lines a-b]".
MeasurementFile foundSetupBlock(const MeasurementFile& file, const std::vector<FoundSetupChange>& found, size_t b);
std::string foundSetupBlockName(const std::string& path, const MeasurementFile& block);

// Splits, registers and checks the rows of one set-up; `name` (the file, and its set-up label) in messages. Throws
// ConfigError naming it when the split leaves fewer than 8 rows to identify or none to verify.
CampaignInput prepareCampaignInput(const std::string& name, RobotFile robot, MeasurementFile rows,
                                   const InputOptions& options);

// Every set-up of one file (a file with a setup column gives one per label, in order of appearance; one without, one
// per block between the set-up changes found in it when options.find_setup_changes), each prepared on its own;
// `path` names the file. A file whose rows name set-ups must name one on every row (ConfigError, its line).
std::vector<CampaignInput> prepareCampaignSetups(const std::string& path, const RobotFile& robot,
                                                 const MeasurementFile& file, const InputOptions& options);

// Set-ups weigh against each other by their sigmas: when one carries the tracker's own (and so the model error beside
// them), the others get their model error too.
void weighSetupsAlike(std::vector<CampaignInput>* setups, const InputOptions& options);

}  // namespace cellcal
