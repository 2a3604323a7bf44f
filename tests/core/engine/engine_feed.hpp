// Feeding a calibration engine the samples a cell would give it, for tests. `Sink` is a CalibrationEngine or anything
// with the same onJointState / onTrackerSample / process (e.g. HostedRobot: one robot of an EngineHost, so the same
// streams exercise its state files).
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <filesystem>
#include <random>
#include <string>
#include <unistd.h>

#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::test {

// A fresh folder for a test's files.
inline std::string tempDir(const std::string& name) {
  namespace fs = std::filesystem;
  const fs::path d = fs::temp_directory_path() / ("cellcal_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d.string();
}

// The tracker sample of a simulated reading: its pose (quaternion x, y, z, w), stamp and sequence number.
inline TrackerSample trackerSample(const Observation& o, std::int64_t stamp_ns, std::uint64_t sequence) {
  TrackerSample s;
  s.stamp_ns = stamp_ns;
  s.sequence = sequence;
  s.position_m = o.measured_in_tracker.translation();
  const Eigen::Quaterniond qn(o.measured_in_tracker.linear());
  s.orientation_xyzw = {qn.x(), qn.y(), qn.z(), qn.w()};
  return s;
}

// The simulated cell's robot program streamed at the joint-state rate: every joint state, a tracker reading in each
// stand-still, process() after every joint state; cell time compressed as in the cell file.
struct Feed {
  const SimulatedCell& cell;
  const SimRobotProgram& program;
  std::mt19937_64 rng;
  std::int64_t epoch_ns = 1'700'000'000'000'000'000;
  double compression;
  std::uint64_t jseq = 0, tseq = 0;
  HiddenJointState hidden{};  // the hidden effect's state along the path (backlash play)
  Eigen::VectorXd last_q = Eigen::VectorXd();

  std::int64_t wallNs(double cell_s) const { return epoch_ns + static_cast<std::int64_t>(cell_s / compression * 1e9); }

  // Returns the number of readings published.
  template <class Sink>
  int run(Sink& engine, int first, int last, double joint_period_cell_s, double pose_time_s, double settle_fraction) {
    int readings = 0;
    for (int g = first; g < last; ++g) {
      for (int k = 0; k < program.posesIn(g); ++k) {
        const double start = program.campaignStart_s(g) + k * pose_time_s;
        const double read_at = start + (1 - settle_fraction + 0.3 * settle_fraction) * pose_time_s;
        bool read = false;
        for (double t = start; t < start + pose_time_s; t += joint_period_cell_s) {
          const SimRobotState st = program.at(t);
          if (last_q.size()) hidden = cell.advanceHiddenState(hidden, last_q, st.q_rad);
          last_q = st.q_rad;
          engine.onJointState({wallNs(t), ++jseq, st.q_rad, st.settled}, wallNs(t));
          if (!read && t >= read_at) {
            read = true;
            const Observation o = cell.measure(st.q_rad, &hidden, t / 3600.0, rng);
            TrackerSample s = trackerSample(o, wallNs(t) - 1000, ++tseq);
            for (int i = 0; i < 3; ++i) {
              s.covariance[i * 7] = o.sigma_position_m * o.sigma_position_m;
              s.covariance[(i + 3) * 7] = o.sigma_orientation_rad * o.sigma_orientation_rad;
            }
            engine.onTrackerSample(s, wallNs(t));
            ++readings;
          }
          engine.process(wallNs(t));
        }
      }
    }
    return readings;
  }
};

// The reading `s` of a stand-still at q: the robot arrives (a moving joint state), stands still around the reading,
// then the engine processes. `seq`: the joint states' sequence number, advanced.
template <class Sink>
void feedStandStill(Sink& e, const Eigen::VectorXd& q, const TrackerSample& s, std::uint64_t& seq) {
  e.onJointState({s.stamp_ns - 2000, ++seq, q, false}, s.stamp_ns);
  e.onJointState({s.stamp_ns - 1000, ++seq, q, true}, s.stamp_ns);
  e.onTrackerSample(s, s.stamp_ns);
  e.onJointState({s.stamp_ns + 1000, ++seq, q, true}, s.stamp_ns + 1000);
  e.process(s.stamp_ns + 2000);
}

// One stand-still per call: a settled joint state before and after the reading, then process().
struct Stream {
  const SimulatedCell& sim;
  std::mt19937_64& rng;
  std::int64_t t_ns = 1'700'000'000'000'000'000;
  std::uint64_t seq = 0;
  double cell_h = 0;

  TrackerSample reading(const Eigen::VectorXd& q) {
    return trackerSample(sim.measure(q, cell_h, rng), t_ns, ++seq);
  }
  // Feeds `s` (made by reading() for q) as the reading of a stand-still at q (feedStandStill).
  template <class Sink>
  void feed(Sink& e, const Eigen::VectorXd& q, const TrackerSample& s) {
    feedStandStill(e, q, s, seq);
  }
  void advance(double seconds) {
    t_ns += static_cast<std::int64_t>(seconds * 1e9);
    cell_h += seconds / 3600;
  }
};

}  // namespace cellcal::test
