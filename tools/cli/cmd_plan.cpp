// `cellcal plan iso9283`: the ISO 9283 test program for a robot (core/accuracy/iso9283_plan.hpp): the cube, the
// test plane and its five poses, reached with one tool orientation, as joint configurations in the standard's cycle
// order, for the robot program (or the simulated cell, simulation.program_csv) to run. `cellcal plan poses`: the K
// configurations a calibration campaign should measure (core/identification/pose_plan.hpp), with their observability
// indices beside K random ones. `cellcal plan cover` is cmd_plan_cover.cpp.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/accuracy/iso9283_plan.hpp"
#include "cellcal/core/identification/pose_plan.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"
#include "plan_common.hpp"

namespace cellcal::cli {
namespace {

struct PlanIsoArgs {
  std::string robot, config, robot_id, out, json, centre_mm;
  double edge_mm = 0, min_z_mm = 0, min_radius_mm = 200, max_edge_mm = 1000;
  int plane = 1, cycles = 30, candidates = 200, directions = 1;
  std::uint64_t seed = 1;
};

Eigen::Vector3d parseXyzMm(const std::string& text, const std::string& option) {
  const std::vector<double> v = parseNumbers(text, 3, option, "X,Y,Z in mm");
  return Eigen::Vector3d(v[0], v[1], v[2]) * 1e-3;
}

void addIsoOptions(CLI::App& cmd, PlanIsoArgs& a) {
  addRobotOrCellOptions(cmd, a.robot, a.config, a.robot_id,
                        "robot file or URDF (a calibrated one plans with its model); its tool frame is the target");
  cmd.add_option("--out", a.out, "the program: joint columns (CSV v1) plus pose and cycle")->required()->check(outputFile());
  cmd.add_option("--cube-centre-mm", a.centre_mm, "the cube's centre X,Y,Z in the robot's base frame (default: found)");
  cmd.add_option("--cube-edge-mm", a.edge_mm, "the cube's edge (default: the largest reached)")->check(positive());
  cmd.add_option("--plane", a.plane, "the test plane: 1 C1-C2-C7-C8, 2 C2-C3-C8-C5, 3 C3-C4-C5-C6, 4 C4-C1-C6-C7")
      ->check(CLI::Range(1, 4))
      ->capture_default_str();
  cmd.add_option("--cycles", a.cycles, "cycles of P1, P5, P4, P3, P2")->check(CLI::Range(2, 10000))->capture_default_str();
  cmd.add_option("--directions", a.directions,
                 "1: every cycle P1, P5, P4, P3, P2; 3: cycles in three orders in turn (P1 P5 P4 P3 P2, P1 P2 P3 P4 P5, "
                 "P1 P3 P5 P2 P4), each pose approached from three others: iso9283 then gives vAP")
      ->check(CLI::IsMember({1, 3}))
      ->capture_default_str();
  cmd.add_option("--min-z-mm", a.min_z_mm, "every corner above this height in the base frame (the floor)")->capture_default_str();
  cmd.add_option("--min-radius-mm", a.min_radius_mm, "every corner this far from the base frame's z axis (joint 1's)")
      ->check(nonNegative())
      ->capture_default_str();
  cmd.add_option("--max-edge-mm", a.max_edge_mm, "the largest edge tried")->check(positive())->capture_default_str();
  cmd.add_option("--candidates", a.candidates, "random tool orientations (and centres) tried")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  cmd.add_option("--seed", a.seed, "seed of those candidates")->capture_default_str();
  cmd.add_option("--json", a.json, "write the cube, the poses and the joints as JSON")->check(outputFile());
}

int runPlanIso(const PlanIsoArgs& a) {
  std::string robot_label;
  const RobotFile rf = robotOrCellRobot(a.robot, a.config, a.robot_id, &robot_label);
  const RobotModel& m = rf.model;
  IsoPlanOptions o;
  if (!a.centre_mm.empty()) o.centre_m = parseXyzMm(a.centre_mm, "--cube-centre-mm");
  if (a.edge_mm > 0) o.edge_m = a.edge_mm * 1e-3;
  o.plane = a.plane;
  o.min_z_m = a.min_z_mm * 1e-3;
  o.min_radius_m = a.min_radius_mm * 1e-3;
  o.max_edge_m = a.max_edge_mm * 1e-3;
  o.candidates = a.candidates;
  o.seed = a.seed;
  IsoPlan plan;
  try {
    plan = planIso9283(m, m.nominal, o);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(robot_label + ": " + e.what());
  }
  const int b = m.baseParam(FrameParam::kX);
  const Pose base = poseFromXyzRpy(m.nominal[b], m.nominal[b + 1], m.nominal[b + 2], m.nominal[b + 3], m.nominal[b + 4],
                                   m.nominal[b + 5]);
  Pose orient = Pose::Identity();
  orient.linear() = plan.cube.orientation;
  const Eigen::Matrix<double, 6, 1> rpy = xyzRpyFromPose(orient);
  static const char* kPlanes[] = {"C1-C2-C7-C8", "C2-C3-C8-C5", "C3-C4-C5-C6", "C4-C1-C6-C7"};
  const Eigen::Vector3d c = plan.cube.centre_m * 1e3, ct = (base * plan.cube.centre_m) * 1e3;
  std::printf("plan iso9283: %s: cube edge %.1f mm centred at (%.1f, %.1f, %.1f) mm in the robot's base frame "
              "((%.1f, %.1f, %.1f) mm in the tracker frame), tool orientation roll %.2f pitch %.2f yaw %.2f deg; "
              "%s\n",
              m.name.c_str(), plan.cube.edge_m * 1e3, c.x(), c.y(), c.z(), ct.x(), ct.y(), ct.z(), radToDeg(rpy[3]),
              radToDeg(rpy[4]), radToDeg(rpy[5]),
              o.edge_m ? "the edge given" : ("the largest of " + std::to_string(plan.candidates_tried) +
                                             " candidates, corners above " + std::to_string(static_cast<int>(a.min_z_mm)) +
                                             " mm and " + std::to_string(static_cast<int>(a.min_radius_mm)) +
                                             " mm from joint 1's axis")
                                                .c_str());
  std::printf("  plane %d (%s); poses in the base frame, mm:\n", plan.plane, kPlanes[plan.plane - 1]);
  for (int k = 0; k < 5; ++k) {
    const Eigen::Vector3d p = plan.poses[static_cast<size_t>(k)].translation() * 1e3;
    std::printf("    P%d  %9.2f %9.2f %9.2f   joints", k + 1, p.x(), p.y(), p.z());
    for (int j = 0; j < m.numJoints(); ++j) std::printf(" %8.3f", radToDeg(plan.q_rad[static_cast<size_t>(k)][j]));
    std::printf(" deg\n");
  }
  // The program: cycles of P1, P5, P4, P3, P2.
  std::ostringstream comment;
  comment << "ISO 9283 test program of " << robot_label << " (cellcal plan iso9283)\ncube edge " << plan.cube.edge_m * 1e3
          << " mm, centre " << c.x() << " " << c.y() << " " << c.z() << " mm (base frame), plane " << plan.plane << " ("
          << kPlanes[plan.plane - 1] << "), " << a.cycles
          << (a.directions == 1 ? " cycles of P1 P5 P4 P3 P2"
                                : " cycles of P1 P5 P4 P3 P2, P1 P2 P3 P4 P5, P1 P3 P5 P2 P4 in turn (three approaches)");
  std::vector<ProgramRow> rows;
  for (int cy = 1; cy <= a.cycles; ++cy)
    for (int k : a.directions == 1 ? kIsoCycleOrder : kIsoDirectionOrders[static_cast<size_t>((cy - 1) % 3)])
      rows.push_back({&plan.q_rad[static_cast<size_t>(k)], "P" + std::to_string(k + 1), cy});
  writeProgram(a.out, comment.str(), m.numJoints(), rows);
  std::printf("  %d cycles, %d rows -> %s; the planned joints reach the poses to %.1g mm and %.1g deg\n", a.cycles,
              5 * a.cycles, a.out.c_str(), plan.worst_position_error_m * 1e3, radToDeg(plan.worst_orientation_error_rad));
  if (!a.json.empty()) {
    nlohmann::json poses = nlohmann::json::array();
    for (int k = 0; k < 5; ++k) {
      const Eigen::Vector3d p = plan.poses[static_cast<size_t>(k)].translation() * 1e3;
      std::vector<double> q;
      for (int j = 0; j < m.numJoints(); ++j) q.push_back(radToDeg(plan.q_rad[static_cast<size_t>(k)][j]));
      poses.push_back({{"name", "P" + std::to_string(k + 1)}, {"base_mm", {p.x(), p.y(), p.z()}}, {"joints_deg", q}});
    }
    const nlohmann::json j = {{"robot", robot_label},
                              {"cube", {{"edge_mm", plan.cube.edge_m * 1e3}, {"centre_base_mm", {c.x(), c.y(), c.z()}},
                                        {"centre_tracker_mm", {ct.x(), ct.y(), ct.z()}},
                                        {"orientation_rpy_deg", {radToDeg(rpy[3]), radToDeg(rpy[4]), radToDeg(rpy[5])}}}},
                              {"plane", plan.plane}, {"cycles", a.cycles}, {"directions", a.directions}, {"poses", poses},
                              {"reached_mm", plan.worst_position_error_m * 1e3}, {"program", a.out}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  return 0;
}

struct PlanPosesArgs {
  std::string robot, config, robot_id, out, json, measurement = "6d";
  TrackerArgs tracker;
  int count = 25, candidates = 2000;
  double sigma_position_mm = 0.015, sigma_orientation_deg = 0.005;
  std::uint64_t seed = 1;
};

void addPosesOptions(CLI::App& cmd, PlanPosesArgs& a) {
  addRobotOrCellOptions(cmd, a.robot, a.config, a.robot_id,
                        "robot file or URDF, with the cell's registration (the tracker sits at the tracker frame's origin)");
  cmd.add_option("--count", a.count, "how many configurations to measure")->check(CLI::Range(1, 100000))->capture_default_str();
  cmd.add_option("--candidates", a.candidates, "random configurations within the limits to choose from")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  addTrackerOptions(cmd, a.tracker);
  cmd.add_option("--measurement", a.measurement, "points or 6d")->check(CLI::IsMember({"points", "6d"}))->capture_default_str();
  cmd.add_option("--sigma-position-mm", a.sigma_position_mm, "the tracker's 1-sigma per axis")->check(positive())->capture_default_str();
  cmd.add_option("--sigma-orientation-deg", a.sigma_orientation_deg, "the tracker's orientation 1-sigma")
      ->check(positive())
      ->capture_default_str();
  cmd.add_option("--seed", a.seed, "seed of the candidates")->capture_default_str();
  cmd.add_option("--out", a.out, "the chosen configurations: joint columns (CSV v1) plus pose, in the order chosen")
      ->required()
      ->check(outputFile());
  cmd.add_option("--json", a.json, "write the configurations, the indices and the predicted errors as JSON")->check(outputFile());
}

int runPlanPoses(const PlanPosesArgs& a) {
  std::string robot_label;
  const RobotFile rf = robotOrCellRobot(a.robot, a.config, a.robot_id, &robot_label);
  const RobotModel& m = rf.model;
  PosePlanOptions o;
  o.count = a.count;
  o.candidates = std::max(a.candidates, a.count);
  o.kind = a.measurement == "points" ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  o.sigma_position_m = a.sigma_position_mm * 1e-3;
  o.sigma_orientation_rad = degToRad(a.sigma_orientation_deg);
  o.seed = a.seed;
  std::string tracker_from;
  o.tracker = trackerSetup(m, a.tracker, &tracker_from);
  PosePlan plan;
  try {
    plan = planPoses(m, m.nominal, o);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(robot_label + ": " + e.what());
  }
  if (o.tracker) {
    const Eigen::Vector3d t = o.tracker->position_in_base_m * 1e3;
    std::printf("plan poses: %s: tracker at (%.0f, %.0f, %.0f) mm in the base frame (%s), range %.0f-%s mm; %d of %d "
                "random configurations within the limits can be measured (%d out of range, %d with the beam crossing "
                "the robot, %d facing away, %d within 200 mm of joint 1's axis)\n",
                m.name.c_str(), t.x(), t.y(), t.z(), tracker_from.c_str(), o.tracker->min_range_m * 1e3,
                std::isfinite(o.tracker->max_range_m) ? std::to_string(static_cast<int>(o.tracker->max_range_m * 1e3)).c_str() : "inf",
                plan.feasible, plan.drawn, plan.out_of_range, plan.occluded, plan.facing_away, plan.near_axis);
  } else {
    std::printf("plan poses: %s: no tracker placement (no registration, no --tracker-mm): %d of %d random configurations "
                "within the limits, range and line of sight not checked\n", m.name.c_str(), plan.feasible, plan.drawn);
  }
  std::printf("  %d chosen to minimise the predicted position error over them (%s, %d greedy choices exchanged "
              "afterwards), beside %d at random:\n",
              a.count, o.kind == MeasurementKind::kPose6D ? "6D" : "points", plan.exchanges, a.count);
  std::printf("  %-44s %12s %12s\n", "observability (larger is better)", "chosen", "random");
  const std::pair<const char*, double ObservabilityIndices::*> rows[] = {
      {"O1 (Borm and Menq)", &ObservabilityIndices::O1}, {"O2 (inverse condition number)", &ObservabilityIndices::O2},
      {"O3 (smallest singular value)", &ObservabilityIndices::O3}, {"O4 (noise amplification)", &ObservabilityIndices::O4}};
  for (const auto& [name, field] : rows) std::printf("  %-44s %12.4g %12.4g\n", name, plan.chosen.*field, plan.random.*field);
  std::printf("  %-44s %9.4f mm %9.4f mm\n", "predicted position error (1 sigma, RMS)", plan.chosen_predicted_rms_m * 1e3,
              plan.random_predicted_rms_m * 1e3);
  std::vector<std::string> names;
  std::vector<ProgramRow> program;
  for (size_t k = 0; k < plan.chosen_q.size(); ++k) names.push_back("C" + std::to_string(k + 1));
  for (size_t k = 0; k < plan.chosen_q.size(); ++k) program.push_back({&plan.chosen_q[k], names[k], 0});
  writeProgram(a.out,
               std::to_string(a.count) + " configurations of " + robot_label + " to measure (cellcal plan poses), in the "
               "order chosen; predicted position error after them " + std::to_string(plan.chosen_predicted_rms_m * 1e3) + " mm",
               m.numJoints(), program);
  std::printf("  -> %s\n", a.out.c_str());
  if (!a.json.empty()) {
    auto indices = [](const ObservabilityIndices& i) { return nlohmann::json{{"O1", i.O1}, {"O2", i.O2}, {"O3", i.O3}, {"O4", i.O4}}; };
    nlohmann::json qs = nlohmann::json::array();
    for (const auto& q : plan.chosen_q) {
      std::vector<double> deg;
      for (int j = 0; j < q.size(); ++j) deg.push_back(radToDeg(q[j]));
      qs.push_back(deg);
    }
    const nlohmann::json j = {{"robot", robot_label},
                              {"count", a.count},
                              {"measurement", a.measurement},
                              {"candidates", plan.drawn},
                              {"feasible", plan.feasible},
                              {"chosen", {{"joints_deg", qs}, {"indices", indices(plan.chosen)},
                                          {"predicted_rms_mm", plan.chosen_predicted_rms_m * 1e3}}},
                              {"random", {{"indices", indices(plan.random)}, {"predicted_rms_mm", plan.random_predicted_rms_m * 1e3}}},
                              {"program", a.out}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  return 0;
}

}  // namespace

Runner addPlanCommand(CLI::App& app) {
  CLI::App* plan = app.add_subcommand("plan", "What to measure: the ISO 9283 test program, informative calibration poses");
  plan->require_subcommand(1);
  const Runner iso = addCommand(*plan, "iso9283", addIsoOptions, runPlanIso);
  const Runner poses = addCommand(*plan, "poses", addPosesOptions, runPlanPoses);
  const Runner cover = addPlanCoverCommand(*plan);
  return [plan, iso, poses, cover]() -> int {
    if (plan->got_subcommand("iso9283")) return iso();
    if (plan->got_subcommand("poses")) return poses();
    if (plan->got_subcommand("cover")) return cover();
    return 2;
  };
}

}  // namespace cellcal::cli
