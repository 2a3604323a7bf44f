// `cellcal cell`'s in-process reference: the same robot program and tracker model through core's CalibrationEngine
// in the launcher's process (no DDS), fed the readings the engine applied; and what the processes' stats say of them.
#include <random>

#include "cell_roles.hpp"
#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::cli {

using namespace cellcal::components;

Reference inProcessReference(const CellConfig& cell, const CellRobot& robot, int index, double cell_time_end_s,
                             const Judge& judge, const ReadingsApplied* readings,
                             const std::map<long long, Eigen::VectorXd>& followed) {
  const SimulatedCell sim = makeSimulatedCell(robot, cell.simulation, index);
  const SimRobotProgram program(sim, cell.simulation);
  EngineSettings es = cell.engine;
  CalibrationEngine engine(robot, es, cell.time_compression);
  std::mt19937_64 rng(sim.config().seed * 6364136223846793005ULL + 1442695040888963407ULL);
  const std::int64_t epoch = 1'700'000'000'000'000'000;
  auto wall = [&](double t) { return epoch + static_cast<std::int64_t>(t / cell.time_compression * 1e9); };
  const double pt = cell.simulation.pose_time_s, sf = cell.simulation.settle_fraction;
  // Per pose id: its joints (the program's, or the configuration it followed) and the cell time the tracker read it.
  std::vector<Eigen::VectorXd> joints_of;
  std::vector<double> read_at_s;
  for (int g = 0; g < program.campaigns(); ++g)
    for (int k = 0; k < program.posesIn(g); ++k) {
      const auto f = followed.find(static_cast<long long>(joints_of.size()));
      joints_of.push_back(f != followed.end() ? f->second : program.campaignConfigurations(g)[k]);
      read_at_s.push_back(program.campaignStart_s(g) + k * pt + (1 - sf + cell.simulation.tracker_delay_fraction * sf) * pt);
    }
  std::uint64_t seq = 0;
  // One reading of pose `id`: fed stamped `stamp_ns` (0: by cell time), or only drawn (nullopt).
  auto reading = [&](std::size_t id, std::optional<std::int64_t> stamp_ns) {
    const double t_read = read_at_s[id];
    const Eigen::VectorXd& q = joints_of[id];
    const Observation obs = sim.measure(q, t_read / 3600.0, rng, robot.measurement);
    ++seq;
    if (!stamp_ns) return;
    const std::int64_t t = *stamp_ns != 0 ? *stamp_ns : wall(t_read);
    engine.onJointState({t - 1000, seq, q, true}, t);
    engine.onTrackerSample(toTrackerSample(toTrackerPose(robot.target_id, t, seq, obs)), t);
    engine.onJointState({t + 1000, ++seq, q, true}, t);
    engine.process(t + 2000);
  };
  Reference ref;
  if (readings) {
    const std::map<std::uint64_t, std::int64_t> applied(readings->applied.begin(), readings->applied.end());
    const auto made = readings->pose_of_reading.size();
    if (readings->applied.size() != readings->poses_used)
      ref.why_program = "the engine applied " + std::to_string(readings->applied.size()) + " readings in this run of its " +
                        std::to_string(readings->poses_used) + " poses (resumed from a state, or more than it lists)";
    else if (!applied.empty() && applied.rbegin()->first > made)
      ref.why_program = "the engine applied reading #" + std::to_string(applied.rbegin()->first) + ", the tracker lists " +
                        std::to_string(made);
    for (const long long id : readings->pose_of_reading)
      if (ref.why_program.empty() && (id < 0 || id >= static_cast<long long>(joints_of.size())))
        ref.why_program = "the tracker measured pose " + std::to_string(id) + ", not in the program";
    if (ref.why_program.empty()) {
      for (size_t i = 0; i < made; ++i) {
        const auto a = applied.find(i + 1);
        reading(static_cast<std::size_t>(readings->pose_of_reading[i]),
                a == applied.end() ? std::nullopt : std::optional<std::int64_t>(a->second));
      }
      ref.inputs = "applied_readings";
    }
  }
  if (ref.inputs.empty()) {
    ref.inputs = "program";
    for (std::size_t id = 0; id < joints_of.size() && read_at_s[id] <= cell_time_end_s; ++id) reading(id, 0);
  }
  const CalibrationSnapshot& snap = engine.snapshot();
  ref.verify_mm = judge.verify(snap, cell_time_end_s / 3600.0);
  ref.poses = static_cast<int>(snap.poses_used);
  return ref;
}

// The readings of one robot the simulated tracker made and the engine applied (mergeProcessStats put both processes'
// stats in the summary); nullopt when a process did not say.
std::optional<ReadingsApplied> readingsApplied(const nlohmann::json& summary, const std::string& robot_id) {
  std::optional<ReadingsApplied> out;
  using namespace stats;
  const nlohmann::json trackers = summary.value("trackers", nlohmann::json::object()),
                       engines = summary.value("engines", nlohmann::json::object());
  for (const auto& [name, t] : trackers.items())
    if (t.contains(kPoseOfReading) && t[kPoseOfReading].contains(robot_id)) {
      out.emplace();
      out->pose_of_reading = t[kPoseOfReading][robot_id].get<std::vector<long long>>();
    }
  if (!out) return std::nullopt;
  for (const auto& [name, e] : engines.items())
    if (e.contains(kRobots) && e[kRobots].contains(robot_id) && e[kRobots][robot_id].contains(kAppliedReadings)) {
      out->applied = e[kRobots][robot_id][kAppliedReadings].get<std::vector<std::pair<std::uint64_t, std::int64_t>>>();
      out->poses_used = e[kRobots][robot_id].value(kPosesUsed, 0ULL);
      return out;
    }
  return std::nullopt;
}

// The poses the simulated program took from the engine's proposals (the joint-state adapter's followed_poses).
std::map<long long, Eigen::VectorXd> followedPoses(const nlohmann::json& summary, const std::string& robot_id) {
  std::map<long long, Eigen::VectorXd> out;
  const nlohmann::json adapters = summary.value("joint_adapters", nlohmann::json::object());
  for (const auto& [name, j] : adapters.items()) {
    if (!j.contains(stats::kFollowedPoses) || !j[stats::kFollowedPoses].contains(robot_id)) continue;
    for (const auto& row : j[stats::kFollowedPoses][robot_id]) {
      const auto v = row.get<std::vector<double>>();
      if (v.size() < 2) continue;
      out[static_cast<long long>(v[0])] = Eigen::Map<const Eigen::VectorXd>(v.data() + 1, static_cast<Eigen::Index>(v.size() - 1));
    }
  }
  return out;
}

}  // namespace cellcal::cli
