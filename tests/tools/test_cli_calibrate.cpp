// `cellcal calibrate` and `cellcal import` as a user runs them: a measurement file of a simulated robot whose
// placement in the tracker frame is unknown to the robot file (hidden errors and placement from a fresh seed).
#include <gtest/gtest.h>

#include <map>
#include <sstream>

#include "cell/cell_test_support.hpp"
#include "cellcal/lab/ipa_dataset.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/model/cause.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/hidden_effect.hpp"
#include "core/identification/placements.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

// Set-up s of the same robot (the same hidden errors): set-up 0 where `sc` places it, every other one with the tracker
// moved 0-2 m and turned up to 90 deg.
SimulationConfig placement(const SimulationConfig& sc, int s, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  SimulationConfig c = sc;
  if (s > 0) {
    c.base_in_tracker.head<3>() += Eigen::Vector3d(1.0 + u(rng), 1.0 + u(rng), 0.2 * u(rng));
    c.base_in_tracker[5] += 0.5 * kPi * u(rng);
  }
  return c;
}

TEST(CliCalibrate, RegistersAndCalibratesAFileToTheNoiseFloor) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  SimulationConfig sc;
  sc.seed = seed;
  const SimulatedCell cell(robot("staubli_tx60"), sc);  // base at (2.2, 0.4, -0.3) m, yaw 160 deg: not in the file
  std::mt19937_64 rng(seed);
  MeasurementFile f;
  double floor_mm = 0;
  int n = 0;
  for (const auto& q : cell.randomConfigurations(200, rng)) {
    const Observation o = cell.measure(q, 0.0, rng);
    f.rows.push_back(measuredRow(q, o));
    if (n++ % 2 == 1) floor_mm += (o.measured_in_tracker.translation() - cell.truePose(q, 0).translation()).norm() * 1e3;
  }
  floor_mm /= 100;
  {
    std::ofstream out(dir + "/m.csv");
    writeMeasurementCsv(out, f, 6, "simulated TX60");
  }
  Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml",
                               "--data", dir + "/m.csv", "--json", dir + "/r.json", "--sigma-position-mm", "0.012"});
  ASSERT_EQ(p.wait(60), 0) << p.log();
  const auto j = readJson(dir + "/r.json");
  EXPECT_TRUE(j["converged"].get<bool>());
  EXPECT_EQ(j["identification_rows"], 100);
  EXPECT_EQ(j["verification_rows"], 100);
  const double before = j["verification"]["before"]["mean_mm"], after = j["verification"]["after"]["mean_mm"];
  EXPECT_GT(before, 0.2) << p.log();
  EXPECT_LT(after, 1.3 * floor_mm) << "floor " << floor_mm << " mm\n" << p.log();
  EXPECT_LT(j["solve_time_s"].get<double>(), 5.0);
}

// Every set-up's verification mean is lower with the extension (calibrate's JSON x) than geometric (g), printed.
void expectEverySetUpBetterWith(const nlohmann::json& g, const nlohmann::json& x, const std::string& with,
                                const std::string& log) {
  for (size_t s = 0; s < x["setups"].size(); ++s) {
    const double xs = x["setups"][s]["verification"]["after"]["mean_mm"], gs = g["setups"][s]["verification"]["after"]["mean_mm"];
    std::printf("  set-up %zu: verification mean %.4f mm with the %s, %.4f mm geometric\n", s + 1, xs, with.c_str(), gs);
    EXPECT_LT(xs, gs) << "set-up " << s + 1 << "\n" << log;
  }
}

// The robot file calibrate saved holds one extension, `spec`.
void expectSavedExtension(const std::string& path, const std::string& spec) {
  const RobotFile saved = loadRobotFile(path);
  ASSERT_TRUE(saved.calibration);
  ASSERT_EQ(saved.calibration->extensions.size(), 1u);
  EXPECT_EQ(extensionSpec(saved.calibration->extensions[0]), spec);
}

// Writes set-up s's rows to dir/setup<s+1>.csv (its comment: `what`, set-up s+1) and returns the path.
std::string writeSetupFile(const std::string& dir, int s, const MeasurementFile& f, const std::string& what) {
  const std::string path = dir + "/setup" + std::to_string(s + 1) + ".csv";
  std::ofstream out(path);
  writeMeasurementCsv(out, f, 6, what + ", set-up " + std::to_string(s + 1));
  return path;
}

// `cellcal calibrate` of the set-ups in `files` (--data each) with --model model_spec, writing <dir>/<name>.json and
// <name>.yaml: its exit code and log.
std::pair<int, std::string> calibrateSetUps(const std::string& dir, const std::string& name, const std::string& robot_file,
                                            const std::vector<std::string>& files, const std::string& model_spec) {
  std::vector<std::string> args = {"cellcal", "calibrate", "--robot", robot_file};
  for (const auto& f : files) {
    args.push_back("--data");
    args.push_back(f);
  }
  for (const std::string& a : {std::string("--model"), model_spec, std::string("--json"), dir + "/" + name + ".json",
                               std::string("--save-robot"), dir + "/" + name + ".yaml"})
    args.push_back(a);
  Process p(dir, name, args);
  const int code = p.wait(60);
  return {code, p.log()};
}

// Two campaigns of the same robot from two tracker placements (random robot errors, placements), each its own file:
// `calibrate --data a.csv --data b.csv` fits one kinematic model with a base and tool per set-up, reports each set-up,
// and predicts each set-up's held-out rows at least as well as calibrating that file alone; `--save-robot` keeps the
// frames of the set-up given last; a command that takes one set-up refuses several.
// Several set-ups with a model extension (--model): the robot's joint 2 compliance (a UR10, UR's masses in its robot
// file) drawn at random in size and sign, measured from two tracker placements. One compliance for both set-ups; each
// set-up's verification error below the geometric joint fit's; the saved file carries the extension and its value;
// --model auto finds the same model in each set-up and fits it.
TEST(CliCalibrate, SeveralSetUpsShareOneExtendedModel) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const std::string ur10 = std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml";
  const RobotModel model = robot("ur10");
  SimulationConfig sc;
  sc.seed = seed;
  {
    const SimulatedCell plain(model, sc);
    const double size_rad = (0.2 + 0.2 * std::abs(u(rng))) * 1e-3 * (u(rng) < 0 ? -1 : 1);
    sc.hidden = scaledHiddenEffect(model, plain.trueParams(0), Cause::kJointCompliance, 1, size_rad, model.links,
                                   plain.randomConfigurations(200, rng), rng);
  }
  std::vector<std::string> files;
  for (int s = 0; s < 2; ++s) {
    const SimulationConfig c = placement(sc, s, rng);
    const SimulatedCell cell(model, c);
    MeasurementFile f;
    for (const auto& q : cell.randomConfigurations(120, rng)) f.rows.push_back(measuredRow(q, cell.measure(q, 0.0, rng)));
    files.push_back(writeSetupFile(dir, s, f, "simulated UR10 with joint 2 compliance"));
  }
  const auto [gc, glog] = calibrateSetUps(dir, "geometric", ur10, files, "geometric");
  ASSERT_EQ(gc, 0) << glog;
  const auto [xc, xlog] = calibrateSetUps(dir, "extended", ur10, files, "joint_compliance:2");
  ASSERT_EQ(xc, 0) << xlog;
  EXPECT_NE(xlog.find("one kinematic model (joint_compliance joint 2)"), std::string::npos) << xlog;
  EXPECT_NE(xlog.find("extension parameters (every set-up's):"), std::string::npos) << xlog;
  const auto g = readJson(dir + "/geometric.json"), x = readJson(dir + "/extended.json");
  ASSERT_EQ(x["extension_params"].size(), 1u) << xlog;
  expectEverySetUpBetterWith(g, x, "compliance", xlog);
  ASSERT_NO_FATAL_FAILURE(expectSavedExtension(dir + "/extended.yaml", "joint_compliance:2"));
  const RobotFile saved = loadRobotFile(dir + "/extended.yaml");
  ASSERT_EQ(saved.calibration->extension_params.size(), 1);
  EXPECT_NEAR(saved.calibration->extension_params[0], x["extension_params"].begin()->get<double>(),
              1e-9 * std::abs(saved.calibration->extension_params[0]));
  // --model auto: `diagnose` on each set-up's rows names the same cause, which is then fitted as if named.
  const auto [ac, alog] = calibrateSetUps(dir, "auto", ur10, files, "auto");
  ASSERT_EQ(ac, 0) << alog;
  EXPECT_NE(alog.find("--model auto: every set-up names joint_compliance joint 2"), std::string::npos) << alog;
  EXPECT_EQ(readJson(dir + "/auto.json")["extension_params"], x["extension_params"]) << alog;
  // A set-up of another robot without the compliance beside the first: the set-ups name different models, and the
  // user is asked to name one.
  {
    SimulationConfig plain_sc;
    plain_sc.seed = seed + 1;
    const SimulatedCell cell(model, placement(plain_sc, 1, rng));
    MeasurementFile f;
    for (const auto& q : cell.randomConfigurations(120, rng)) f.rows.push_back(measuredRow(q, cell.measure(q, 0.0, rng)));
    std::ofstream out(dir + "/plain.csv");
    writeMeasurementCsv(out, f, 6, "simulated UR10 without a hidden effect");
  }
  const auto [dc, dlog] = calibrateSetUps(dir, "differ", ur10, {files[0], dir + "/plain.csv"}, "auto");
  EXPECT_EQ(dc, 2) << dlog;
  EXPECT_NE(dlog.find("--model auto: the set-ups name different models (set-up 1: joint_compliance joint 2; set-up 2: "
                      "geometric)"),
            std::string::npos)
      << dlog;
}

// A backlash in several set-ups: joint 2's play (0.3-1.0 mrad, drawn at random) carried along each set-up's path of
// stand-stills (the file's row order), measured from two tracker placements. `calibrate --model backlash:2` with both
// files: one width for both set-ups, near the truth, each set-up's verification error below the geometric joint
// fit's, the rows before the joint first moved left out and said, the saved file carrying it.
TEST(CliCalibrate, SeveralSetUpsShareOneBacklash) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  const std::string ur10 = std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml";
  const RobotModel model = robot("ur10");
  SimulationConfig sc;
  sc.seed = seed;
  sc.hidden.cause = Cause::kBacklash;
  sc.hidden.joint = 1;
  sc.hidden.backlash_width_rad = (0.3 + 0.7 * u(rng)) * 1e-3;
  std::vector<std::string> files;
  for (int s = 0; s < 2; ++s) {
    const SimulatedCell cell(model, placement(sc, s, rng));
    MeasurementFile f;
    HiddenJointState state;
    const auto qs = cell.randomConfigurations(120, rng);
    for (size_t i = 0; i < qs.size(); ++i) {
      if (i) state = cell.advanceHiddenState(state, qs[i - 1], qs[i]);
      f.rows.push_back(measuredRow(qs[i], cell.measure(qs[i], &state, 0.0, rng)));
    }
    files.push_back(writeSetupFile(dir, s, f, "simulated UR10 with joint 2 backlash"));
  }
  const auto [gc, glog] = calibrateSetUps(dir, "geometric", ur10, files, "geometric");
  ASSERT_EQ(gc, 0) << glog;
  const auto [xc, xlog] = calibrateSetUps(dir, "backlash", ur10, files, "backlash:2");
  ASSERT_EQ(xc, 0) << xlog;
  EXPECT_NE(xlog.find("before the backlash joint first moved in this set-up left out of the fit"), std::string::npos)
      << xlog;
  const auto g = readJson(dir + "/geometric.json"), x = readJson(dir + "/backlash.json");
  ASSERT_EQ(x["extension_params"].size(), 1u) << xlog;
  const double width = -x["extension_params"].begin()->get<double>();
  std::printf("  width %.4f mrad (true %.4f)\n", width * 1e3, sc.hidden.backlash_width_rad * 1e3);
  EXPECT_NEAR(width, sc.hidden.backlash_width_rad, 0.25 * sc.hidden.backlash_width_rad) << xlog;
  for (int s = 0; s < 2; ++s) EXPECT_GE(x["setups"][s]["rows_left_out_backlash"].get<int>(), 1) << xlog;
  expectEverySetUpBetterWith(g, x, "backlash", xlog);
  expectSavedExtension(dir + "/backlash.yaml", "backlash:2");
}

// Gross errors in several set-ups: a few identification rows of each set-up bumped by 1-3 mm (a target knocked), at
// random rows, and one verification row. Each set-up lists its own by file line; the model predicts what that of the
// plain reference predicts, to a micrometre: the same files with the bumped identification rows (and the
// verification row after each, so the alternate split keeps its parity) removed, where the screening leaves every
// identification row in.
TEST(CliCalibrate, SeveralSetUpsLeaveOutTheirGrossErrors) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const std::string tx60 = std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml";
  SimulationConfig sc;
  sc.seed = seed;
  std::vector<std::string> files, clean;
  std::vector<std::vector<int>> bumped_lines(2);
  for (int s = 0; s < 2; ++s) {
    const SimulationConfig c = placement(sc, s, rng);
    const SimulatedCell cell(robot("staubli_tx60"), c);
    MeasurementFile f, reference;
    const auto qs = cell.randomConfigurations(120, rng);
    std::vector<int> bump;  // identification rows (even: the alternate split) at least 4 apart, then one verification row
    while (bump.size() < 3) {
      const int i = 2 * static_cast<int>(rng() % 58);
      bool apart = true;
      for (int b : bump) apart = apart && std::abs(b - i) >= 4;
      if (apart) bump.push_back(i);
    }
    bump.push_back(2 * static_cast<int>(rng() % 59) + 1);
    for (int i = 0; i < static_cast<int>(qs.size()); ++i) {
      Observation o = cell.measure(qs[i], 0.0, rng);
      if (std::count(bump.begin(), bump.end(), i)) {
        o.measured_in_tracker.translation() += (1e-3 + 2e-3 * std::abs(u(rng))) * Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
        bumped_lines[s].push_back(i + 3);  // one comment line, the header, then the rows
      }
      f.rows.push_back(measuredRow(qs[i], o));
      const bool dropped = std::count(bump.begin(), bump.end() - 1, i) || std::count(bump.begin(), bump.end() - 1, i - 1);
      if (!dropped) reference.rows.push_back(f.rows.back());
    }
    files.push_back(writeSetupFile(dir, s, f, "simulated TX60 with bumped rows"));
    clean.push_back(dir + "/clean" + std::to_string(s + 1) + ".csv");
    std::ofstream out(clean.back());
    writeMeasurementCsv(out, reference, 6, "the same without the bumped identification rows");
  }
  Process joint(dir, "joint", {"cellcal", "calibrate", "--robot", tx60, "--data", files[0], "--data", files[1],
                               "--json", dir + "/joint.json", "--save-robot", dir + "/joint.yaml"});
  ASSERT_EQ(joint.wait(60), 0) << joint.log();
  Process ref(dir, "reference", {"cellcal", "calibrate", "--robot", tx60, "--data", clean[0], "--data", clean[1],
                                 "--json", dir + "/reference.json", "--save-robot", dir + "/reference.yaml"});
  ASSERT_EQ(ref.wait(60), 0) << ref.log();
  const auto j = readJson(dir + "/joint.json"), r = readJson(dir + "/reference.json");
  // The reference's fit is a plain one: nothing among its identification rows is screened out.
  for (int s = 0; s < 2; ++s) EXPECT_TRUE(r["setups"][s]["outliers"]["identification"]["rows"].empty()) << ref.log();
  for (int s = 0; s < 2; ++s) {
    std::vector<int> listed;
    for (const auto& part : {"identification", "verification"})
      for (const auto& row : j["setups"][s]["outliers"][part]["rows"]) listed.push_back(row["line"].get<int>());
    std::sort(listed.begin(), listed.end());
    std::vector<int> expected = bumped_lines[s];
    std::sort(expected.begin(), expected.end());
    EXPECT_EQ(listed, expected) << "set-up " << s + 1 << "\n" << joint.log();
  }
  // The same model: parameters the rows cannot separate are held at start values that come from each run's own
  // registration, so they are compared by what the saved models predict (set-up 2's frames) at fresh configurations.
  const RobotModel a = loadRobotFile(dir + "/joint.yaml").model, b = loadRobotFile(dir + "/reference.yaml").model;
  const SimulatedCell poses(robot("staubli_tx60"), sc);
  KinematicsData da(a), db(b);
  double worst = 0;
  for (const auto& q : poses.randomConfigurations(200, rng))
    worst = std::max(worst, (forwardKinematics(a, da, a.nominal, q).translation() -
                             forwardKinematics(b, db, b.nominal, q).translation()).norm());
  EXPECT_LT(worst, 1e-6) << joint.log() << ref.log();
  EXPECT_NE(joint.log().find("gross errors"), std::string::npos) << joint.log();
}

TEST(CliCalibrate, SeveralSetUpsShareOneKinematicModel) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  SimulationConfig sc;
  sc.seed = seed;
  const std::string tx60 = std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml";
  std::vector<std::string> files;
  std::vector<MeasurementFile> parts;
  for (int s = 0; s < 2; ++s) {
    const SimulationConfig c = placement(sc, s, rng);
    const SimulatedCell cell(robot("staubli_tx60"), c);
    MeasurementFile f;
    for (const auto& q : cell.randomConfigurations(160, rng)) {
      const Observation o = cell.measure(q, 0.0, rng);
      f.rows.push_back(measuredRow(q, o));
    }
    files.push_back(writeSetupFile(dir, s, f, "simulated TX60"));
    parts.push_back(f);
  }
  // The same rows in one file, the two set-ups interleaved at random and named in a setup column (set-up 1 first:
  // set-ups are numbered in order of first appearance, as the files are in order of --data).
  MeasurementFile both;
  const std::vector<std::string> labels = {"north", "after-move"};
  size_t next[2] = {0, 0};
  while (next[0] < parts[0].rows.size() || next[1] < parts[1].rows.size()) {
    const int s = next[0] == 0 ? 0
                  : next[0] == parts[0].rows.size() ? 1
                  : next[1] == parts[1].rows.size() ? 0
                                                    : static_cast<int>(rng() % 2);
    MeasurementRow r = parts[s].rows[next[s]++];
    r.setup = labels[s];
    both.rows.push_back(r);
  }
  {
    std::ofstream out(dir + "/both.csv");
    writeMeasurementCsv(out, both, 6, "simulated TX60, two set-ups in one file");
  }
  Process joint(dir, "joint", {"cellcal", "calibrate", "--robot", tx60, "--data", files[0], "--data", files[1], "--json",
                               dir + "/joint.json", "--save-robot", dir + "/joint.yaml"});
  ASSERT_EQ(joint.wait(60), 0) << joint.log();
  EXPECT_NE(joint.log().find("2 set-ups, one kinematic model"), std::string::npos) << joint.log();
  const auto j = readJson(dir + "/joint.json");
  ASSERT_EQ(j["setups"].size(), 2u);
  for (int s = 0; s < 2; ++s) {
    Process own(dir, "own", {"cellcal", "calibrate", "--robot", tx60, "--data", files[s], "--json", dir + "/own.json"});
    ASSERT_EQ(own.wait(60), 0) << own.log();
    const double own_mm = readJson(dir + "/own.json")["verification"]["after"]["mean_mm"];
    const double joint_mm = j["setups"][s]["verification"]["after"]["mean_mm"];
    EXPECT_LT(joint_mm, 1.05 * own_mm) << "set-up " << s + 1 << "\n" << joint.log();
  }
  const RobotFile saved = loadRobotFile(dir + "/joint.yaml");
  ASSERT_TRUE(saved.calibration);
  EXPECT_EQ(saved.calibration->provenanceValue("frames_of"), files[1]);
  Process diag(dir, "diagnose", {"cellcal", "diagnose", "--robot", tx60, "--data", files[0], "--data", files[1]});
  EXPECT_EQ(diag.wait(60), 2);
  EXPECT_NE(diag.log().find("only `cellcal calibrate` takes several set-ups"), std::string::npos) << diag.log();
  // Set-ups are fitted by Gauss-Newton: --solver lm is refused, not ignored.
  Process lm(dir, "lm", {"cellcal", "calibrate", "--robot", tx60, "--data", files[0], "--data", files[1], "--solver", "lm"});
  EXPECT_EQ(lm.wait(60), 2);
  EXPECT_NE(lm.log().find("--solver lm takes one set-up"), std::string::npos) << lm.log();

  // The setup column: the same calibration as the two files (the reference), each set-up named by its label.
  Process col(dir, "column", {"cellcal", "calibrate", "--robot", tx60, "--data", dir + "/both.csv", "--json",
                              dir + "/both.json"});
  ASSERT_EQ(col.wait(60), 0) << col.log();
  const auto b = readJson(dir + "/both.json");
  ASSERT_EQ(b["setups"].size(), 2u) << col.log();
  EXPECT_EQ(b["setups"][0]["data"], dir + "/both.csv [setup north]");
  EXPECT_EQ(b["setups"][1]["data"], dir + "/both.csv [setup after-move]");
  ASSERT_EQ(b["parameters"].size(), j["parameters"].size());
  for (size_t k = 0; k < j["parameters"].size(); ++k)
    EXPECT_NEAR(b["parameters"][k]["value"].get<double>(), j["parameters"][k]["value"].get<double>(), 1e-9)
        << j["parameters"][k]["name"];
  for (int s = 0; s < 2; ++s)
    EXPECT_NEAR(b["setups"][s]["verification"]["after"]["mean_mm"].get<double>(),
                j["setups"][s]["verification"]["after"]["mean_mm"].get<double>(), 1e-9);
  // Other commands take one set-up, and say so; a row without a label among labelled ones is named.
  Process diag2(dir, "diagnose2", {"cellcal", "diagnose", "--robot", tx60, "--data", dir + "/both.csv"});
  EXPECT_EQ(diag2.wait(60), 2);
  EXPECT_NE(diag2.log().find("rows of 2 set-ups (column setup: north, after-move)"), std::string::npos) << diag2.log();
  both.rows[7].setup.reset();
  {
    std::ofstream out(dir + "/unlabelled.csv");
    writeMeasurementCsv(out, both, 6, "");
  }
  Process bad(dir, "unlabelled", {"cellcal", "calibrate", "--robot", tx60, "--data", dir + "/unlabelled.csv"});
  EXPECT_EQ(bad.wait(60), 2);
  EXPECT_NE(bad.log().find("line " + std::to_string(7 + 2) + ": setup: empty, while other rows name their set-up"),
            std::string::npos)
      << bad.log();
}

// `cellcal continuous` on a file of a simulated robot warming up over 6 h (stamps and temperatures in the file,
// placement unknown to the robot file): RLS with 18 fresh poses per half hour beats the one-off calibration, and a
// file without stamps is refused with its line named, and runs with --period-s as with its stamps.
TEST(CliContinuous, RunsAFileInTimeOrder) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  SimulationConfig sc;
  sc.seed = seed;
  sc.warmup_K = 8.0;
  const SimulatedCell cell(robot("staubli_tx60"), sc);
  std::mt19937_64 rng(seed);
  MeasurementFile f;
  const auto qs = cell.randomConfigurations(720, rng);
  for (size_t i = 0; i < qs.size(); ++i) {
    const double t_h = static_cast<double>(i) / 120.0;
    const Observation o = cell.measure(qs[i], t_h, rng);
    MeasurementRow r;
    r.line = static_cast<int>(i) + 2;
    r.q_rad = qs[i];
    r.position_m = o.measured_in_tracker.translation();
    r.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
    r.stamp_s = t_h * 3600.0;
    r.temperature_c = cell.temperatureC(t_h);
    f.rows.push_back(r);
  }
  {
    std::ofstream out(dir + "/m.csv");
    writeMeasurementCsv(out, f, 6, "simulated TX60 warming up");
  }
  const std::string robot_file = std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml";
  Process p(dir, "continuous", {"cellcal", "continuous", "--robot", robot_file, "--data", dir + "/m.csv", "--json",
                                dir + "/c.json", "--sigma-position-mm", "0.012", "--quiet"});
  ASSERT_EQ(p.wait(60), 0) << p.log();
  const auto j = readJson(dir + "/c.json");
  EXPECT_EQ(j["updates"], 11) << p.log();
  EXPECT_EQ(j["intervals"].size(), 11u);
  EXPECT_EQ(j["intervals"][0]["poses_used"], 18);
  EXPECT_LT(j["rls"]["mean_mm"].get<double>(), j["static"]["mean_mm"].get<double>()) << p.log();
  for (auto& r : f.rows) r.stamp_s.reset();
  {
    std::ofstream out(dir + "/nostamp.csv");
    writeMeasurementCsv(out, f, 6, "no stamps");
  }
  Process bad(dir, "continuous_bad", {"cellcal", "continuous", "--robot", robot_file, "--data", dir + "/nostamp.csv"});
  EXPECT_NE(bad.wait(30), 0);
  EXPECT_NE(bad.log().find("nostamp.csv:"), std::string::npos) << bad.log();
  EXPECT_NE(bad.log().find("stamp_s"), std::string::npos) << bad.log();
  // With --period-s (the rows are 30 s apart): the same file, the same result as with its stamps.
  Process periodic(dir, "continuous_period", {"cellcal", "continuous", "--robot", robot_file, "--data", dir + "/nostamp.csv",
                                              "--period-s", "30", "--json", dir + "/p.json", "--sigma-position-mm", "0.012",
                                              "--quiet"});
  ASSERT_EQ(periodic.wait(60), 0) << periodic.log();
  const auto pj = readJson(dir + "/p.json");
  EXPECT_EQ(pj["updates"], j["updates"]);
  EXPECT_NEAR(pj["rls"]["mean_mm"].get<double>(), j["rls"]["mean_mm"].get<double>(), 1e-9) << periodic.log();
}

// Identification rows from one corner of the workspace, verification rows from all of it (`--split halves`): the
// robot, the frames, the measurement type, the model (geometric or a joint compliance) and which corner (one wrist
// orientation; the upper arm within a 10 deg band; the forearm within a 10 deg band) drawn at random. Whatever the
// draw, calibrate never exits 0 with a verification max above 3x the identification max, and says why when it
// exits 4; every parameter it holds for an excitation deficit is named in the JSON.
TEST(CliCalibrate, ExtrapolationIsNeverReportedAsSuccess) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int exits_4 = 0, exits_0 = 0, held_named = 0;
  for (int d = 0; d < 6; ++d) {
    const RandomDraw draw = randomDraw(rng);
    const std::string& name = draw.name;
    const MeasurementKind kind = draw.kind;
    const RobotModel model = robot(name);
    const SimulatedCell cell(model, draw.sc);
    const int corner = static_cast<int>(3 * u(rng));
    const Eigen::VectorXd q0 = cell.randomConfigurations(1, rng).front();
    MeasurementFile f;
    auto add = [&](const Eigen::VectorXd& q) { f.rows.push_back(measuredRow(q, cell.measure(q, 0.0, rng, kind))); };
    for (Eigen::VectorXd q : cell.randomConfigurations(120, rng)) {
      if (corner == 0) q.tail(3) = q0.tail(3) + 0.01 * Eigen::Vector3d::Random();
      else q[corner] = q0[corner] + (u(rng) - 0.5) * 10 * kPi / 180;
      if (model.withinLimits(q)) add(q);
    }
    const int ident_rows = static_cast<int>(f.rows.size());
    for (const auto& q : cell.randomConfigurations(ident_rows, rng)) add(q);
    {
      std::ofstream out(dir + "/x.csv");
      writeMeasurementCsv(out, f, model.numJoints(), "identification rows from one corner");
    }
    const std::string spec = u(rng) < 0.5 ? "geometric" : "joint_compliance:" + std::to_string(2 + static_cast<int>(2 * u(rng)));
    Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml",
                                 "--data", dir + "/x.csv", "--split", "halves", "--model", spec, "--json", dir + "/x.json"});
    const int code = p.wait(120);
    ASSERT_TRUE(code == 0 || code == 4 || code == 3) << p.log();
    const auto j = readJson(dir + "/x.json");
    const double ident_max = j["identification"]["after"]["max_mm"], verify_max = j["verification_without_outliers"]["after"]["max_mm"];
    std::printf("draw %d: %s %s, corner %d, %s: identification max %.3f mm, verification max %.3f mm, exit %d, %zu held\n",
                d, name.c_str(), kind == MeasurementKind::kPose6D ? "6D" : "points", corner, spec.c_str(), ident_max,
                verify_max, code, j["held"].size());
    if (code == 0) {
      ++exits_0;
      EXPECT_LE(verify_max, 3 * ident_max + 1e-9) << p.log();
    }
    if (code == 4) {
      ++exits_4;
      EXPECT_NE(p.log().find("not usable:"), std::string::npos) << p.log();
      EXPECT_TRUE(j["unusable"].is_string());
    }
    for (const auto& h : j["held"]) {
      EXPECT_NE(p.log().find("held: " + h["name"].get<std::string>()), std::string::npos) << p.log();
      ++held_named;
    }
  }
  std::printf("%d draws exit 0, %d exit 4 (not usable); %d parameters held and named\n", exits_0, exits_4, held_named);
}

// A model carried to a new set-up (`calibrate --frames-only`): a campaign calibrated and saved, then the tracker
// moved; robot, measurement type and placements drawn at random. The frames registered on the new rows get their own
// uncertainty: every frame parameter the rows determine (all 12 from 6D readings, 9 from points: no tool rotation) a
// finite sigma, and the variance factor of what they leave, at most about 1 with the campaign's kinematics (only noise)
// and far above it with the robot file's nominal ones (their error shows in the residual, and the frames' sigmas
// widen with it). The predicted model error is the file's covariance less what the new frames take up of it
// (carriedPrediction): actual / predicted near 1 with the campaign's file, far below it with the nominal file's priors.
TEST(CliCalibrate, FramesOnlyGivesTheFramesTheirOwnUncertainty) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  for (int d = 0; d < 3; ++d) {
    const RandomDraw draw = randomDraw(rng);
    const std::string& name = draw.name;
    const MeasurementKind kind = draw.kind;
    const RobotModel model = robot(name);
    const std::string nominal = std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml";
    const SimulatedCell campaign(model, draw.sc), moved(model, placement(draw.sc, 1, rng));
    auto write = [&](const SimulatedCell& cell, const std::string& path) {
      MeasurementFile f;
      for (const auto& q : cell.randomConfigurations(120, rng))
        f.rows.push_back(measuredRow(q, cell.measure(q, 0.0, rng, kind)));
      std::ofstream out(path);
      writeMeasurementCsv(out, f, model.numJoints(), "simulated");
    };
    write(campaign, dir + "/campaign.csv");
    write(moved, dir + "/moved.csv");
    const std::string what = name + (kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", draw " + std::to_string(d);
    Process c(dir, "campaign", {"cellcal", "calibrate", "--robot", nominal, "--data", dir + "/campaign.csv",
                                "--save-robot", dir + "/campaign.yaml"});
    ASSERT_EQ(c.wait(120), 0) << what << "\n" << c.log();
    double factor[2], base_x_sigma[2], ratio[2];
    for (int k = 0; k < 2; ++k) {
      const std::string file = k == 0 ? dir + "/campaign.yaml" : nominal, tag = k == 0 ? "calibrated" : "nominal";
      Process p(dir, "frames_" + tag, {"cellcal", "calibrate", "--robot", file, "--data", dir + "/moved.csv",
                                       "--frames-only", "--json", dir + "/" + tag + ".json"});
      const int code = p.wait(120);
      ASSERT_TRUE(code == 0 || (k == 1 && code == 4)) << what << "\n" << p.log();  // nominal may be unusable
      const auto j = readJson(dir + "/" + tag + ".json");
      ASSERT_TRUE(j["prediction"].is_object()) << what;
      ratio[k] = j["prediction"]["actual_over_predicted_rms"];
      EXPECT_NE(p.log().find(k == 0 ? "the robot file's covariance less what the new frames take up"
                                    : "the priors of an uncalibrated model less what the new frames take up"),
                std::string::npos) << p.log();
      factor[k] = j["frames_variance_factor"];
      int frames = 0;
      for (const auto& prm : j["parameters"]) {
        const std::string n = prm["name"];
        if ((n.rfind("base.", 0) != 0 && n.rfind("tool.", 0) != 0) || !prm["estimated"].get<bool>()) continue;
        ++frames;
        EXPECT_TRUE(prm["stddev"].is_number() && prm["stddev"].get<double>() > 0) << what << ": " << prm.dump();
        if (n == "base.x_mm") base_x_sigma[k] = prm["stddev"].get<double>() * std::sqrt(std::max(1.0, factor[k]));
      }
      EXPECT_EQ(frames, kind == MeasurementKind::kPose6D ? 12 : 9) << what << "\n" << p.log();
    }
    EXPECT_GT(factor[0], 0.0) << what;  // below 1 where the file's default sigma exceeds the simulated noise (0.37-0.6)
    EXPECT_LT(factor[0], 3.0) << what << ": the campaign's kinematics leave more than noise on the moved set-up";
    EXPECT_GT(factor[1], 10 * factor[0]) << what << ": the nominal kinematics' error does not show in the residual";
    EXPECT_GT(base_x_sigma[1], base_x_sigma[0]) << what;
    // The predicted model error on the moved set-up: the campaign's covariance carried (actual / predicted near 1;
    // 120 held-out rows: RMS within a few tenths of it), the nominal file's priors (wide: far below 1).
    EXPECT_GT(ratio[0], 0.6) << what;
    EXPECT_LT(ratio[0], 1.6) << what;
    EXPECT_LT(ratio[1], ratio[0]) << what;
    std::printf("  %s: frames' variance factor %.2f with the campaign's kinematics, %.1f with the nominal ones; "
                "base.x sigma %.4f / %.4f mm; actual / predicted RMS %.2f / %.2f\n", what.c_str(), factor[0], factor[1],
                base_x_sigma[0], base_x_sigma[1], ratio[0], ratio[1]);
  }
}

// Extensions carried to a new set-up (`calibrate --frames-only`) are judged against the same campaign's geometric
// calibration, saved beside them in the robot file, on the new rows. Robot, measurement type, placements drawn at
// random; joint 2 or 3 has an error the library does not have (a bump of 0.1-0.3 deg over 0.2 rad of its angle) in
// the 60 % of its range the campaign measured, and `calibrate --model cyclic_transmission:J` fits it there. On a
// set-up measuring the rest of that joint's range the cyclic term no longer holds: where it is clearly worse than the
// geometric calibration carried the same way (by half or more), the geometric one is used and said; the result is no
// worse than it. A true cyclic error over the whole range transfers and is kept.
TEST(CliCalibrate, FramesOnlyJudgesTheCarriedExtensionsAgainstTheGeometricCalibration) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int judged = 0;
  for (int d = 0; d < 4; ++d) {
    const bool bump = d % 2 == 0;
    const RandomDraw draw = randomDraw(rng);
    const RobotModel model = robot(draw.name);
    const std::string nominal = std::string(CELLCAL_CONFIG_DIR) + "/robots/" + draw.name + ".yaml";
    SimulationConfig sc = draw.steadySc();
    const int j = 1 + static_cast<int>(u(rng) * 2);
    const double amplitude_rad = (0.1 + 0.2 * u(rng)) * kPi / 180;
    Eigen::Vector4d harmonics = Eigen::Vector4d::Zero();
    for (int k = 0; k < 4; ++k) harmonics[k] = (2 * u(rng) - 1) * amplitude_rad / 2;
    const SimulatedCell campaign(model, sc), moved(model, placement(sc, 1, rng));
    std::vector<Eigen::VectorXd> qs = campaign.randomConfigurations(1200, rng);
    std::vector<double> sorted;
    for (const auto& q : qs) sorted.push_back(q[j]);
    std::sort(sorted.begin(), sorted.end());
    const double cut = sorted[sorted.size() * 6 / 10], centre = sorted[sorted.size() * 3 / 10];
    auto error = [&](const Eigen::VectorXd& q) {
      const double x = q[j];
      return bump ? amplitude_rad * std::exp(-0.5 * (x - centre) * (x - centre) / 0.04)
                  : harmonics.dot(Eigen::Vector4d(std::sin(x), std::cos(x), std::sin(2 * x), std::cos(2 * x)));
    };
    MeasurementFile inside, beyond;
    for (const auto& q : qs) {
      Eigen::VectorXd qt = q;
      qt[j] += error(q);
      const bool in = q[j] < cut;
      const SimulatedCell& cell = in ? campaign : moved;
      if ((in ? inside : beyond).rows.size() < 400)
        (in ? inside : beyond).rows.push_back(measuredRow(q, cell.measurePose(cell.truePose(qt, 0.0), q, rng, draw.kind)));
    }
    for (auto* f : {&inside, &beyond}) {
      std::ofstream out(dir + (f == &inside ? "/campaign.csv" : "/beyond.csv"));
      writeMeasurementCsv(out, *f, model.numJoints(), "simulated");
    }
    const std::string what = draw.name + (draw.kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", joint " +
                             std::to_string(j + 1) + (bump ? " bump" : " cyclic error");
    Process c(dir, "campaign", {"cellcal", "calibrate", "--robot", nominal, "--data", dir + "/campaign.csv", "--model",
                                "cyclic_transmission:" + std::to_string(j + 1), "--save-robot", dir + "/campaign.yaml"});
    ASSERT_EQ(c.wait(120), 0) << what << "\n" << c.log();
    ASSERT_NE(readTextFile(dir + "/campaign.yaml").find("geometric_parameters:"), std::string::npos);
    // What the cyclic term may do beyond the campaign's range of joint j (its region folds): saved, and carried.
    const RobotFile saved = loadRobotFile(dir + "/campaign.yaml");
    ASSERT_TRUE(saved.calibration.has_value());
    const std::vector<BeyondRange> beyond_data = saved.calibration->beyond_data;
    EXPECT_EQ(beyond_data.size(), 1u) << what;  // every joint with an extension, held or not
    for (const auto& b : beyond_data) EXPECT_EQ(b.joint, j) << what;
    if (!beyond_data.empty()) {
      RobotCalibration stripped = *saved.calibration;
      stripped.beyond_data.clear();
      saveRobotFile(dir + "/stripped.yaml", saved.model, &stripped, "", &saved.source);
      double ratio[2] = {0, 0};
      int flagged = 0;  // rows of beyond.csv farther beyond the range than the folds judged
      for (int w = 0; w < 2; ++w) {
        Process k(dir, "carry", {"cellcal", "calibrate", "--robot", dir + (w ? "/campaign.yaml" : "/stripped.yaml"), "--data",
                                 dir + "/beyond.csv", "--frames-only", "--keep-extensions", "--json", dir + "/c.json"});
        const int kc = k.wait(120);
        ASSERT_TRUE(kc == 0 || kc == 4) << k.log();
        const auto kj = readJson(dir + "/c.json");
        ratio[w] = kj["prediction"]["actual_over_predicted_rms"];
        EXPECT_EQ(kj["beyond_data"]["ranges"].size(), w ? beyond_data.size() : 0u) << k.log();
        if (w) {
          EXPECT_NE(k.log().find("carried beyond the campaign's data: joint " + std::to_string(j + 1)), std::string::npos) << k.log();
          flagged = kj["prediction"]["verification_rows_beyond_checked_range"];
        } else {
          EXPECT_EQ(kj["prediction"]["verification_rows_beyond_checked_range"], 0) << k.log();
        }
      }
      const BeyondRange& b = beyond_data.front();
      std::printf("  %s: beyond_data carried (sigma %.3g deg, judged %.1f deg beyond): actual / predicted %.2f without "
                  "it, %.2f with it; %d verification rows farther than judged\n",
                  what.c_str(), b.sigma_at_1_rad * 180 / kPi, b.checked_rad * 180 / kPi, ratio[0], ratio[1], flagged);
      // Every row of beyond.csv lies beyond the campaign's range of joint j: a sigma there raises the prediction; a
      // joint whose folds held (sigma 0) keeps its range and judged distance only, and predicts as without it.
      if (b.sigma_at_1_rad > 0) {
        EXPECT_LT(ratio[1], ratio[0]) << what;
      } else {
        EXPECT_NEAR(ratio[1], ratio[0], 1e-6 * ratio[0]) << what;  // the stripped file is the saved one written again
      }
    }
    Process f(dir, "frames", {"cellcal", "calibrate", "--robot", dir + "/campaign.yaml", "--data", dir + "/beyond.csv",
                              "--frames-only", "--json", dir + "/f.json"});
    const int code = f.wait(120);
    ASSERT_TRUE(code == 0 || code == 4) << what << "\n" << f.log();
    const auto j_out = readJson(dir + "/f.json");
    const auto& ce = j_out["carried_extensions"];
    ASSERT_TRUE(ce.is_object()) << what << "\n" << f.log();
    const double ext_mm = ce["mean_extended_mm"], geo_mm = ce["mean_geometric_mm"];
    const bool transfer = ce["transfer"];
    std::printf("  %s: carried beyond the campaign, extended %.4f mm, geometric %.4f mm, z %.1f: %s\n", what.c_str(),
                ext_mm, geo_mm, ce["z"].get<double>(), transfer ? "transfers" : "does not transfer");
    EXPECT_EQ(ce["used"], transfer ? "extended" : "geometric") << what;
    EXPECT_NE(f.log().find(transfer ? "hold on these rows" : "do not transfer"), std::string::npos) << f.log();
    if (!transfer) {  // the result is the geometric calibration's
      EXPECT_LE(j_out["verification"]["after"]["mean_mm"].get<double>(), 1.05 * geo_mm) << what << "\n" << f.log();
    }
    if (bump && ext_mm > 1.5 * geo_mm) {
      ++judged;
      EXPECT_FALSE(transfer) << what << "\n" << f.log();
    }
    if (!bump && amplitude_rad > 0.15 * kPi / 180) {
      ++judged;
      EXPECT_TRUE(transfer) << what << "\n" << f.log();
    }
    if (!transfer) {
      Process k(dir, "keep", {"cellcal", "calibrate", "--robot", dir + "/campaign.yaml", "--data", dir + "/beyond.csv",
                              "--frames-only", "--keep-extensions", "--json", dir + "/k.json"});
      k.wait(120);
      EXPECT_EQ(readJson(dir + "/k.json")["carried_extensions"]["used"], "extended") << k.log();
    }
  }
  std::printf("  %d of 4 draws judged\n", judged);
  EXPECT_GE(judged, 2);
}

// An extension a driver bounds, carried beyond the driver's range of its campaign: a link deflection (a drawn beam
// link) that is quadratic in the gravity across the link (outside the library, whose deflection is linear in it),
// measured on the 60 % of rows with the least gravity across it; `calibrate --model link_deflection:L` saves the
// range of that gravity, how far its folds judged it and the further error they measured (beyond_drivers); a set-up
// measuring the other rows carries it with --frames-only: said, in --json, in the prediction (a sigma raises it) and
// rows farther than judged are counted. Robot, measurement type, placements, size drawn at random.
TEST(CliCalibrate, ALinkDeflectionsRangeOfLoadIsSavedAndCarried) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed() + 7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int d = 0; d < 2; ++d) {
    const RandomDraw draw = randomDraw(rng);
    const RobotModel model = robot(draw.name);
    const std::string nominal = std::string(CELLCAL_CONFIG_DIR) + "/robots/" + draw.name + ".yaml";
    SimulationConfig sc = draw.steadySc();
    const SimulatedCell campaign(model, sc), moved(model, placement(sc, 1, rng));
    const Eigen::VectorXd truth = campaign.trueParams(0);
    std::vector<int> beams;
    for (int j = 0; j < model.numJoints(); ++j)
      if (applicable(model, Extension{Cause::kLinkDeflection, j}, false)) beams.push_back(j);
    const int link = beams[static_cast<size_t>(u(rng) * beams.size())];
    const Extension e{Cause::kLinkDeflection, link};
    const std::vector<Eigen::VectorXd> qs = campaign.randomConfigurations(1200, rng);
    std::vector<double> x;
    for (const auto& q : qs) x.push_back(causeModel(Cause::kLinkDeflection).rangeValue(model, truth, e, q, Drivers{}));
    std::vector<double> sorted = x;
    std::sort(sorted.begin(), sorted.end());
    const double cut = sorted[sorted.size() * 6 / 10], mean_in = sorted[sorted.size() * 3 / 10];
    const double size_rad = (0.05 + 0.1 * u(rng)) * kPi / 180 * (u(rng) < 0.5 ? 1 : -1);
    const double length = linkLength(model, truth, link);
    test::detail::Cartesian bend;
    bend.link = link;
    MeasurementFile inside, beyond;
    std::vector<size_t> written;  // the rows of beyond.csv
    for (size_t i = 0; i < qs.size(); ++i) {
      const double f = x[i] / mean_in;  // quadratic in the gravity across the link
      bend.sag_m = size_rad * length * f;
      bend.slope_rad = 1.4 * size_rad * f;
      const bool in = x[i] < cut;
      const SimulatedCell& cell = in ? campaign : moved;
      const Eigen::VectorXd cell_truth = cell.trueParams(0);
      const Pose T = bend.apply(model, cell_truth, qs[i], forwardKinematics(model, cell_truth, qs[i]), 0.0);
      if ((in ? inside : beyond).rows.size() < 400) {
        (in ? inside : beyond).rows.push_back(measuredRow(qs[i], cell.measurePose(T, qs[i], rng, draw.kind)));
        if (!in) written.push_back(i);
      }
    }
    for (auto* f : {&inside, &beyond}) {
      std::ofstream out(dir + (f == &inside ? "/campaign.csv" : "/beyond.csv"));
      writeMeasurementCsv(out, *f, model.numJoints(), "simulated");
    }
    const std::string what = draw.name + (draw.kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", link " +
                             std::to_string(link + 1);
    Process c(dir, "campaign", {"cellcal", "calibrate", "--robot", nominal, "--data", dir + "/campaign.csv", "--model",
                                extensionSpec(e), "--save-robot", dir + "/campaign.yaml"});
    ASSERT_EQ(c.wait(120), 0) << what << "\n" << c.log();
    EXPECT_NE(c.log().find("link_deflection link " + std::to_string(link + 1) + " by gravity across link"),
              std::string::npos) << c.log();
    const RobotFile saved = loadRobotFile(dir + "/campaign.yaml");
    ASSERT_TRUE(saved.calibration.has_value());
    ASSERT_EQ(saved.calibration->beyond_drivers.size(), 1u) << what << "\n" << c.log();
    const DriverRange r = saved.calibration->beyond_drivers.front();
    EXPECT_EQ(extensionSpec(r.extension), extensionSpec(e));
    EXPECT_LT(r.upper, cut + 0.02) << what;  // the campaign's gravity (at the fitted kinematics)
    EXPECT_GT(r.upper, sorted[sorted.size() * 5 / 10]) << what;
    RobotCalibration stripped = *saved.calibration;
    stripped.beyond_drivers.clear();
    saveRobotFile(dir + "/stripped.yaml", saved.model, &stripped, "", &saved.source);
    double ratio[2] = {0, 0};
    int flagged = 0;
    for (int w = 0; w < 2; ++w) {
      Process k(dir, "carry", {"cellcal", "calibrate", "--robot", dir + (w ? "/campaign.yaml" : "/stripped.yaml"), "--data",
                               dir + "/beyond.csv", "--frames-only", "--keep-extensions", "--json", dir + "/c.json"});
      const int kc = k.wait(120);
      ASSERT_TRUE(kc == 0 || kc == 4) << k.log();
      const auto kj = readJson(dir + "/c.json");
      ratio[w] = kj["prediction"]["actual_over_predicted_rms"];
      EXPECT_EQ(kj["beyond_data"]["driver_ranges"].size(), w ? 1u : 0u) << k.log();
      if (w) {
        EXPECT_NE(k.log().find("carried beyond the campaign's data: link_deflection link " + std::to_string(link + 1)),
                  std::string::npos) << k.log();
        flagged = kj["prediction"]["verification_rows_beyond_checked_range"];
      }
    }
    std::printf("  %s, deflection %.3f deg at 1 g: beyond_drivers carried (%s, sigma %.3g mm%s, %s): actual / predicted "
                "%.2f without it, %.2f with it; %d verification rows farther than judged\n",
                what.c_str(), size_rad * 180 / kPi, r.rangeText().c_str(), r.sigma_at_1_m * 1e3, r.growthText().c_str(),
                r.judgedText().c_str(), ratio[0], ratio[1], flagged);
    // The rows of beyond.csv farther than judged, by the gravity at the true kinematics (a margin for the fitted ones).
    int far = 0, near = 0;
    for (size_t i : written) {
      far += x[i] > r.upper + r.checked_above + 0.01;
      near += x[i] < r.upper + r.checked_above - 0.01;
    }
    if (far > 0 || near == 0) {
      EXPECT_GT(flagged, 0) << what;
    }
    EXPECT_LT(flagged, static_cast<int>(beyond.rows.size())) << what;
    if (r.sigma_at_1_m > 0) {
      EXPECT_LT(ratio[1], ratio[0]) << what;
    } else {
      EXPECT_NEAR(ratio[1], ratio[0], 1e-6 * ratio[0]) << what;
    }
  }
}

// A fit that did not converge never exits 0, and by default the fit converges where rank alone does not. Files as a
// real UR5 grid gave (issue #35): a Cartesian grid at one tool orientation, points, the target 0.1-0.2 mm off the
// flange axis, a compliance of joint 2 or 3 the geometric model does not hold (random size), on the UR10 at random
// placements. Drawn until `calibrate` with rank alone deciding (--plausible-length-mm 0 --plausible-angle-deg 0
// --rank-tolerance 1e-8 --excitation-ratio 0) does not converge (about one file in 25; the TX60 converged in every draw tried): then
// `calibrate --model auto` on that file with the same options exits 3 and saves nothing, `diagnose` exits 3 when its
// geometric or extended fit did not converge, by default (plausible ranges) `calibrate` converges, and `calibrate
// --model auto` exits 3 exactly when its fit did not converge.
TEST(CliCalibrate, AFitThatDidNotConvergeNeverExitsZero) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  std::uniform_real_distribution<double> u(0, 1);
  const std::vector<std::string> rank_only = {"--plausible-length-mm", "0", "--plausible-angle-deg", "0",
                                              "--rank-tolerance", "1e-8", "--excitation-ratio", "0"};
  auto run = [&](const std::string& name, const std::string& robot_file, std::vector<std::string> extra) {
    std::vector<std::string> args = {"cellcal", "calibrate", "--robot", robot_file, "--data", dir + "/grid.csv",
                                     "--position-only", "--json", dir + "/" + name + ".json"};
    args.insert(args.end(), extra.begin(), extra.end());
    Process p(dir, name, args);
    const int code = p.wait(120);
    return std::make_pair(code, p.log());
  };
  // About one file in 25 (first such draw at 23, 11, 1, 26, 74 and 29 for seeds 11-16): 60 draws missed in one CI run
  // in ten (addb831's skipped it); 200 miss with odds of about 4e-4, and a draw takes 0.2 s.
  constexpr int kMaxDraws = 200;
  int draws = 0;
  for (; draws < kMaxDraws; ++draws) {
    const std::string name = "ur10";
    const std::string robot_file = std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml";
    const RobotModel model = robot(name);
    SimulationConfig sc = randomPlacement(rng);
    nearAxisTarget(sc, rng);
    const SimulatedCell plain(model, sc);
    const std::vector<Eigen::VectorXd> qs = gridAtOneOrientation(plain, 6, rng);
    if (qs.size() < 100) continue;
    const int joint = 1 + static_cast<int>(2 * u(rng)) % 2;
    sc.hidden = scaledHiddenEffect(plain.model(), plain.trueParams(0), Cause::kJointCompliance, joint,
                                   (0.03 + 0.05 * u(rng)) * kPi / 180,
                                   model.links.empty() ? plausibleLinks(plain.model(), plain.trueParams(0), rng) : model.links,
                                   qs, rng);
    const SimulatedCell cell(model, sc);
    MeasurementFile f;
    for (const auto& q : qs) f.rows.push_back(measuredRow(q, cell.measure(q, 0.0, rng, MeasurementKind::kPosition3D)));
    {
      std::ofstream out(dir + "/grid.csv");
      writeMeasurementCsv(out, f, 6, "simulated grid at one tool orientation");
    }
    const auto [code, log] = run("rank_only", robot_file, rank_only);
    if (readJson(dir + "/rank_only.json")["converged"].get<bool>()) {
      ASSERT_NE(code, 3) << log;
      continue;
    }
    ASSERT_EQ(code, 3) << log;
    std::printf("draw %d (%s, joint %d compliance): rank alone does not converge\n", draws + 1, name.c_str(), joint + 1);
    std::vector<std::string> auto_rank = rank_only;
    for (const std::string& a : {std::string("--model"), std::string("auto"), std::string("--save-robot"), dir + "/auto.yaml"})
      auto_rank.push_back(a);
    const auto [auto_code, auto_log] = run("auto_rank_only", robot_file, auto_rank);
    EXPECT_EQ(auto_code, 3) << auto_log;
    EXPECT_FALSE(readJson(dir + "/auto_rank_only.json")["converged"].get<bool>()) << auto_log;
    EXPECT_FALSE(std::ifstream(dir + "/auto.yaml").good()) << auto_log;
    std::vector<std::string> diag = {"cellcal", "diagnose", "--robot", robot_file, "--data", dir + "/grid.csv",
                                     "--position-only", "--no-progress", "--json", dir + "/diagnose.json"};
    diag.insert(diag.end(), rank_only.begin(), rank_only.begin() + 4);  // diagnose keeps the default rank tolerance
    Process d(dir, "diagnose", diag);
    const int diag_code = d.wait(300);
    ASSERT_TRUE(diag_code == 0 || diag_code == 3 || diag_code == 4) << d.log();
    const auto dj = readJson(dir + "/diagnose.json");
    if (!dj["geometric"]["converged"].get<bool>() || !dj["extended"]["converged"].get<bool>()) {
      EXPECT_EQ(diag_code, 3) << d.log();
    }
    const auto [def_code, def_log] = run("default", robot_file, {});
    EXPECT_NE(def_code, 3) << def_log;  // 4 where the effect the model does not hold makes it no better than nominal
    const auto dflt = readJson(dir + "/default.json");
    EXPECT_TRUE(dflt["converged"].get<bool>()) << def_log;
    // It decided otherwise than rank alone: held parameters within their plausible ranges, or, by the default rank
    // tolerance (1e-5, against 1e-8 here), another set (seed 4's sixth draw: joint 5's offset held instead of its a,
    // nothing within the ranges).
    EXPECT_TRUE(!dflt["identifiability"]["held_within_plausible"].empty() ||
                dflt["identifiability"]["not_identifiable"] != readJson(dir + "/rank_only.json")["identifiability"]["not_identifiable"])
        << def_log;
    // The extended model chosen by default can still fail to converge (an extension column has no plausible range:
    // seed 7189369393246471111, joint 3's compliance, 50 iterations): then it must say so with exit 3, never 0.
    const auto [def_auto_code, def_auto_log] = run("default_auto", robot_file, {"--model", "auto"});
    EXPECT_EQ(def_auto_code == 3, !readJson(dir + "/default_auto.json")["converged"].get<bool>()) << def_auto_log;
    if (def_auto_code == 3) std::printf("default --model auto did not converge either (exit 3)\n");
    break;
  }
  if (draws == kMaxDraws) GTEST_SKIP() << "no draw of " << kMaxDraws << " where rank alone does not converge";
}

TEST(CliCalibrate, BadFilesAreNamedWithLineAndColumn) {
  const std::string dir = testDir();
  std::ofstream(dir + "/bad.csv") << "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n1,2,3,4,5,6,1,2,3\n1,2,3,4,5,six,1,2,3\n";
  Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml",
                               "--data", dir + "/bad.csv"});
  EXPECT_NE(p.wait(30), 0);
  EXPECT_NE(p.log().find("bad.csv:3:6: q6_deg: 'six' is not a finite number"), std::string::npos) << p.log();
}


// Usage errors exit 2 as --help documents (CLI11's own codes are 105, 106, ...); --help exits 0; a file to write
// into a folder that does not exist yet gets its folder.
TEST(CliUsage, UsageErrorsExitTwoAndOutputFoldersAreMade) {
  const std::string dir = testDir();
  const std::string tx60 = std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml";
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"cellcal", "calibrate", "--robot", tx60},           // required --data missing
        std::vector<std::string>{"cellcal", "calibrate", "--no-such-option"},         // unknown option
        std::vector<std::string>{"cellcal", "validate", dir + "/none.mcap"},          // not an existing file
        std::vector<std::string>{"cellcal"}}) {                                        // no subcommand
    Process p(dir, "usage", args);
    EXPECT_EQ(p.wait(30), 2) << args.back() << "\n" << p.log();
  }
  Process help(dir, "help", {"cellcal", "calibrate", "--help"});
  EXPECT_EQ(help.wait(30), 0) << help.log();
  std::ofstream(dir + "/m.csv") << "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n1,2,3,4,5,6,1,2,3\n";
  Process imp(dir, "import", {"cellcal", "import", "csv", dir + "/m.csv", "--robot", tx60, "--out",
                              dir + "/made/here/m.mcap"});
  EXPECT_EQ(imp.wait(30), 0) << imp.log();
  EXPECT_TRUE(std::filesystem::exists(dir + "/made/here/m.mcap"));
}

// A drawn file written as dir/m.csv; the robot file of its robot and its readings' position sigma (mm).
struct WrittenDraw {
  std::string robot_file;
  double sigma_mm = 0;
};
WrittenDraw writeDraw(const std::string& dir, const HiddenEffectData& h, const char* comment) {
  std::ofstream out(dir + "/m.csv");
  writeMeasurementCsv(out, h.file, 6, comment);
  return {std::string(CELLCAL_CONFIG_DIR) + "/robots/" + h.draw.robot + ".yaml",
          h.data.verification.front().sigma_position_m * 1e3};
}

// `calibrate --report`: report.md gives the held-out figures --json gives (mean, RMS, 99.7th percentile and max
// before and after, on the verification rows without their gross errors), a row of the
// figures' data per such row, the three figures drawn, and every estimated parameter with the value and sigma of the
// JSON. A file with an effect hidden in it and gross errors (robot, placements, points or 6D drawn at random).
TEST(CliCalibrate, AReportShowsTheHeldOutErrorsTheJsonGives) {
  const std::string dir = testDir();
  DrawOptions o;
  o.poses = 200;
  o.max_outlier_fraction = 0.03;
  const HiddenEffectData h = makeHiddenEffectData(o, testSeed());
  const auto [robot_file, sigma_mm] = writeDraw(dir, h, "simulated robot with a hidden effect");
  Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", robot_file, "--data", dir + "/m.csv", "--json",
                               dir + "/c.json", "--report", dir + "/report", "--sigma-position-mm", std::to_string(sigma_mm)});
  ASSERT_EQ(p.wait(120), 0) << p.log();
  const auto j = readJson(dir + "/c.json");
  std::ifstream in(dir + "/report/report.md");
  ASSERT_TRUE(in) << p.log();
  std::map<std::string, std::vector<double>> table;  // first cell -> the figures after it
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("| ", 0) != 0) continue;
    std::vector<std::string> cells;
    std::stringstream ss(line.substr(1));
    for (std::string c; std::getline(ss, c, '|');) {
      const size_t a = c.find_first_not_of(' '), b = c.find_last_not_of(' ');
      cells.push_back(a == std::string::npos ? "" : c.substr(a, b - a + 1));
    }
    std::vector<double> figures;
    for (size_t k = 1; k < cells.size(); ++k) figures.push_back(std::atof(cells[k].c_str()));
    if (!cells.empty()) table[cells[0]] = figures;
  }
  const auto& held = j["verification_without_outliers"];
  for (const char* side : {"before", "after"}) {
    ASSERT_EQ(table[side].size(), 4u) << side;
    EXPECT_NEAR(table[side][0], held[side]["mean_mm"].get<double>(), 6e-5) << side;
    EXPECT_NEAR(table[side][1], held[side]["rms_mm"].get<double>(), 6e-5) << side;
    EXPECT_NEAR(table[side][3], held[side]["max_mm"].get<double>(), 6e-5) << side;
    EXPECT_NEAR(table[side][2], held[side]["p997_mm"].get<double>(), 6e-5) << side;
    EXPECT_GE(table[side][2], table[side][1] - 1e-4) << side;
    EXPECT_LE(table[side][2], table[side][3] + 1e-4) << side;
  }
  const int kept = j["verification_rows"].get<int>() - static_cast<int>(j["outliers"]["verification"]["rows"].size());
  for (const char* figure : {"histogram", "joints", "workspace"}) {
    EXPECT_TRUE(isGnuplotFigure(dir + "/report/" + figure + ".svg")) << figure;
    std::ifstream data(dir + "/report/" + figure + ".dat");
    int rows = 0;
    for (std::string line; std::getline(data, line);) rows += !line.empty() && line[0] != '#';
    EXPECT_EQ(rows, kept) << figure;
  }
  int estimated = 0;
  for (const auto& prm : j["parameters"]) {
    if (!prm["estimated"].get<bool>()) continue;
    ++estimated;
    const std::string name = prm["name"];
    ASSERT_EQ(table.count(name), 1u) << name;
    EXPECT_NEAR(table[name][1], prm["value"].get<double>(), 6e-5) << name;
    EXPECT_NEAR(table[name][3], std::abs(prm["stddev"].get<double>()), 6e-5) << name;
  }
  EXPECT_GT(estimated, 10);
  // Several set-ups: a usage error, nothing written.
  Process two(dir, "two", {"cellcal", "calibrate", "--robot", robot_file, "--data", dir + "/m.csv", "--data",
                           dir + "/m.csv", "--report", dir + "/report2"});
  EXPECT_EQ(two.wait(120), 2) << two.log();
  EXPECT_NE(two.log().find("--report takes one set-up"), std::string::npos) << two.log();
  EXPECT_FALSE(std::filesystem::exists(dir + "/report2/report.md"));
}

// A campaign whose positions lie on a line (a robot scanning along one axis at one tool orientation; robot, line,
// length, points or 6D drawn at random): calibrate registers what the rows pin, says that the turn about the line is
// not in them, and calibrates; the held-out rows on the line come out better than before and as its check predicts
// (mostly at the readings' noise; where the fit leaves more, it says so).
TEST(CliCalibrate, PositionsOnALineAreRegisteredAndTheTurnAboutItIsSaid) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  SimulationConfig sc;
  sc.seed = rng();
  const std::string name = rng() % 2 ? "staubli_tx60" : "ur10";
  const SimulatedCell cell(robot(name), sc);
  const RobotModel& m = cell.model();
  const MeasurementKind kind = rng() % 2 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  KinematicsData data(m);
  std::normal_distribution<double> g;
  MeasurementFile f;
  double noise_mm = 0;
  for (int attempt = 0; attempt < 20 && f.rows.size() < 80; ++attempt) {
    f.rows.clear();
    noise_mm = 0;
    const Eigen::VectorXd q0 = cell.randomConfigurations(1, rng).front();
    const Pose start = forwardKinematics(m, data, m.nominal, q0);
    const Eigen::Vector3d dir_m = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const double length_m = std::uniform_real_distribution<double>(0.2, 0.5)(rng);
    Eigen::VectorXd q = q0;
    for (int k = 0; k < 80; ++k) {
      Pose target = start;
      target.translation() += dir_m * length_m * (k / 79.0 - 0.5);
      const IkResult ik = solveInverseKinematics(m, m.nominal, target, q);
      if (!ik.ok() || (k > 0 && (ik.q_rad - q).cwiseAbs().maxCoeff() > 0.3)) break;  // out of reach, another branch
      q = ik.q_rad;
      const Observation o = cell.measure(q, 0.0, rng, kind);
      f.rows.push_back(measuredRow(q, o));
      noise_mm += (o.measured_in_tracker.translation() - cell.truePose(q, 0).translation()).norm() * 1e3 / 80;
    }
  }
  ASSERT_EQ(f.rows.size(), 80u) << "no line of 80 reachable positions found";
  {
    std::ofstream out(dir + "/line.csv");
    writeMeasurementCsv(out, f, m.numJoints(), "a line scan");
  }
  Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml",
                               "--data", dir + "/line.csv", "--json", dir + "/line.json"});
  const int code = p.wait(120);
  EXPECT_TRUE(code == 0 || code == 4) << p.log();
  EXPECT_NE(p.log().find("NOTE: the positions lie on a line"), std::string::npos) << p.log();
  const auto j = readJson(dir + "/line.json");
  ASSERT_FALSE(j.is_discarded()) << p.log();
  EXPECT_TRUE(j["registration_note"].is_string()) << j.dump().substr(0, 400);
  // Its figures are true: deployed (exit 0) where better than the registered nominal model on the held-out rows, not
  // (exit 4) where a line the nominal model already meets at the noise leaves nothing to gain; the held-out errors
  // those its own check predicts (the residual and the parameters' uncertainty together).
  const auto& held = j["verification_without_outliers"];
  EXPECT_EQ(code == 0, held["after"]["mean_mm"].get<double>() < held["before"]["mean_mm"].get<double>()) << p.log();
  const double ratio = j["prediction"]["actual_over_predicted_rms"].get<double>();
  EXPECT_GT(ratio, 0.5) << p.log();
  EXPECT_LT(ratio, 2.0) << p.log();
  std::printf("  %s, %s: exit %d, held-out mean %.4f mm after (readings' noise %.4f mm), check ratio %.2f\n",
              name.c_str(), kind == MeasurementKind::kPose6D ? "6D" : "points", code,
              held["after"]["mean_mm"].get<double>(), noise_mm, ratio);
}

// A robot base that drifts in the tracker's frame as the cell warms up (about joint 1's axis or by any small twist;
// robot, placements, points or 6D, thermometer or not, warm-up, size and seed drawn at random): `diagnose` never names
// a drift of the robot without saying it may be the frame's, in its output and its JSON; `calibrate --model
// frame_drift` fits the frame's drift by name.
TEST(CliDiagnose, ABaseThatDriftsIsSaidToBeTheFrames) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  DrawOptions o;
  o.category = DrawCategory::kOutOfLibrary;
  o.force_outside = OutsideEffect::kBaseDrift;
  o.min_amp_deg = 0.02;
  HiddenEffectData h = makeHiddenEffectData(o, rng());
  while (h.draw.outside_rms_mm <= 2 * h.noise_rms_mm) h = makeHiddenEffectData(o, rng());
  std::printf("hidden: %s, noise %.4f mm RMS\n", h.draw.describe().c_str(), h.noise_rms_mm);
  const auto [robot_file, sigma_mm] = writeDraw(dir, h, "simulated robot whose base drifts");
  Process p(dir, "diagnose", {"cellcal", "diagnose", "--robot", robot_file, "--data", dir + "/m.csv", "--json",
                              dir + "/d.json", "--sigma-position-mm", std::to_string(sigma_mm)});
  ASSERT_EQ(p.wait(120), 0) << p.log();
  const auto j = readJson(dir + "/d.json");
  const auto& dc = j["drift_check"];
  ASSERT_TRUE(dc["ran"].get<bool>()) << p.log();
  const std::string outcome = dc["outcome"];
  EXPECT_TRUE(outcome == "alike" || outcome == "frame_drift_better" || outcome == "frame_drift_explains" ||
              outcome == "both")
      << p.log();
  EXPECT_NE(j["verdict_text"].get<std::string>().find("base frame"), std::string::npos) << p.log();
  EXPECT_NE(p.log().find("drift check"), std::string::npos) << p.log();
  Process c(dir, "calibrate", {"cellcal", "calibrate", "--robot", robot_file, "--data", dir + "/m.csv", "--json",
                               dir + "/c.json", "--model", "frame_drift"});
  ASSERT_EQ(c.wait(120), 0) << c.log();
  const auto cj = readJson(dir + "/c.json");
  EXPECT_LT(cj["verification_without_outliers"]["after"]["rms_mm"].get<double>(), 1.2 * h.noise_rms_mm) << c.log();
  EXPECT_EQ(cj["extension_params"].size(), 6u) << cj["extension_params"].dump();
}

// `cellcal diagnose` and `cellcal calibrate --model` on a file with an effect hidden in it (robot, tracker placement,
// target offset, points or 6D, cause, joint, size, gross errors and seed drawn at random; sizes from 0.005 to 0.05 deg
// RMS, mostly above the tracker noise). The tool sees only the file and registers the frames itself.
TEST(CliDiagnose, NamesTheHiddenCauseAndCalibratesTheExtendedModel) {
  const std::string dir = testDir();
  DrawOptions o;
  o.min_amp_deg = 0.005;
  o.max_outlier_fraction = 0.03;
  const HiddenEffectData h = makeHiddenEffectData(o, testSeed());
  const TrueEffect& t = h.draw.effects.front();
  std::printf("hidden: %s, noise %.4f mm RMS\n", h.draw.describe().c_str(), h.noise_rms_mm);
  const auto [robot_file, sigma_mm] = writeDraw(dir, h, "simulated robot with a hidden effect");
  Process p(dir, "diagnose", {"cellcal", "diagnose", "--robot", robot_file, "--data", dir + "/m.csv", "--json",
                              dir + "/d.json", "--report", dir + "/report", "--sigma-position-mm", std::to_string(sigma_mm)});
  ASSERT_EQ(p.wait(120), 0) << p.log();
  const auto j = readJson(dir + "/d.json");
  const std::string cause = j["cause"];
  std::vector<int> joints = j["joints"].get<std::vector<int>>();
  // Judged where the effect is clearly above the noise (the rate near the noise is the HiddenEffects suites' business).
  const bool large = t.effect_rms_mm > 2 * h.noise_rms_mm;
  EXPECT_EQ(j["measurement"], h.draw.kind == MeasurementKind::kPose6D ? "pose6d" : "position3d");
  // The truth is named, or (where these data tell two causes only weakly apart, e.g. a TX60's joint 3 compliance
  // and its forearm's deflection) named as alike.
  bool alike = false;
  if (!j["causes"].empty())
    for (const auto& a : j["causes"][0]["alike"]) alike = alike || a.get<std::string>() == extensionLabel({t.cause, t.joint});
  if (large && !alike) {
    EXPECT_EQ(cause, causeName(t.cause)) << p.log();
    if (t.joint_effect_rms_mm > 2 * h.noise_rms_mm) {
      EXPECT_EQ(joints, std::vector<int>{t.joint + 1}) << p.log();
    }
  }
  if (large) {
    EXPECT_LT(j["extended"]["verify_rms_mm"].get<double>(), 1.2 * h.noise_rms_mm) << p.log();
    EXPECT_GT(j["gain_pct"].get<double>(), 0.0);
    EXPECT_TRUE(isGnuplotFigure(dir + "/report/signature.svg"));
  }
  // Every gross error named by its file line.
  std::vector<int> flagged;
  for (const char* set : {"identification", "verification"})
    for (const auto& r : j["outliers"][set]["rows"]) flagged.push_back(r["line"].get<int>());
  const MeasurementFile written = readMeasurementCsv(dir + "/m.csv", robot(h.draw.robot));
  auto line = [&](int row) { return written.rows[static_cast<size_t>(row)].line; };
  for (int i : h.outlier_identification)
    EXPECT_NE(std::find(flagged.begin(), flagged.end(), line(2 * i)), flagged.end()) << "row " << 2 * i;
  for (int i : h.outlier_verification)
    EXPECT_NE(std::find(flagged.begin(), flagged.end(), line(2 * i + 1)), flagged.end()) << "row " << 2 * i + 1;
  EXPECT_EQ(flagged.size(), h.outlier_identification.size() + h.outlier_verification.size()) << p.log();
  EXPECT_TRUE(std::filesystem::exists(dir + "/report/report.md"));
  ASSERT_TRUE(j["candidates"].is_array());
  ASSERT_FALSE(j["candidates"].empty());
  for (const char* k : {"cause", "joints", "verify_mean_mm", "params"}) EXPECT_TRUE(j["candidates"][0].contains(k)) << k;
  for (const char* k : {"verdict", "verdict_text", "noise", "outliers", "causes"}) EXPECT_TRUE(j.contains(k)) << k;
  EXPECT_TRUE(j["geometric"].contains("verify_mean_mm"));
  EXPECT_TRUE(j["extended"].contains("verify_rms_mm"));
  // The region check judged every cause kept (and the first one left out, if any), and says what it left out.
  const auto& rc = j["region_check"];
  ASSERT_TRUE(rc.is_object()) << j.dump();
  EXPECT_EQ(rc["causes"].size(), j["causes"].size() + (rc["left_out"].empty() ? 0 : 1)) << rc.dump();
  for (const auto& c : rc["causes"])
    for (const char* k : {"label", "split", "mean_with_mm", "mean_without_mm", "gain_pct", "z", "transfers"})
      EXPECT_TRUE(c.contains(k)) << k;
  if (!rc["causes"].empty()) {
    EXPECT_NE(readTextFile(dir + "/report/report.md").find("Beyond the rows fitted"), std::string::npos);
  }
  // The drift check ran where a thermal drift was named (these files have stamps: a time driver at least).
  const auto& dc = j["drift_check"];
  ASSERT_TRUE(dc.is_object()) << j.dump();
  bool drift_named = false;
  for (const auto& c : j["causes"]) drift_named = drift_named || c["cause"] == "thermal_drift";
  if (drift_named) {
    EXPECT_TRUE(dc["ran"].get<bool>()) << dc.dump();
    EXPECT_NE(readTextFile(dir + "/report/report.md").find("A drift or the frame"), std::string::npos);
  }
  if (dc["ran"].get<bool>()) {
    for (const char* k : {"outcome", "text", "chosen", "alternative", "mean_chosen_mm", "mean_alternative_mm", "z_frame"})
      EXPECT_FALSE(dc[k].is_null()) << k << " " << dc.dump();
  }
  if (!j["causes"].empty() || !rc["left_out"].empty()) {
    Process n(dir, "diagnose-no-region-check", {"cellcal", "diagnose", "--robot", robot_file, "--data", dir + "/m.csv",
                                                "--json", dir + "/n.json", "--no-region-check", "--sigma-position-mm",
                                                std::to_string(sigma_mm)});
    ASSERT_EQ(n.wait(120), 0) << n.log();
    const auto nj = readJson(dir + "/n.json");
    EXPECT_FALSE(nj["region_check"]["ran"].get<bool>());
    EXPECT_EQ(nj["causes"].size(), j["causes"].size() + rc["left_out"].size()) << nj.dump();
  }

  // calibrate with the model diagnose named (auto) and with the true cause given by hand.
  if (large && cause != "none") {
    std::string spec = cause + (joints.empty() ? "" : ":" + std::to_string(joints[0]));
    for (const std::string& model : {std::string("auto"), spec}) {
      Process c(dir, "calibrate", {"cellcal", "calibrate", "--robot", robot_file, "--data", dir + "/m.csv", "--json",
                                   dir + "/c.json", "--model", model});
      ASSERT_EQ(c.wait(120), 0) << c.log();
      const auto cj = readJson(dir + "/c.json");
      EXPECT_LT(cj["verification_without_outliers"]["after"]["rms_mm"].get<double>(), 1.2 * h.noise_rms_mm)
          << model << "\n" << c.log();
      EXPECT_FALSE(cj["extension_params"].empty()) << c.log();
      EXPECT_EQ(cj["region_check"].is_object(), model == "auto") << cj["region_check"].dump();
    }
  }
  Process bad(dir, "calibrate-bad", {"cellcal", "calibrate", "--robot", robot_file, "--data", dir + "/m.csv", "--model",
                                     "backlash"});
  EXPECT_NE(bad.wait(30), 0);
  EXPECT_NE(bad.log().find("needs a joint"), std::string::npos) << bad.log();
}

}  // namespace
}  // namespace cellcal

namespace cellcal {
namespace {

using namespace cellcal::test;

// The paper experiment's figures (gnuplot): accuracy before/after each update, residuals, joint drift, pose sweep.
TEST(CliExperiment, PaperFiguresAreRendered) {
  const std::string dir = testDir();
  Process p(dir, "paper", {"cellcal", "experiment", "paper", "--seed", std::to_string(testSeed() % 100000), "--plot",
                           dir + "/figures", "--quiet"});
  ASSERT_EQ(p.wait(120), 0) << p.log();
  for (const char* f : {"maintenance", "residuals", "joint_drift", "pose_sweep"})
    EXPECT_TRUE(isGnuplotFigure(dir + "/figures/" + f + ".png")) << p.log();
}

// --residual-map on a file whose robot has a repeatable error no kinematic model holds (a smooth vector field over
// joints 1-3 of random size and wavelength, added to every reading), each configuration measured twice in random
// order: the alternate split puts most second readings beside their first, and the map takes the held-out error well
// below the model's; --split positions verifies at positions the identification never saw, where the map must not
// make it worse.
TEST(CliCalibrate, AResidualMapCorrectsWhatTheModelLeavesAtMeasuredPosesOnly) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  SimulationConfig sc;
  sc.seed = seed;
  const SimulatedCell cell(robot("staubli_tx60"), sc);
  const double size = 1e-4 + 2e-4 * u(rng);
  Eigen::Vector3d w, phase;
  for (int k = 0; k < 3; ++k) w[k] = 0.15 + 0.25 * u(rng), phase[k] = 6.28 * u(rng);
  auto field = [&](const Eigen::VectorXd& q) -> Eigen::Vector3d {
    return size * Eigen::Vector3d(std::sin(q[0] / w[0] + phase[0]), std::sin(q[1] / w[1] + phase[1]),
                                  std::sin(q[2] / w[2] + phase[2]));
  };
  std::vector<Eigen::VectorXd> qs;
  for (const auto& q : cell.randomConfigurations(200, rng)) qs.insert(qs.end(), {q, q});
  std::shuffle(qs.begin(), qs.end(), rng);
  MeasurementFile f;
  for (const auto& q : qs) {
    Observation o = cell.measure(q, 0.0, rng, MeasurementKind::kPosition3D);
    o.measured_in_tracker.translation() += field(q);
    f.rows.push_back(measuredRow(q, o));
  }
  {
    std::ofstream out(dir + "/m.csv");
    writeMeasurementCsv(out, f, 6, "simulated TX60 with a repeatable error field");
  }
  SCOPED_TRACE("field " + std::to_string(size * 1e3) + " mm, wavelengths " + std::to_string(w[0]) + " " +
               std::to_string(w[1]) + " " + std::to_string(w[2]) + " rad");
  auto run = [&](const std::string& split) {
    Process p(dir, "calibrate_" + split,
              {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml", "--data",
               dir + "/m.csv", "--json", dir + "/" + split + ".json", "--residual-map", "--split", split});
    EXPECT_EQ(p.wait(120), 0) << p.log();
    return readJson(dir + "/" + split + ".json")["residual_map"];
  };
  const auto alt = run("alternate");
  ASSERT_TRUE(alt.is_object());
  std::printf("  alternate: %.4f mm with the map, %.4f without (%d rows near); ",
              alt["all_mean_with_mm"].get<double>(), alt["all_mean_without_mm"].get<double>(),
              alt["verification_rows_near"].get<int>());
  EXPECT_LT(alt["near_mean_with_mm"].get<double>(), 0.6 * alt["near_mean_without_mm"].get<double>());
  EXPECT_LT(alt["all_mean_with_mm"].get<double>(), alt["all_mean_without_mm"].get<double>());
  const auto pos = run("positions");
  ASSERT_TRUE(pos.is_object());
  std::printf("positions: %.4f mm with the map, %.4f without (%d rows near)\n", pos["all_mean_with_mm"].get<double>(),
              pos["all_mean_without_mm"].get<double>(), pos["verification_rows_near"].get<int>());
  EXPECT_LT(pos["all_mean_with_mm"].get<double>(), 1.03 * pos["all_mean_without_mm"].get<double>());
}

}  // namespace
}  // namespace cellcal
