// The engine host (components/common): each robot's state file replaced after every change, a restart that resumes
// exactly where the engine stopped, a state file another model made refused with the file named, a full disk that
// keeps the old file and loses nothing. The simulated cell's streams, random seeds; the host only sees samples.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <csignal>

#include <filesystem>
#include <fstream>
#include <random>

#include "cellcal/components/engine_host.hpp"
#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/lab/sim_program.hpp"
#include "core/engine/engine_feed.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;
using components::EngineHost;
using test::Feed;
using test::Stream;

// One robot of a host, with the engine's own feeding interface (engine_feed.hpp): a persisting engine.
struct HostedRobot {
  CellConfig cell;  // the host refers to it
  EngineHost host;
  EngineHost::Robot& r;
  explicit HostedRobot(CellConfig c) : cell(std::move(c)), host(cell, {}, nullptr), r(host.robots().begin()->second) {}
  bool onJointState(const JointSample& s, std::int64_t t) { return host.onJointState(r.robot->robot_id, s, t); }
  bool onTrackerSample(const TrackerSample& s, std::int64_t t) { return host.onTrackerSample(r.robot->target_id, s, t); }
  void process(std::int64_t t) { host.tick(t); }
  const CalibrationSnapshot& snapshot() const { return r.engine->snapshot(); }
};

struct HostFixture : ::testing::Test {
  CellConfig config = loadCellConfig(std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml");
  std::uint64_t seed = test::testSeed();
  void SetUp() override {
    config.simulation.seed = seed;
    config.simulation.groups = 3;
    config.engine.state_dir = test::tempDir(::testing::UnitTest::GetInstance()->current_test_info()->name());
  }
  void TearDown() override {
    fs::remove_all(config.engine.state_dir);
    fs::remove_all(config.engine.state_dir + "_killed");
  }
  // The cell with its one robot replaced.
  CellConfig withRobot(const CellRobot& robot) const {
    CellConfig c = config;
    c.robots = {robot};
    return c;
  }
};

TEST_F(HostFixture, RestartFromPersistedStateContinuesExactlyWhereItStopped) {
  const CellRobot& robot = config.robots[0];
  const SimulatedCell cell = makeSimulatedCell(robot, config.simulation, 0);
  const SimRobotProgram program(cell, config.simulation);
  const double dt = config.time_compression / config.simulation.joint_rate_hz;
  const double pt = config.simulation.pose_time_s, sf = config.simulation.settle_fraction;
  CalibrationEngine straight(robot, config.engine, config.time_compression);
  Feed f1{cell, program, std::mt19937_64(seed), 1'700'000'000'000'000'000, config.time_compression};
  f1.run(straight, 0, 3, dt, pt, sf);

  Feed f2{cell, program, std::mt19937_64(seed), 1'700'000'000'000'000'000, config.time_compression};
  std::uint64_t version_at_stop = 0;
  const std::string killed = config.engine.state_dir + "_killed";
  {
    HostedRobot first(config);
    EXPECT_FALSE(first.r.restored);
    f2.run(first, 0, 2, dt, pt, sf);
    version_at_stop = first.snapshot().version;
    // "Killed": what a SIGKILL leaves is the state folder as it is now (no clean close); the restart reads a copy.
    fs::remove_all(killed);
    fs::copy(config.engine.state_dir, killed, fs::copy_options::recursive);
  }
  ASSERT_GT(fs::file_size(fs::path(killed) / "tx60.state.journal"), 0u) << "the journal holds the changes";
  CellConfig restarted = config;
  restarted.engine.state_dir = killed;
  HostedRobot second(restarted);
  ASSERT_TRUE(second.r.restored);
  EXPECT_EQ(second.snapshot().version, version_at_stop);
  f2.run(second, 2, 3, dt, pt, sf);
  EXPECT_EQ(second.snapshot().version, straight.snapshot().version);
  EXPECT_EQ(second.snapshot().poses_used, straight.snapshot().poses_used);
  EXPECT_LT((second.snapshot().params - straight.snapshot().params).cwiseAbs().maxCoeff(), 1e-12);
  // Where the cell works came back with it: the same configurations, so health is judged where it was.
  EXPECT_EQ(second.r.engine->workConfigurations(), straight.workConfigurations());
  EXPECT_NEAR(second.snapshot().prediction_sigma_position_m, straight.snapshot().prediction_sigma_position_m,
              1e-9 * straight.snapshot().prediction_sigma_position_m);
  EXPECT_EQ(second.snapshot().health, straight.snapshot().health);
  // A clean close of the first host made its own snapshot current and emptied its journal.
  EXPECT_EQ(fs::file_size(fs::path(config.engine.state_dir) / "tx60.state.journal"), 0u);
  EXPECT_EQ(loadEngineState(stateFilePath(config.engine.state_dir, "tx60"))->version, version_at_stop);
  // A reading from before the stop is never applied twice.
  TrackerSample old;
  old.stamp_ns = second.snapshot().last_measurement_stamp_ns;
  old.sequence = 1;
  EXPECT_FALSE(second.r.engine->onTrackerSample(old, old.stamp_ns));
  EXPECT_EQ(second.r.engine->counters().rejected[static_cast<size_t>(Rejection::kAlreadyApplied)], 1u);
}

TEST_F(HostFixture, ExtendedStateResumesAndAnAddedExtensionKeepsTheKinematics) {
  CellRobot robot = config.robots[0];
  robot.extensions = {Extension{Cause::kBacklash, 2}, Extension{Cause::kJointCompliance, 1}};
  const SimulatedCell cell = makeSimulatedCell(robot, config.simulation, 0);
  const SimRobotProgram program(cell, config.simulation);
  const double dt = config.time_compression / config.simulation.joint_rate_hz;
  const double pt = config.simulation.pose_time_s, sf = config.simulation.settle_fraction;
  for (EngineMode mode : {EngineMode::kContinuous, EngineMode::kPeriodic}) {
    config.engine.mode = mode;
    config.engine.batch_poses = 7;  // the stop leaves a batch half full
    fs::remove_all(config.engine.state_dir);
    const CellConfig extended_cell = withRobot(robot);
    CalibrationEngine straight(extended_cell.robots[0], extended_cell.engine, config.time_compression);
    Feed f1{cell, program, std::mt19937_64(seed), 1'700'000'000'000'000'000, config.time_compression};
    f1.run(straight, 0, 3, dt, pt, sf);
    Feed f2{cell, program, std::mt19937_64(seed), 1'700'000'000'000'000'000, config.time_compression};
    {
      HostedRobot first(extended_cell);
      f2.run(first, 0, 2, dt, pt, sf);
    }
    HostedRobot second(extended_cell);
    ASSERT_TRUE(second.r.restored);
    EXPECT_TRUE(second.r.engine->restoreNote().empty()) << second.r.engine->restoreNote();
    f2.run(second, 2, 3, dt, pt, sf);
    EXPECT_EQ(second.snapshot().version, straight.snapshot().version);
    EXPECT_LT((second.snapshot().params - straight.snapshot().params).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((second.snapshot().extension_params - straight.snapshot().extension_params).cwiseAbs().maxCoeff(), 1e-15);
    EXPECT_LT((second.snapshot().covariance - straight.snapshot().covariance).cwiseAbs().maxCoeff(), 1e-18);
  }
  // A geometric state; then the cell file names an extension: the kinematic estimate carries over.
  config.engine.mode = EngineMode::kContinuous;
  fs::remove_all(config.engine.state_dir);
  Eigen::VectorXd kinematic;
  {
    HostedRobot e(config);
    Feed f{cell, program, std::mt19937_64(seed), 1'700'000'000'000'000'000, config.time_compression};
    f.run(e, 0, 1, dt, pt, sf);
    kinematic = e.snapshot().params;
  }
  HostedRobot extended(withRobot(robot));
  ASSERT_TRUE(extended.r.restored);
  EXPECT_NE(extended.r.engine->restoreNote().find("none -> backlash:3, joint_compliance:2"), std::string::npos)
      << extended.r.engine->restoreNote();
  EXPECT_EQ(extended.snapshot().params, kinematic);
  EXPECT_EQ(extended.snapshot().extensions.size(), 2u);
  EXPECT_TRUE(extended.snapshot().extension_params.isZero());
}

TEST_F(HostFixture, StateOfAnotherModelIsRefusedWithTheFileNamed) {
  { HostedRobot e(config); }
  auto refused = [&](const std::string& why) {
    try {
      HostedRobot e(config);
      ADD_FAILURE() << "state accepted: " << why;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("tx60.state.json"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("start this robot's calibration over"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  const std::string file = (fs::path(config.engine.state_dir) / "tx60.state.json").string();
  std::ofstream(file) << "{\"format\": 1";
  refused("not a readable engine state");
  // A readable state of another robot, and of a model whose nominal values changed.
  EngineState other = CalibrationEngine(config.robots[0], config.engine, 1.0).exportState();
  other.robot_id = "ur10_left";
  saveEngineState(file, other);
  refused("state of robot 'ur10_left'");
  EngineState changed = CalibrationEngine(config.robots[0], config.engine, 1.0).exportState();
  changed.nominal[config.robots[0].model.jointParam(1, JointParam::kA)] += 1e-3;
  saveEngineState(file, changed);
  refused("the nominal model changed since (joint2.a_m)");
}
// The disk fills while the engine runs: the write fails with a clear error, what was saved before stays readable, the
// host keeps the updates in memory and saves them all with the first update after space is back; a restart then
// resumes the latest version. In both durability modes: the snapshot's temporary file is /dev/full; the journal
// cannot grow past the process's file size limit (RLIMIT_FSIZE, SIGXFSZ ignored) while the disk is "full".
TEST_F(HostFixture, ADiskFullWhilePersistingKeepsTheOldStateAndLosesNothing) {
  if (!fs::exists("/dev/full")) GTEST_SKIP() << "no /dev/full";
  const CellRobot& robot = config.robots[0];
  const SimulatedCell sim = makeSimulatedCell(robot, config.simulation, 0);
  std::mt19937_64 rng(seed);
  const auto qs = sim.randomConfigurations(60, rng);
  const int full_from = std::uniform_int_distribution<int>(10, 30)(rng);
  const int full_for = std::uniform_int_distribution<int>(1, 15)(rng);
  struct rlimit unlimited {};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &unlimited), 0);
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  for (const Durability durability : {Durability::kSnapshot, Durability::kJournal}) {
    SCOPED_TRACE(durabilityName(durability));
    fs::remove_all(config.engine.state_dir);
    config.engine.durability = durability;
    HostedRobot engine(config);
    Stream st{sim, rng};
    const std::string file = engine.r.state_file;
    const std::string tmp = file + ".tmp." + std::to_string(::getpid());
    const std::string failing = durability == Durability::kSnapshot ? tmp : stateJournalPath(file);
    std::string saved;
    std::uint64_t saved_version = 0;
    auto savedNow = [&] { return engineStateToJson(*loadDurableState(file).state); };
    for (int k = 0; k < static_cast<int>(qs.size()); ++k) {
      const bool full = k >= full_from && k < full_from + full_for;
      if (k == full_from) {
        saved = savedNow();
        saved_version = engine.snapshot().version;
      }
      // The host removes its failed temporary file; the disk stays full until k = full_from + full_for.
      if (durability == Durability::kSnapshot) {
        if (full && !fs::is_symlink(tmp)) fs::create_symlink("/dev/full", tmp);
        if (!full && fs::is_symlink(tmp)) fs::remove(tmp);
      } else {
        struct rlimit l = unlimited;
        if (full) l.rlim_cur = fs::file_size(failing);
        ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &l), 0);
      }
      st.advance(60);
      st.feed(engine, qs[k], st.reading(qs[k]));
      if (full) {
        EXPECT_NE(engine.r.persist_error.find(durability == Durability::kSnapshot ? "No space left on device"
                                                                                  : "File too large"),
                  std::string::npos)
            << engine.r.persist_error;
        EXPECT_NE(engine.r.persist_error.find(failing), std::string::npos) << engine.r.persist_error;
        EXPECT_TRUE(savedNow() == saved) << "what was saved before must stay readable";
        EXPECT_GT(engine.snapshot().version, saved_version);
      }
    }
    ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &unlimited), 0);
    EXPECT_EQ(engine.r.persist_failures, static_cast<std::uint64_t>(full_for));
    EXPECT_TRUE(engine.r.persist_error.empty());
    HostedRobot restarted(config);
    ASSERT_TRUE(restarted.r.restored);
    EXPECT_EQ(restarted.snapshot().version, engine.snapshot().version);
    EXPECT_EQ(restarted.snapshot().poses_used, engine.snapshot().poses_used);
    EXPECT_EQ((restarted.snapshot().params - engine.snapshot().params).cwiseAbs().maxCoeff(), 0.0);
  }
  std::signal(SIGXFSZ, old_handler);
}

// Without persistence (`cellcal validate`) no file is touched; unknown robots and targets are counted; a new version
// is handed on once; tickIfDue polls at most every kTickPeriod of the given clock.
TEST_F(HostFixture, WithoutPersistenceNothingIsWrittenAndEveryVersionIsHandedOnOnce) {
  const CellRobot& robot = config.robots[0];
  const SimulatedCell sim = makeSimulatedCell(robot, config.simulation, 0);
  std::mt19937_64 rng(seed);
  std::uint64_t handed = 0, last = 0;
  EngineHost host(config, {false, nullptr}, [&](EngineHost::Robot& r) {
    ++handed;
    EXPECT_EQ(r.engine->snapshot().version, last + 1);
    last = r.engine->snapshot().version;
  });
  Stream st{sim, rng};
  struct Sink {
    EngineHost& h;
    const CellRobot& r;
    void onJointState(const JointSample& s, std::int64_t t) { h.onJointState(r.robot_id, s, t); }
    void onTrackerSample(const TrackerSample& s, std::int64_t t) { h.onTrackerSample(r.target_id, s, t); }
    void process(std::int64_t t) { h.tickIfDue(t); }
  } sink{host, robot};
  for (const auto& q : sim.randomConfigurations(20, rng)) {
    st.advance(60);
    st.feed(sink, q, st.reading(q));
  }
  EXPECT_EQ(handed, host.updates());
  EXPECT_EQ(handed, host.robots().at(robot.robot_id).engine->snapshot().version);
  EXPECT_GT(handed, 0u);
  EXPECT_TRUE(fs::is_empty(config.engine.state_dir));
  EXPECT_TRUE(host.takeUnsynced().empty());
  EXPECT_FALSE(host.onJointState("nobody", {}, 0));
  EXPECT_FALSE(host.onTrackerSample("no_target", {}, 0));
  EXPECT_EQ(host.unknownKeys(), 2u);
}

// The engine's own share of the latency path (EngineProcess's stats): from receiving the sample that made a reading
// pairable to its version handed on, measured once per such version by the host's clock, and equal to its parts.
TEST_F(HostFixture, TheEnginesOwnShareIsMeasuredFromTheDecidingSample) {
  const CellRobot& robot = config.robots[0];
  const SimulatedCell sim = makeSimulatedCell(robot, config.simulation, 0);
  std::mt19937_64 rng(seed);
  std::int64_t now = 0;  // the host's clock: set per sample, a random delay after its receive time
  std::uniform_int_distribution<std::int64_t> delay_ns(1000, 900000);
  std::vector<std::int64_t> delays;
  EngineHost host(config, {false, [&] { return now; }}, nullptr);
  struct Sink {
    EngineHost& h;
    const CellRobot& r;
    std::int64_t& now;
    std::int64_t delay = 0;
    void onJointState(const JointSample& s, std::int64_t t) {
      now = t + delay;
      h.onJointState(r.robot_id, s, t);
    }
    void onTrackerSample(const TrackerSample& s, std::int64_t t) {
      now = t + delay;
      h.onTrackerSample(r.target_id, s, t);
    }
    void process(std::int64_t t) {
      now = t;
      h.tick(t);
    }
  } sink{host, robot, now};
  Stream st{sim, rng};
  for (const auto& q : sim.randomConfigurations(20, rng)) {
    st.advance(60);
    sink.delay = delay_ns(rng);
    const std::uint64_t before = host.updates();
    st.feed(sink, q, st.reading(q));
    if (host.updates() != before) delays.push_back(sink.delay);
  }
  const EngineHost::Robot& r = host.robots().at(robot.robot_id);
  ASSERT_GT(delays.size(), 0u);
  ASSERT_EQ(r.decided_ns.size(), delays.size()) << "one measure per version made on a sample's arrival";
  for (size_t k = 0; k < delays.size(); ++k) {
    EXPECT_EQ(r.decided_ns[k], delays[k]);
    EXPECT_EQ(r.queued_ns[k] + r.process_ns[k] + r.persist_ns[k] + r.publish_ns[k], r.decided_ns[k]);
  }
}

// What made each reading pairable is counted by its cause: a reading whose joint state of the same instant was there
// already pairs on its own arrival (a tracker triggered with the controller), one that came before the joint state
// after it pairs on that joint state; the reading's own transport (stamp -> received) is kept per reading.
TEST_F(HostFixture, EachPairingIsCountedByTheSampleThatDecidedIt) {
  const CellRobot& robot = config.robots[0];
  const SimulatedCell sim = makeSimulatedCell(robot, config.simulation, 0);
  std::mt19937_64 rng(seed);
  EngineHost host(config, {false, nullptr}, nullptr);
  Stream st{sim, rng};
  std::uniform_int_distribution<std::int64_t> transport_ns(50'000, 900'000);
  std::vector<std::int64_t> transports;
  std::uint64_t on_reading = 0, on_joint_state = 0;
  for (const auto& q : sim.randomConfigurations(30, rng)) {
    st.advance(60);
    const TrackerSample s = st.reading(q);
    const std::int64_t transport = transport_ns(rng);
    const std::uint64_t paired = host.robots().at(robot.robot_id).engine->counters().paired;
    host.onJointState(robot.robot_id, {s.stamp_ns - 1000, ++st.seq, q, true}, s.stamp_ns);
    if (rng() % 2) {  // triggered: the joint state of the reading's instant arrives first
      host.onJointState(robot.robot_id, {s.stamp_ns, ++st.seq, q, true}, s.stamp_ns + 1000);
      host.onTrackerSample(robot.target_id, s, s.stamp_ns + transport);
      on_reading += host.robots().at(robot.robot_id).engine->counters().paired - paired;
    } else {          // free-running: the reading waits for the next joint state
      host.onTrackerSample(robot.target_id, s, s.stamp_ns + transport);
      host.onJointState(robot.robot_id, {s.stamp_ns + 1000, ++st.seq, q, true}, s.stamp_ns + transport + 1000);
      on_joint_state += host.robots().at(robot.robot_id).engine->counters().paired - paired;
    }
    transports.push_back(transport);
  }
  const EngineHost::Robot& r = host.robots().at(robot.robot_id);
  EXPECT_GT(on_reading, 5u);
  EXPECT_GT(on_joint_state, 5u);
  EXPECT_EQ(r.paired_on_reading, on_reading);
  EXPECT_EQ(r.paired_on_joint_state, on_joint_state);
  EXPECT_EQ(r.paired_on_tick, 0u);
  EXPECT_EQ(on_reading + on_joint_state, r.engine->counters().paired);
  EXPECT_EQ(std::vector<std::int64_t>(r.reading_received_ns.begin(), r.reading_received_ns.end()), transports);
}

}  // namespace
}  // namespace cellcal
