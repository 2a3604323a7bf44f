// The engine's trial of a calibration file against the kinematics it started from (file_trial.hpp). The file is a
// real `calibrate --save-robot` of a first campaign; the cell's robot keeps a random share of that campaign's errors
// (-0.5 to 1.3 of them: re-mastered, repaired, or as it was) plus new ones, so the file is sometimes better than its
// nominal kinematics and sometimes worse. The engine sees only the readings of the cell. Plain reference: both models'
// frames registered on the trial's registration positions (every other one, in the order first visited), judged on
// 400 fresh noise-free poses of the cell's robot; the held-out comparison's standard error from the trial's other
// positions, recomputed here.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/campaign/campaign.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "core/engine/engine_feed.hpp"
#include "core/simulated_arm.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;
const std::string kCell = std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml";

// |measured - model| position (m) of each reading under a geometric model.
std::vector<double> errors(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs) {
  KinematicsData data(model);
  std::vector<double> e;
  for (const Observation& o : obs)
    e.push_back((forwardKinematics(model, data, params, o.q_rad).translation() - o.measured_in_tracker.translation()).norm());
  return e;
}

// Where the trial's verdict lands, draw by draw: the deployed model is the better on fresh poses wherever the two
// differ there by more than twice the held-out comparison's standard error, in at least 95 % of those draws. The
// engine's figures are the plain recomputation's; a withdrawn file leaves the engine that started from nominal, to the
// bit; a restart in the middle of the trial changes nothing.
TEST(FileTrial, ACalibrationFileWorseThanItsNominalKinematicsIsWithdrawn) {
  const CellConfig config = loadCellConfig(kCell);
  const std::vector<RobotModel> arms =
      test::armsToDraw({"abb/irb2600_12_165.urdf", "kuka/kr10r1420.urdf", "fanuc/m10ia.urdf", "universal_robots/ur5.urdf"});
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  const std::string dir = test::tempDir("file_trial");
  constexpr int kDraws = 24;
  int judged = 0, right = 0, withdrawn = 0, refused = 0;
  for (int draw = 0; draw < kDraws; ++draw) {
    const RobotModel& arm_file = arms[rng() % arms.size()];
    test::SimulatedArm arm{arm_file, rng};
    arm.six_d = rng() % 2 == 0;
    arm.sigma_m = 0.01e-3 * (1 + arm.u01());
    // The cell: the robot file placed where the cell file registers it.
    const Eigen::VectorXd nominal = arm.placed(arm_file.nominal);
    const RobotModel cell_model = arm_file.withParams(nominal);
    // The first campaign, calibrated and saved as `calibrate --save-robot` saves it.
    const Eigen::VectorXd e1 = arm.jointErrors(1.0);
    RobotFile rf;
    rf.model = cell_model;
    CampaignProblem first;
    first.setups = {prepareCampaignInput("first.csv", rf, arm.measure(nominal + e1, 120), arm.options())};
    const CampaignReport r1 = calibrateCampaign(first);
    ASSERT_EQ(r1.exitCode(), 0) << r1.unusable << r1.message;
    // Made 1 to 30 days before the cell's first reading: the engine widens its covariance by the drift since.
    std::int64_t t_ns = 1'700'000'000'000'000'000;
    RobotCalibration cal = r1.calibration;
    const std::time_t made = static_cast<std::time_t>(t_ns / 1'000'000'000 - (1 + 29 * arm.u01()) * 86400);
    char date[32];
    std::strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&made));
    cal.provenance = {{"date_utc", date}};
    const std::string path = dir + "/calibrated_" + std::to_string(draw) + ".yaml";
    saveRobotFile(path, cell_model.withParams(r1.saved_params), &cal, "campaign one");
    // The cell's robot now.
    const double share = -0.5 + 1.8 * arm.u01();
    const Eigen::VectorXd truth = nominal + share * e1 + arm.jointErrors(0.3);

    CellRobot robot = config.robots[0];
    robot.model = cell_model;
    robot.robot_file = path;
    robot.measurement = arm.six_d ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
    robot.extensions.clear();
    CellRobot with_file = robot;
    with_file.calibration_file = path;
    with_file.start = loadRobotFile(path);
    ASSERT_EQ(with_file.start->calibration->nominal_params.size(), arm_file.numParams());
    CalibrationEngine engine(with_file, config.engine, 1.0), fresh(robot, config.engine, 1.0);
    std::optional<CalibrationEngine> restarted;
    restarted.emplace(with_file, config.engine, 1.0);
    const int restart_at = 1 + static_cast<int>(rng() % 18);
    EXPECT_NE(engine.startNote().find("judged against the nominal kinematics"), std::string::npos) << engine.startNote();

    // The readings: new positions, and now and then one visited before.
    KinematicsData data(arm_file);
    std::vector<Eigen::VectorXd> positions;
    std::vector<Observation> registration, judging;  // the trial's, as the header splits them
    std::uint64_t seq_a = 0, seq_b = 0, seq_c = 0, tseq = 0;
    bool trial_full = false;
    for (int pose = 0; pose < 40; ++pose) {
      std::size_t at = positions.size();
      if (!positions.empty() && arm.u01() < 0.25) at = rng() % positions.size();
      else positions.push_back(arm.configuration());
      const Eigen::VectorXd& q = positions[at];
      Observation o;
      o.q_rad = q;
      o.kind = robot.measurement;
      o.measured_in_tracker = forwardKinematics(arm_file, data, truth, q);
      o.measured_in_tracker.translation() += arm.sigma_m * Eigen::Vector3d(arm.g(), arm.g(), arm.g());
      if (arm.six_d)
        o.measured_in_tracker.linear() = expSO3(arm.sigma_rad * Eigen::Vector3d(arm.g(), arm.g(), arm.g())) *
                                         o.measured_in_tracker.linear();
      o.sigma_position_m = arm.sigma_m;
      o.sigma_orientation_rad = arm.sigma_rad;
      if (!trial_full) (at % 2 == 0 ? registration : judging).push_back(o);
      trial_full = trial_full || positions.size() == FileTrial::kPositions;
      t_ns += 60'000'000'000;
      TrackerSample s = test::trackerSample(o, t_ns, ++tseq);
      for (int i = 0; i < 3; ++i) {
        s.covariance[i * 7] = arm.sigma_m * arm.sigma_m;
        s.covariance[(i + 3) * 7] = arm.sigma_rad * arm.sigma_rad;
      }
      // The robot arrives from elsewhere (a revisit is a new stand-still), then stands still for the reading.
      const Eigen::VectorXd passing = q.array() + 0.1;
      auto feed = [&](CalibrationEngine& e, std::uint64_t& seq) {
        e.onJointState({s.stamp_ns - 5000, ++seq, passing, false}, s.stamp_ns - 5000);
        test::feedStandStill(e, q, s, seq);
      };
      feed(engine, seq_a);
      feed(fresh, seq_b);
      if (pose == restart_at) {  // the engine process restarts from its journal record
        const EngineState saved = engineStateFromBinary(engineStateToBinary(restarted->exportState()));
        restarted.emplace(with_file, config.engine, 1.0);
        restarted->importState(saved);
      }
      feed(*restarted, seq_c);
    }
    const CalibrationSnapshot& snap = engine.snapshot();
    const bool was_refused = snap.start_warning.find("does not fit this cell") != std::string::npos;
    const std::optional<FileVerdict>& v = engine.fileVerdict();
    ASSERT_TRUE(was_refused || v.has_value()) << "neither refused nor judged after 40 poses";
    const bool nominal_deployed = was_refused || v->nominal_better;

    // Plain reference.
    auto registered = [&](const Eigen::VectorXd& p, bool closed_form) {
      const Eigen::VectorXd start = closed_form ? registerFrames(arm_file, p, registration).params : p;
      return refineFrames(arm_file, start, {}, Eigen::VectorXd(), registration,
                          std::vector<Drivers>(registration.size())).params;
    };
    const Eigen::VectorXd pf = registered(with_file.start->model.nominal, false);
    const Eigen::VectorXd pn = registered(with_file.start->calibration->nominal_params, true);
    const std::vector<double> ef = errors(arm_file, pf, judging), en = errors(arm_file, pn, judging);
    std::vector<double> d;
    for (size_t k = 0; k < ef.size(); ++k) d.push_back(ef[k] - en[k]);
    double var = 0;
    for (double x : d) var += (x - mean(d)) * (x - mean(d)) / static_cast<double>(d.size() - 1);
    const double se = std::sqrt(var / static_cast<double>(d.size()));
    double fresh_f = 0, fresh_n = 0;
    for (int k = 0; k < 400; ++k) {
      const Eigen::VectorXd q = arm.configuration();
      const Eigen::Vector3d at = forwardKinematics(arm_file, data, truth, q).translation();
      fresh_f += (forwardKinematics(arm_file, data, pf, q).translation() - at).norm() / 400;
      fresh_n += (forwardKinematics(arm_file, data, pn, q).translation() - at).norm() / 400;
    }
    const bool nominal_truly_better = fresh_n < fresh_f;
    const bool differ = std::abs(fresh_f - fresh_n) > 2 * se;
    std::printf("  %-16s %-6s share %+.2f: fresh file %.4f mm, nominal %.4f mm (SE %.4f); %s%s\n", arm_file.name.c_str(),
                arm.six_d ? "6D" : "points", share, fresh_f * 1e3, fresh_n * 1e3, se * 1e3,
                was_refused ? "refused at probation" : v->nominal_better ? "withdrawn" : "kept",
                !differ ? " (within 2 SE: not judged)" : nominal_deployed == nominal_truly_better ? "" : "  WRONG");
    if (differ) {
      ++judged;
      right += nominal_deployed == nominal_truly_better;
    }
    refused += was_refused;
    if (!was_refused) {
      // The engine's figures are the plain recomputation's, on the same positions.
      ASSERT_TRUE(v->judged);
      EXPECT_EQ(v->positions, FileTrial::kPositions);
      EXPECT_EQ(v->judged_readings, judging.size())
          << "poses " << v->poses << " same_pose " << engine.counters().same_pose << " last rejection "
          << engine.counters().last_rejection << " registration " << registration.size();
      EXPECT_NEAR(v->mean_file_mm, mean(ef) * 1e3, 1e-6);
      EXPECT_NEAR(v->mean_nominal_mm, mean(en) * 1e3, 1e-6);
      EXPECT_EQ(v->nominal_better, mean(en) < mean(ef));
      EXPECT_NEAR(v->z, (mean(ef) - mean(en)) / se, 1e-6 * (1 + std::abs(v->z)));
      withdrawn += v->nominal_better;
      if (v->nominal_better) {
        EXPECT_NE(snap.start_warning.find("does worse here than the nominal kinematics"), std::string::npos)
            << snap.start_warning;
      } else {
        EXPECT_TRUE(snap.start_warning.empty()) << snap.start_warning;
      }
      bool said = false;  // the engine process logs its notes
      for (const auto& n : engine.takeNotes())
        said = said || n.find(v->nominal_better ? "WARNING: calibration_file " + path + " does worse here"
                                                : "calibration_file " + path + " kept: ") == 0;
      EXPECT_TRUE(said);
    }
    if (nominal_deployed) {  // from then on, the engine that started from nominal, to the bit
      EXPECT_TRUE(snap.params == fresh.snapshot().params)
          << (snap.params - fresh.snapshot().params).cwiseAbs().maxCoeff();
      EXPECT_TRUE(snap.covariance == fresh.snapshot().covariance);
      EXPECT_EQ(snap.poses_used, fresh.snapshot().poses_used);
      EXPECT_EQ(snap.health, fresh.snapshot().health);
    }
    // A restart during the trial: the same verdict, the same calibration to the bit.
    EXPECT_TRUE(restarted->snapshot().params == snap.params) << "restarted after pose " << restart_at;
    EXPECT_EQ(restarted->snapshot().start_warning, snap.start_warning);
    EXPECT_EQ(restarted->snapshot().poses_used, snap.poses_used) << restarted->counters().last_rejection << " paired " << restarted->counters().paired << " same " << restarted->counters().same_pose << " readings " << restarted->counters().tracker_readings << " engine paired " << engine.counters().paired;
  }
  fs::remove_all(dir);
  std::printf("  %d of %d judged draws right; withdrawn %d, refused at probation %d, of %d\n", right, judged, withdrawn,
              refused, kDraws);
  // Right in at least 95 % of the judged draws: at most one wrong in 20. Over 100 seeds the trial was wrong in 6 of
  // 2,144 judged draws (0.3 %; five within 2.5 standard errors of the fresh-pose difference, one at 5.3 with points
  // on a UR10), never twice in a run. A single wrong draw among fewer than 20 judged is allowed, which
  // ceil(0.95 * judged) would not (1 of the 100 seeds).
  ASSERT_GE(judged, 8);
  EXPECT_LE(judged - right, std::max(1, judged / 20));
  EXPECT_GT(withdrawn + refused, 0);
  EXPECT_LT(withdrawn + refused, kDraws);
}

// The trial's own rule, as its header states it: judge() is due at the kPositions-th distinct position (a revisit
// within kSameRad of every joint is no new one), or after kMaxPoses poses; a cell that keeps to fewer positions is
// not judged, and the verdict says so with what it saw.
TEST(FileTrial, ItIsDueAtItsTwentiethPositionOrItsLastPose) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  const RobotModel model = loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml");
  auto pose = [&](const Eigen::VectorXd& q) {
    DrivenReading r;
    r.reading.observation.q_rad = q;
    return r;
  };
  auto randomQ = [&] { return Eigen::VectorXd(Eigen::VectorXd::NullaryExpr(6, [&] { return u(rng); })); };
  FileTrial trial;
  trial.start(CalibratedModel::geometric(model.nominal), model.nominal);
  std::vector<Eigen::VectorXd> seen;
  std::size_t kept = 0;
  while (true) {
    Eigen::VectorXd q;
    if (!seen.empty() && rng() % 3 == 0) {  // a revisit, within the tolerance
      q = seen[rng() % seen.size()];
      q[static_cast<Eigen::Index>(rng() % 6)] += 0.9 * FileTrial::kSameRad;
    } else {
      q = randomQ();
      seen.push_back(q);
    }
    ++kept;
    const bool due = trial.keep(pose(q));
    EXPECT_EQ(due, seen.size() == FileTrial::kPositions) << kept << " poses, " << seen.size() << " positions";
    if (due) break;
  }
  EXPECT_EQ(trial.poses().size(), kept);
  // Three positions over and over: not judged after kMaxPoses, and said.
  FileTrial few;
  few.start(CalibratedModel::geometric(model.nominal), model.nominal);
  const Eigen::VectorXd a = randomQ(), b = randomQ(), c = randomQ();
  for (std::size_t k = 1; k <= FileTrial::kMaxPoses; ++k)
    EXPECT_EQ(few.keep(pose(k % 3 == 0 ? a : k % 3 == 1 ? b : c)), k == FileTrial::kMaxPoses) << k;
  const FileVerdict v = few.judge(model);
  EXPECT_FALSE(v.judged);
  EXPECT_FALSE(v.nominal_better);
  EXPECT_EQ(v.positions, 3u);
  EXPECT_EQ(v.poses, FileTrial::kMaxPoses);
  EXPECT_NE(v.text("cal.yaml").find("kept without a judgement against its nominal kinematics: its first 200 poses visit "
                                    "3 distinct positions"),
            std::string::npos)
      << v.text("cal.yaml");
  EXPECT_EQ(few.take().size(), FileTrial::kMaxPoses);
  EXPECT_FALSE(few.active());
}

}  // namespace
}  // namespace cellcal
