// Vendor interop on loopback: a Cyclone DDS participant (tests/interop/cyclone_peer.c, C code idlc made from cellcal's
// own IDL) publishes a simulated robot's joint states and tracker readings and then asks for targets; cellcal's engine
// and compensation publisher (Fast DDS processes) calibrate from them and answer. The Cyclone side counts the
// CalibrationState and CompensatedTarget samples it receives. Settings: docs/interop.md.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <iomanip>
#include <random>

#include "cell/cell_test_support.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

// Cyclone DDS on loopback: the 127.0.0.1 interface, no multicast (lo has none), unicast discovery to 127.0.0.1.
const char* kCycloneLoopback =
    "<CycloneDDS><Domain id=\"any\"><General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>40</MaxAutoParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>"
    "</Domain></CycloneDDS>";

TEST(Interop, CycloneDdsFeedsTheEngineAndReceivesCalibrationsAndCompensatedTargets) {
  const std::string dir = testDir();
  const int domain = domainForTest();
  const std::uint64_t seed = testSeed();
  // Fast DDS 2.9's TypeInformation is refused by Cyclone DDS 0.10: the cell does not send it.
  const std::string cfg = writeCell(dir, domain, seed, {{"tx60", "tx60_target"}}, "", "", ", type_information: false");
  const CellConfig cell = loadCellConfig(cfg);

  // The inputs: 40 stand-stills of a simulated robot (hidden errors from the seed), each a move, two settled joint
  // states, the tracker reading, two more; then 20 targets the nominal model reaches, with those joints as the seed.
  std::mt19937_64 rng(seed);
  SimulationSettings settings;
  settings.seed = seed;
  const SimulatedCell sim = makeSimulatedCell(cell.robots[0], settings, 0);
  const int poses = 40, targets = 20;
  const auto qs = sim.randomConfigurations(poses + 1, rng);
  std::ofstream in(dir + "/inputs.txt");
  auto joints = [&](std::int64_t t_ms, const Eigen::VectorXd& q, bool settled) {
    in << "J " << t_ms * 1000000 << " tx60 " << (settled ? 1 : 0) << ' ' << q.size();
    for (int i = 0; i < q.size(); ++i) in << ' ' << std::setprecision(17) << q[i];
    in << '\n';
  };
  for (int k = 0; k < poses; ++k) {
    const std::int64_t t = 100LL * k;
    joints(t, qs[k] + 0.5 * (qs[k + 1] - qs[k]), false);
    joints(t + 40, qs[k + 1], true);
    joints(t + 50, qs[k + 1], true);
    const msg::TrackerPose r = components::toTrackerPose("tx60_target", 0, 0, sim.measure(qs[k + 1], 0.0, rng));
    in << "T " << (t + 55) * 1000000 << " tx60_target " << (r.has_orientation() ? 1 : 0) << std::setprecision(17);
    for (double v : r.position_m()) in << ' ' << v;
    for (double v : r.orientation_xyzw()) in << ' ' << v;
    for (double v : r.covariance()) in << ' ' << v;
    in << '\n';
    joints(t + 60, qs[k + 1], true);
    joints(t + 70, qs[k + 1], true);
  }
  KinematicsData kd(sim.model());
  std::int64_t t = 100LL * poses + 1000;  // 1 s after the last reading: the calibration has reached compensation
  for (const auto& q : sim.randomConfigurations(targets, rng)) {
    msg::TargetPose tp;
    components::fromPose(forwardKinematics(sim.model(), kd, sim.nominalParams(), q), tp.position_m(), tp.orientation_xyzw());
    in << "P " << t * 1000000 << " tx60" << std::setprecision(17);
    for (double v : tp.position_m()) in << ' ' << v;
    for (double v : tp.orientation_xyzw()) in << ' ' << v;
    in << ' ' << q.size();  // the controller's joints for the target, as the solver's seed
    for (int i = 0; i < q.size(); ++i) in << ' ' << q[i];
    in << '\n';
    t += 50;
  }
  in.close();

  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet", "--stats-json", dir + "/engine.json"});
  Process compensation(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg});
  std::ofstream(dir + "/cyclone.xml") << kCycloneLoopback;
  ::setenv("CYCLONEDDS_URI", ("file://" + dir + "/cyclone.xml").c_str(), 1);
  Process peer(dir, "cyclone_peer", {"cyclone_peer", std::to_string(domain), dir + "/inputs.txt", "2", dir + "/peer.json"});
  ASSERT_EQ(peer.wait(60), 0) << peer.log() << engine.log() << compensation.log();
  EXPECT_EQ(engine.stop(SIGINT), 0) << engine.log();
  EXPECT_EQ(compensation.stop(SIGINT), 0) << compensation.log();
  const auto p = readJson(dir + "/peer.json");
  const auto e = readJson(dir + "/engine.json");
  ASSERT_FALSE(p.is_discarded()) << peer.log();
  ASSERT_FALSE(e.is_discarded()) << engine.log();
  EXPECT_EQ(p["published"]["tracker_pose"], poses);
  EXPECT_EQ(p["published"]["target_pose"], targets);
  // Cyclone -> Fast DDS: the engine took the readings (best effort on loopback: at most a couple lost) and calibrated.
  const int tracker_rx = e["topics"]["cellcal/tracker_pose"]["received"];
  EXPECT_GE(tracker_rx, poses - 2) << e.dump();
  EXPECT_GE(e["topics"]["cellcal/joint_state"]["received"].get<int>(), 5 * (poses - 2));
  // Fast DDS -> Cyclone: the calibrations, up to the last one, and an answer to every target.
  EXPECT_GE(p["received"]["max_version"].get<int>(), tracker_rx - 2) << p.dump();
  EXPECT_GT(p["received"]["calibration_state"].get<int>(), 0);
  EXPECT_EQ(p["received"]["compensated_target"], targets) << p.dump();
  // Answers made with the calibration the engine computed from Cyclone's samples (a target may still be refused on
  // its own: beyond the correction bound or the joint limits).
  EXPECT_GE(p["received"]["applied"].get<int>(), targets / 2) << p.dump();
  std::printf("  Cyclone DDS peer: sent %d readings and %d targets; the engine (Fast DDS) received %d and published up "
              "to v%d; the peer received %d CalibrationState and %d CompensatedTarget (%d applied)\n",
              poses, targets, tracker_rx, p["received"]["max_version"].get<int>(),
              p["received"]["calibration_state"].get<int>(), p["received"]["compensated_target"].get<int>(),
              p["received"]["applied"].get<int>());
}

}  // namespace
}  // namespace cellcal
