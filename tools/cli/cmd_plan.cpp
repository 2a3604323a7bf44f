// `cellcal plan iso9283`: the ISO 9283 test program for a robot (core/accuracy/iso9283_plan.hpp): the cube, the
// test plane and its five poses, reached with one tool orientation, as joint configurations in the standard's cycle
// order, for the robot program (or the simulated cell, simulation.program_csv) to run. `cellcal plan poses`: the K
// configurations a calibration campaign should measure (core/identification/pose_plan.hpp), with their observability
// indices beside K random ones. `cellcal plan cover`: which of a robot program's targets compensation with a
// calibrated robot file corrects, and the ones it passes through because the model's extensions were never judged
// there, as a program to measure (core/engine/compensation.hpp, compensateProgram).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <fstream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/accuracy/iso9283_plan.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/identification/pose_plan.hpp"
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

// A robot program (CSV v1's joint columns in radians to the last digit, pose, and cycle when given), written whole.
struct ProgramRow {
  const Eigen::VectorXd* q;
  std::string pose;
  int cycle = 0;  // 0: no cycle column
};
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
  // The program: cycles of P1, P5, P4, P3, P2.
  std::ostringstream comment;
  comment << "ISO 9283 test program of " << robot_label << " (cellcal plan iso9283)\ncube edge " << plan.cube.edge_m * 1e3
          << " mm, centre " << c.x() << " " << c.y() << " " << c.z() << " mm (base frame), plane " << plan.plane << " ("
          << kPlanes[plan.plane - 1] << "), " << a.cycles << " cycles of P1 P5 P4 P3 P2";
  std::vector<ProgramRow> rows;
  for (int cy = 1; cy <= a.cycles; ++cy)
    for (int k : kIsoCycleOrder) rows.push_back({&plan.q_rad[static_cast<size_t>(k)], "P" + std::to_string(k + 1), cy});
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
                              {"plane", plan.plane}, {"cycles", a.cycles}, {"poses", poses},
                              {"reached_mm", plan.worst_position_error_m * 1e3}, {"program", a.out}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  return 0;
}

// Where the tracker stands and what it can see (--tracker-mm, --range-mm, --link-radius-mm, --acceptance-deg): the
// tracker frame's origin of the model's registration unless --tracker-mm places it; none when neither is known.
struct TrackerArgs {
  std::string tracker_mm, range_mm;
  double link_radius_mm = 60, acceptance_deg = 0;
};
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


struct PlanCoverArgs {
  std::string robot, config, robot_id, calibration, program, out;
  TrackerArgs tracker;
  double max_predicted_sigma_mm = 1, max_correction_mm = 5;
};

void addCoverOptions(CLI::App& cmd, PlanCoverArgs& a) {
  addRobotOrCellOptions(cmd, a.robot, a.config, a.robot_id,
                        "the robot as its controller knows it (its nominal robot file or URDF): the program's targets "
                        "are the poses it commands");
  cmd.add_option("--calibration", a.calibration, "the calibrated robot file compensation applies (calibrate --save-robot)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd.add_option("--program", a.program, "the robot program: CSV v1's joint columns (q1_rad..), pose optional")
      ->required()
      ->check(CLI::ExistingFile);
  cmd.add_option("--max-predicted-sigma-mm", a.max_predicted_sigma_mm,
                 "compensation.max_predicted_sigma_mm: a target whose predicted error is above it is passed through "
                 "(0: no guard; never-judged targets are then corrected with their error not known)")
      ->check(nonNegative())
      ->capture_default_str();
  cmd.add_option("--max-correction-mm", a.max_correction_mm, "compensation.max_correction_mm")->check(positive())->capture_default_str();
  addTrackerOptions(cmd, a.tracker);
  cmd.add_option("--out", a.out, "the program's configurations passed through where the extensions were never judged "
                 "and the tracker can measure: joint columns (CSV v1) plus pose")
      ->required()
      ->check(outputFile());
}

int runPlanCover(const PlanCoverArgs& a) {
  std::string robot_label;
  const RobotFile rf = robotOrCellRobot(a.robot, a.config, a.robot_id, &robot_label);
  const RobotFile cal = loadRobotFile(a.calibration);
  if (!cal.calibration)
    throw ConfigError(a.calibration + ": not a calibrated robot file (no calibration section): calibrate --save-robot writes one");
  if (cal.model.numJoints() != rf.model.numJoints() || cal.model.numParams() != rf.model.numParams())
    throw ConfigError(a.calibration + ": another robot than " + robot_label + " (" + std::to_string(cal.model.numJoints()) +
                      " joints, " + std::to_string(cal.model.numParams()) + " parameters against " +
                      std::to_string(rf.model.numJoints()) + " and " + std::to_string(rf.model.numParams()) + ")");
  // The controller: the nominal kinematics with the frames the calibration registered (the tracker frame its targets
  // are in), as the compensation publisher sees a cell registered by that campaign.
  RobotModel controller = rf.model;
  const int f0 = controller.baseParam(FrameParam::kX);
  controller.nominal.tail(controller.numParams() - f0) = cal.model.nominal.tail(controller.numParams() - f0);
  IdentifiedModel model(calibratedModel(cal));
  attachRobotFile(cal, model);
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(a.program, rf.model, po);
  std::vector<Eigen::VectorXd> qs;
  for (const auto& row : program.rows) qs.push_back(row.q_rad);
  CompensationSettings settings;
  settings.max_predicted_sigma_m = a.max_predicted_sigma_mm * 1e-3;
  settings.max_correction_m = a.max_correction_mm * 1e-3;
  const ProgramCompensation pc = compensateProgram(controller, model, qs, settings);
  std::string tracker_from;
  const std::optional<TrackerSetup> tracker = trackerSetup(cal.model, a.tracker, &tracker_from);
  auto label = [&](size_t i) {
    return program.rows[i].pose ? *program.rows[i].pose : "row " + std::to_string(i + 1);
  };
  std::printf("plan cover: %zu configurations of %s compensated with %s (as the compensation publisher would: predicted "
              "error guard %.3g mm)\n", qs.size(), a.program.c_str(), a.calibration.c_str(), a.max_predicted_sigma_mm);
  std::vector<double> sigma;
  for (const auto& r : pc.results)
    if (r.applied && std::isfinite(r.predicted_sigma_position_m)) sigma.push_back(r.predicted_sigma_position_m * 1e3);
  std::sort(sigma.begin(), sigma.end());
  std::printf("  corrected: %d", pc.applied);
  if (!sigma.empty()) std::printf(" (predicted 1-sigma error %.3g-%.3g mm)", sigma.front(), sigma.back());
  const int blind = static_cast<int>(std::count_if(pc.results.begin(), pc.results.end(),
                                                   [](const CompensationResult& r) { return r.applied && r.unjudged; }));
  if (blind > 0)
    std::printf("; of them %d where the model's extensions were never judged, their error not known (the guard off)", blind);
  std::printf("\n  passed through where the model's extensions were never judged: %d\n", pc.unjudged);
  std::vector<size_t> to_measure;  // never judged (passed through, or corrected blind), the tracker can measure them
  int occluded = 0;
  for (size_t i = 0; i < qs.size(); ++i) {
    const CompensationResult& r = pc.results[i];
    if (!r.unjudged) continue;
    const Visibility v = tracker ? visibility(cal.model, cal.model.nominal, qs[i], *tracker) : Visibility::kVisible;
    std::printf("    %s: %s%s\n", label(i).c_str(),
                r.applied ? "corrected with its error not known: the extensions were never judged there" : r.reason.c_str(),
                v == Visibility::kVisible ? "" : (std::string("; the tracker cannot measure it: ") + visibilityName(v)).c_str());
    if (v == Visibility::kVisible) to_measure.push_back(i);
    else ++occluded;
  }
  std::printf("  passed through or refused otherwise: %d\n", pc.refused);
  for (size_t i = 0; i < qs.size(); ++i)
    if (!pc.results[i].applied && !pc.results[i].unjudged)
      std::printf("    %s: %s: %s\n", label(i).c_str(), outcomeName(pc.results[i].outcome), pc.results[i].reason.c_str());
  std::vector<std::string> names;
  for (size_t i : to_measure) names.push_back(label(i));
  std::vector<ProgramRow> measure;
  for (size_t k = 0; k < to_measure.size(); ++k) measure.push_back({&qs[to_measure[k]], names[k], 0});
  writeProgram(a.out,
               std::to_string(measure.size()) + " configurations of " + a.program + " that compensation with " +
                   a.calibration + " passes through where its extensions were never judged (cellcal plan cover): "
                   "measure them and calibrate again with the campaign's rows",
               rf.model.numJoints(), measure);
  std::printf("  to measure: %zu of those %d (%s%s) -> %s: measured and calibrated again beside the campaign's rows, "
              "they lie within the data\n",
              measure.size(), pc.unjudged + blind, tracker ? "the tracker at " : "the tracker's place not known, not checked",
              tracker ? (tracker_from + (occluded ? ", " + std::to_string(occluded) + " it cannot measure" : "")).c_str() : "",
              a.out.c_str());
  return 0;
}

}  // namespace

Runner addPlanCommand(CLI::App& app) {
  CLI::App* plan = app.add_subcommand("plan", "What to measure: the ISO 9283 test program, informative calibration poses");
  plan->require_subcommand(1);
  const Runner iso = addCommand(*plan, "iso9283", addIsoOptions, runPlanIso);
  const Runner poses = addCommand(*plan, "poses", addPosesOptions, runPlanPoses);
  const Runner cover = addCommand(*plan, "cover", addCoverOptions, runPlanCover);
  return [plan, iso, poses, cover]() -> int {
    if (plan->got_subcommand("iso9283")) return iso();
    if (plan->got_subcommand("poses")) return poses();
    if (plan->got_subcommand("cover")) return cover();
    return 2;
  };
}

}  // namespace cellcal::cli
