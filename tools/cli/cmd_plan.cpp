// `cellcal plan iso9283`: the ISO 9283 test program for a robot (core/accuracy/iso9283_plan.hpp): the cube, the
// test plane and its five poses, reached with one tool orientation, as joint configurations in the standard's cycle
// order, for the robot program (or the simulated cell, simulation.program_csv) to run.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/accuracy/iso9283_plan.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {
namespace {

struct PlanIsoArgs {
  std::string robot, config, robot_id, out, json, centre_mm;
  double edge_mm = 0, min_z_mm = 0, min_radius_mm = 200, max_edge_mm = 1000;
  int plane = 1, cycles = 30, candidates = 200;
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
  // The program: cycles of P1, P5, P4, P3, P2; joints in radians to the last digit.
  std::ostringstream csv;
  csv << "# ISO 9283 test program of " << robot_label << " (cellcal plan iso9283)\n# cube edge " << plan.cube.edge_m * 1e3
      << " mm, centre " << c.x() << " " << c.y() << " " << c.z() << " mm (base frame), plane " << plan.plane << " ("
      << kPlanes[plan.plane - 1] << "), " << a.cycles << " cycles of P1 P5 P4 P3 P2\n";
  for (int j = 1; j <= m.numJoints(); ++j) csv << "q" << j << "_rad,";
  csv << "pose,cycle\n";
  csv.precision(17);
  for (int cy = 1; cy <= a.cycles; ++cy)
    for (int k : kIsoCycleOrder) {
      for (int j = 0; j < m.numJoints(); ++j) csv << plan.q_rad[static_cast<size_t>(k)][j] << ",";
      csv << "P" << k + 1 << "," << cy << "\n";
    }
  {
    std::ofstream out(a.out);
    if (!out) throw std::runtime_error(a.out + ": cannot write");
    out << csv.str();
  }
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
                              {"plane", plan.plane}, {"cycles", a.cycles}, {"poses", poses},
                              {"reached_mm", plan.worst_position_error_m * 1e3}, {"program", a.out}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  return 0;
}

}  // namespace

Runner addPlanCommand(CLI::App& app) {
  CLI::App* plan = app.add_subcommand("plan", "What to measure: the ISO 9283 test program");
  plan->require_subcommand(1);
  const Runner iso = addCommand(*plan, "iso9283", addIsoOptions, runPlanIso);
  return [plan, iso]() -> int {
    if (plan->got_subcommand("iso9283")) return iso();
    return 2;
  };
}

}  // namespace cellcal::cli
