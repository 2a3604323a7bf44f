// cellcal_compensation_publisher: for every cellcal/target_pose, solves the identified model for the joints that
// reach the target and publishes on cellcal/compensated_target the pose to command the unmodified controller
// (the nominal model's pose of those joints), the joints, the correction and the calibration version used.
// Uses the latest calibration whose health is ok. When the engine's latest is not ok (degraded: drift alarm;
// hold_last_good; uncalibrated after a reset) it keeps applying the last ok one it had and says so in `reason`; it
// also says when the engine reports stale inputs (the tracker or the controller stopped). Refuses (applied = false,
// with the reason) when it never had an ok calibration, the identified model cannot reach the target, or the
// correction exceeds compensation.max_correction_mm / _deg (or clamps, if so set) -- whatever it received.
// A calibration with model extensions (CalibrationState::model_extensions) is solved with them (compensation.hpp).
#include <unistd.h>

#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/compensation.hpp"

using namespace cellcal;
using namespace cellcal::components;

int main(int argc, char** argv) {
  CLI::App app{"cellcal compensation publisher: corrected targets for the unmodified robot controller"};
  app.footer(manFooter(
      "cellcal/target_pose, cellcal/calibration_state, cellcal/calibration_diagnostics",
      "cellcal/compensated_target (never a correction beyond compensation.max_correction_mm / _deg)",
      "  cellcal_compensation_publisher                                   answer targets with the latest ok calibration\n"
      "  cellcal_compensation_publisher --wait-for-calibration-s 30      wait for the engine before answering\n",
      ""));
  ProcessOptions o;
  double duration_s = 0;
  double wait_for_calibration_s = 3;
  addCommonOptions(app, o);
  app.add_option("--wait-for-calibration-s", wait_for_calibration_s,
                 "at start, wait this long for every robot's calibration before taking targets")
      ->capture_default_str();
  app.add_option("--duration-s", duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  return runMain("cellcal_compensation_publisher", argc, argv, app, [&] {
    const CellConfig cell = loadCell(o);
    struct Robot {
      const CellRobot* robot;
      std::optional<ReceivedCalibration> calibration;  // the latest received
      std::optional<ReceivedCalibration> last_ok;      // the latest received with health ok (the one applied)
      // The last compensated targets' joints, oldest first: the seed when a target brings none, and backlash's play.
      std::vector<Eigen::VectorXd> path;
      std::uint64_t seq = 0;
      std::string engine_warning;                      // from the engine's diagnostics: stale inputs
    };
    std::map<std::string, Robot> robots;
    for (const auto& r : cell.robots) robots[r.robot_id] = Robot{&r, std::nullopt, std::nullopt, {}, 0, ""};
    std::mutex mutex;
    std::uint64_t applied = 0, refused = 0, clamped = 0, bad_states = 0;

    DdsNode node(cell, "cellcal_compensation_publisher", identity::kCompensationPublisher);
    auto writer = node.writer<msg::CompensatedTarget>();
    node.reader<msg::CalibrationState>([&](const msg::CalibrationState& m, const fdds::SampleInfo&) {
      std::lock_guard<std::mutex> lock(mutex);
      auto it = robots.find(m.robot_id().to_string());
      if (it == robots.end()) return;
      std::string error;
      auto c = fromCalibrationState(it->second.robot->model, m, &error);
      if (!c) {
        ++bad_states;
        std::cerr << "compensation_publisher: ignored: " << error << "\n";
        return;
      }
      Robot& r = it->second;
      // A new calibration, or the same version number made again by an engine that restarted from an older state.
      const bool changed = !r.calibration || r.calibration->version != c->version ||
                           r.calibration->last_measurement_stamp_ns != c->last_measurement_stamp_ns ||
                           r.calibration->health != c->health;
      if (!changed) return;
      if (!r.calibration)
        std::cerr << "compensation_publisher: " << it->first << ": calibration v" << c->version << " received ("
                  << c->poses_used << " poses)\n";
      if (c->health != msg::HEALTH_OK && (!r.calibration || r.calibration->health == msg::HEALTH_OK) && r.last_ok)
        std::cerr << "compensation_publisher: " << it->first << ": calibration v" << c->version << " has health "
                  << static_cast<int>(c->health) << ": keeping v" << r.last_ok->version << "\n";
      if (c->health == msg::HEALTH_OK) r.last_ok = *c;
      r.calibration = std::move(c);
    });
    node.reader<msg::CalibrationDiagnostics>([&](const msg::CalibrationDiagnostics& d, const fdds::SampleInfo&) {
      std::lock_guard<std::mutex> lock(mutex);
      auto it = robots.find(d.robot_id().to_string());
      if (it == robots.end()) return;
      it->second.engine_warning = d.stale_inputs().size() == 0 ? "" : "engine input stale: " + d.stale_inputs().to_string();
    });
    // Targets are taken only once every robot's calibration is here (TRANSIENT_LOCAL delivers the latest at once
    // on discovery) or after --wait-for-calibration-s: a restarted publisher never answers from an empty state
    // while the engine's calibration is on its way.
    {
      const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(wait_for_calibration_s);
      while (std::chrono::steady_clock::now() < deadline && !stopRequested()) {
        {
          std::lock_guard<std::mutex> lock(mutex);
          bool all = true;
          for (const auto& [id, r] : robots) all = all && r.calibration.has_value();
          if (all) break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
    }
    node.reader<msg::TargetPose>([&](const msg::TargetPose& t, const fdds::SampleInfo&) {
      std::lock_guard<std::mutex> lock(mutex);
      auto it = robots.find(t.robot_id().to_string());
      if (it == robots.end()) return;
      Robot& r = it->second;
      msg::CompensatedTarget out;
      out.robot_id(t.robot_id());
      out.sequence_number(++r.seq);
      out.target_sequence(t.sequence_number());
      out.desired_position_m(t.position_m());
      out.desired_orientation_xyzw(t.orientation_xyzw());
      out.corrected_position_m(t.position_m());
      out.corrected_orientation_xyzw(t.orientation_xyzw());
      out.applied(false);
      out.clamped(false);
      bool finite = true;
      for (double v : t.position_m()) finite = finite && std::isfinite(v);
      for (double v : t.orientation_xyzw()) finite = finite && std::isfinite(v);
      const auto& q = t.orientation_xyzw();
      const double qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      if (!finite || std::abs(qn - 1.0) > 1e-6) {
        out.reason("target rejected: non-finite position or non-unit quaternion");
      } else if (!r.calibration) {
        out.reason("no calibration received yet");
      } else if (!r.last_ok) {
        out.calibration_version(r.calibration->version);
        out.reason("calibration v" + std::to_string(r.calibration->version) + " is not healthy (health " +
                   std::to_string(static_cast<int>(r.calibration->health)) + ") and none was before");
      } else {
        const ReceivedCalibration& use = *r.last_ok;
        out.calibration_version(use.version);
        // Said in `reason` even when applied: what the operator should know about the calibration used.
        std::string note;
        if (r.calibration->health != msg::HEALTH_OK)
          note = "holding v" + std::to_string(use.version) + ": the engine's v" + std::to_string(r.calibration->version) +
                 " has health " + std::to_string(static_cast<int>(r.calibration->health));
        if (!r.engine_warning.empty()) note += (note.empty() ? "" : "; ") + r.engine_warning;
        Eigen::VectorXd seed = Eigen::Map<const Eigen::VectorXd>(t.seed_position_rad().data(),
                                                                 static_cast<Eigen::Index>(t.seed_position_rad().size()));
        if (seed.size() == 0 && !r.path.empty()) seed = r.path.back();
        // With model extensions, backlash's play is that of the path through the previous compensated targets.
        const IdentifiedModel identified{use.params, use.extensions, use.extension_params};
        const CompensationResult c = compensate(r.robot->model, identified, toPose(t.position_m(), t.orientation_xyzw()),
                                                seed, cell.compensation, r.path);
        out.applied(c.applied);
        out.clamped(c.clamped);
        out.reason((c.reason.empty() ? note : note.empty() ? c.reason : c.reason + "; " + note).substr(0, 255));
        out.correction_position_m(c.correction_position_m);
        out.correction_orientation_rad(c.correction_orientation_rad);
        if (c.applied) {
          fromPose(c.corrected_in_tracker, out.corrected_position_m(), out.corrected_orientation_xyzw());
          out.joint_position_rad(std::vector<double>(c.q_rad.data(), c.q_rad.data() + c.q_rad.size()));
          r.path.push_back(c.q_rad);
          if (r.path.size() > static_cast<size_t>(kPlayHistory)) r.path.erase(r.path.begin());
        }
      }
      out.source_stamp_ns(static_cast<std::uint64_t>(wallNs()));
      writer.write(out);
      if (out.applied()) ++applied; else ++refused;
      if (out.clamped()) ++clamped;
    });
    std::cerr << "compensation_publisher: " << robots.size() << " robot(s), bound "
              << cell.compensation.max_correction_m * 1e3 << " mm / " << cell.compensation.max_correction_rad * 180 / kPi
              << " deg, domain " << node.domainId() << "\n";
    const auto start = std::chrono::steady_clock::now();
    while (sleepUntil(std::chrono::steady_clock::now() + std::chrono::milliseconds(20)))
      if (duration_s > 0 && std::chrono::steady_clock::now() - start >= std::chrono::duration<double>(duration_s)) break;
    node.shutdown();
    nlohmann::json versions = nlohmann::json::object();
    for (const auto& [id, r] : robots) versions[id] = r.calibration ? r.calibration->version : 0;
    writeJsonFile(o.stats_json, {{"name", "compensation_publisher"},
                                 {"pid", ::getpid()},
                                 {"topics", node.stats()},
                                 {"extra", {{"applied", applied}, {"refused", refused}, {"clamped", clamped},
                                            {"bad_calibration_states", bad_states}, {"calibration_versions", versions}}}});
    return 0;
  });
}
