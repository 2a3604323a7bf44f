// `cellcal import`: `import ipa` (a series of the ipa UR10 dataset to CSV v1) and `import csv` (a measurement file,
// CSV v1, as a recording of the cell's input topics).
#include <cstdio>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>

#include "cellcal/components/convert.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/lab/ipa_dataset.hpp"
#include "cellcal/recording/recording.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

// `import csv`: a measurement file (CSV v1) as a recording: per row, the robot settled bracket_s before and after
// the reading (two JointStates) and the TrackerPose at the row's time.
struct ImportCsvArgs {
  std::string csv, robot_file, out, robot_id, target_id;
  double start_unix_s = 1.7e9;  // stamp_s = 0 (or the first row) at this Unix time
  double period_s = 30;         // rows without stamp_s: this far apart
  double bracket_s = 0.01;
  double sigma_position_mm = 0.025, sigma_orientation_deg = 0.01;
  bool skip_bad_rows = false;
};


using namespace cellcal::components;
using namespace cellcal::recording;

int importCsvToRecording(const ImportCsvArgs& a) {
  const RobotModel model = loadRobotModel(a.robot_file);
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = a.skip_bad_rows;
  const MeasurementFile f = readMeasurementCsv(a.csv, model, mo);
  if (f.rows.empty()) throw std::runtime_error(a.csv + ": no rows");
  if (!(a.period_s > 0)) throw std::runtime_error("--period-s must be > 0");
  const std::string robot_id = a.robot_id.empty() ? model.name : a.robot_id;
  const std::string target_id = a.target_id.empty() ? robot_id + "_target" : a.target_id;
  const bool stamped = std::all_of(f.rows.begin(), f.rows.end(), [](const auto& r) { return r.stamp_s.has_value(); });
  const std::int64_t start_ns = static_cast<std::int64_t>(std::llround(a.start_unix_s * 1e9));
  const std::int64_t bracket_ns = static_cast<std::int64_t>(std::llround(a.bracket_s * 1e9));
  RecordingWriter rec(a.out);
  std::map<std::string, std::string> md = {{"imported_from", a.csv}};
  rec.channel(TopicOf<msg::JointState>::name, md);
  rec.channel(TopicOf<msg::TrackerPose>::name, md);
  std::uint32_t joint_seq = 0, tracker_seq = 0;
  std::int64_t previous_ns = INT64_MIN;
  const double first_s = stamped ? *f.rows.front().stamp_s : 0.0;
  for (size_t k = 0; k < f.rows.size(); ++k) {
    const MeasurementRow& row = f.rows[k];
    const double rel_s = stamped ? *row.stamp_s - first_s : static_cast<double>(k) * a.period_s;
    const std::int64_t t = start_ns + static_cast<std::int64_t>(std::llround(rel_s * 1e9));
    if (previous_ns != INT64_MIN && t - previous_ns <= 2 * bracket_ns)
      throw std::runtime_error(a.csv + ":" + std::to_string(row.line) + ": the row is at " + std::to_string(rel_s) +
                               " s, not more than " + std::to_string(2 * a.bracket_s) +
                               " s after the previous row (the robot stands still around each reading)");
    previous_ns = t;
    // The robot stands still from bracket_s before the reading to bracket_s after it (two settled joint states).
    const Observation obs = toObservation(row, row.orientation ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D,
                                          a.sigma_position_mm * 1e-3, a.sigma_orientation_deg * kPi / 180);
    auto before = toJointState(robot_id, t - bracket_ns, ++joint_seq, row.q_rad, true);
    rec.write(before, static_cast<std::uint64_t>(t - bracket_ns), static_cast<std::uint64_t>(t - bracket_ns), joint_seq);
    auto reading = toTrackerPose(target_id, t, ++tracker_seq, obs);
    rec.write(reading, static_cast<std::uint64_t>(t), static_cast<std::uint64_t>(t), tracker_seq);
    auto after = toJointState(robot_id, t + bracket_ns, ++joint_seq, row.q_rad, true);
    rec.write(after, static_cast<std::uint64_t>(t + bracket_ns), static_cast<std::uint64_t>(t + bracket_ns), joint_seq);
  }
  rec.file().close();
  std::printf("import csv: %zu rows of %s (robot %s, target %s) -> %s: %u JointState + %u TrackerPose messages, "
              "%s, stamp_s 0 at Unix time %.3f s\n",
              f.rows.size(), a.csv.c_str(), robot_id.c_str(), target_id.c_str(), a.out.c_str(), joint_seq, tracker_seq,
              stamped ? "stamps from stamp_s" : ("rows " + std::to_string(a.period_s) + " s apart").c_str(), a.start_unix_s);
  if (f.skipped_rows) std::printf("import csv: %d bad rows skipped\n", f.skipped_rows);
  return 0;
}

}  // namespace

Runner addImportCommand(CLI::App& app) {
  auto robot = std::make_shared<std::string>(defaultRobotFile("ur10.yaml"));
  auto in = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  CLI::App* imp = app.add_subcommand("import", "Convert measurements: other formats to CSV v1, CSV v1 to a recording");
  imp->require_subcommand(1);
  CLI::App* ipa = addSubcommand(*imp, "ipa");
  ipa->add_option("series", *in, "Series_A/measurements_grid.csv or Series_B/measurements_joint_configurations.csv")
      ->required()
      ->check(CLI::ExistingFile);
  ipa->add_option("--out", *out, "CSV v1 file to write")->required()->check(outputFile());
  ipa->add_option("--robot", *robot, "robot file (joint limits are checked)")->capture_default_str();
  auto csv = std::make_shared<ImportCsvArgs>();
  CLI::App* c = addSubcommand(*imp, "csv");
  c->add_option("file", csv->csv, "CSV v1 measurement file")->required()->check(CLI::ExistingFile);
  c->add_option("--robot", csv->robot_file, "robot file (YAML)")->required()->check(CLI::ExistingFile);
  c->add_option("--out", csv->out, "MCAP file to write")->required()->check(outputFile());
  c->add_option("--robot-id", csv->robot_id, "JointState robot_id (default: the robot file's name)");
  c->add_option("--target-id", csv->target_id, "TrackerPose target_id (default: <robot_id>_target)");
  c->add_option("--start-unix-s", csv->start_unix_s, "Unix time of the first row")->capture_default_str();
  c->add_option("--period-s", csv->period_s, "seconds between rows without stamp_s")->capture_default_str();
  c->add_option("--bracket-s", csv->bracket_s, "settled joint states this long before and after each reading")
      ->capture_default_str();
  c->add_option("--sigma-position-mm", csv->sigma_position_mm, "1-sigma of a reading's position (its covariance)")
      ->capture_default_str();
  c->add_option("--sigma-orientation-deg", csv->sigma_orientation_deg, "1-sigma of a reading's orientation")
      ->capture_default_str();
  c->add_flag("--skip-bad-rows", csv->skip_bad_rows, "skip (and count) bad rows instead of stopping");
  return [=]() -> int {
    if (*c) return importCsvToRecording(*csv);
    if (!*ipa) return 0;
    const RobotModel r = loadRobotModel(*robot);
    std::string notes;
    const MeasurementFile f = readIpaSeries(*in, r, &notes);
    std::ofstream o(*out);
    if (!o) throw std::runtime_error(*out + ": cannot write");
    writeMeasurementCsv(o, f, r.numJoints(),
                        "converted by `cellcal import ipa` from " + *in +
                            "\nipa-robot-accuracy (Landgraf et al., IEEE CASE 2021), MIT licence\n" + notes);
    std::printf("%s -> %s\n", notes.c_str(), out->c_str());
    return 0;
  };
}

}  // namespace cellcal::cli
