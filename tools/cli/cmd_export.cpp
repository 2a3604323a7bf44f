// `cellcal export`: a recording's tracker readings paired with joint states as the engine pairs them, as CSV v1.
#include <cstdio>
#include <fstream>
#include <map>
#include <string>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/recording/recording.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

using namespace cellcal::components;
using namespace cellcal::recording;

struct ExportArgs {
  ProcessOptions common;
  std::string file, out, robot_id;
};

void addOptions(CLI::App& cmd, ExportArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_option("file", a.file, "MCAP recording")->required()->check(CLI::ExistingFile);
  cmd.add_option("--out", a.out, "CSV v1 file to write")->required()->check(outputFile());
  cmd.add_option("--robot-id", a.robot_id, "robot of the cell file (default: the first)");
}

int runExport(const ExportArgs& a) {
  const Recording rec = readRecording(a.file);
  const CellConfig cell = loadCell(a.common);
  const CellRobot* robot = a.robot_id.empty() ? &cell.robots.front() : cell.robotById(a.robot_id);
  if (!robot) throw std::runtime_error("--robot-id " + a.robot_id + ": not in " + cell.source);
  PairingBuffer pairing(robot->model, pairingOptions(*robot, cell.engine));
  std::map<std::int64_t, TrackerSample> readings;  // by stamp, for the orientation-less rows
  MeasurementFile f;
  f.source = a.file;
  std::int64_t first_stamp = 0;
  std::uint64_t rejected = 0;
  auto take = [&](const PairingOutcome& out) {
    rejected += out.rejected.size();
    for (const auto& p : out.paired) {
      const auto it = readings.find(p.tracker_stamp_ns);
      if (it == readings.end()) continue;
      if (f.rows.empty()) first_stamp = p.tracker_stamp_ns;
      MeasurementRow row;
      row.line = static_cast<int>(f.rows.size()) + 1;
      row.q_rad = p.observation.q_rad;
      row.position_m = it->second.position_m;
      if (it->second.has_orientation) {
        const auto& q = it->second.orientation_xyzw;
        row.orientation = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized();
      }
      row.stamp_s = (p.tracker_stamp_ns - first_stamp) / 1e9;
      f.rows.push_back(std::move(row));
      readings.erase(readings.begin(), std::next(it));
    }
  };
  msg::JointState js;  // reused (see runValidate)
  msg::TrackerPose tp;
  for (const auto& rm : rec.in_log_order) {
    const auto now = static_cast<std::int64_t>(rm.message->log_time_ns);
    std::string error;
    if (*rm.topic == TopicOf<msg::JointState>::name) {
      if (!decodeCdr(rm.message->data, &js, &error)) throw std::runtime_error(a.file + ": " + *rm.topic + ": " + error);
      if (js.robot_id().to_string() != robot->robot_id) continue;
      pairing.addJointState(toJointSample(js), now);
    } else if (*rm.topic == TopicOf<msg::TrackerPose>::name) {
      if (!decodeCdr(rm.message->data, &tp, &error)) throw std::runtime_error(a.file + ": " + *rm.topic + ": " + error);
      if (tp.target_id().to_string() != robot->target_id) continue;
      const TrackerSample s = toTrackerSample(tp);
      if (!pairing.addTrackerSample(s, now)) readings[s.stamp_ns] = s;
      else ++rejected;
    } else {
      continue;
    }
    take(pairing.poll(now));
  }
  take(pairing.poll(static_cast<std::int64_t>(rec.end_ns) + 1000000000LL));
  if (f.rows.empty())
    throw std::runtime_error(a.file + ": no tracker reading of " + robot->target_id + " pairs with a settled joint state of " +
                             robot->robot_id + " (" + std::to_string(rejected) + " rejected)");
  std::ofstream o(a.out);
  if (!o) throw std::runtime_error(a.out + ": cannot write");
  writeMeasurementCsv(o, f, robot->model.numJoints(),
                      "exported by `cellcal export` from " + a.file + " (robot " + robot->robot_id + ", target " +
                          robot->target_id + "): one row per tracker reading paired with a settled joint state\n"
                          "stamp_s = 0 at Unix time " + std::to_string(first_stamp) + " ns");
  std::printf("export: %zu rows (readings paired with settled joint states; %llu rejected by the pairing) -> %s\n",
              f.rows.size(), static_cast<unsigned long long>(rejected), a.out.c_str());
  return 0;
}

}  // namespace

Runner addExportCommand(CLI::App& app) { return addCommand(app, "export", addOptions, runExport); }

}  // namespace cellcal::cli
