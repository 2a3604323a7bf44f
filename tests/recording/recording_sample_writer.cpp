// Writes a cellcal recording (recording/recording.hpp: omgidl schemas, CDR payloads) of random JointState,
// TrackerPose and CalibrationState samples and, beside it, every sample's field values as JSON, for a CDR reader
// written by others to decode and compare (recording_cdr_reader.mjs, @foxglove/omgidl-serialization).
//   recording_sample_writer OUT.mcap OUT.json SEED
// 64-bit integers are written as decimal strings (JSON numbers lose them).
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "cellcal/recording/recording.hpp"

using namespace cellcal;
using namespace cellcal::components;
using namespace cellcal::recording;
using nlohmann::json;

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr, "usage: recording_sample_writer OUT.mcap OUT.json SEED\n");
    return 2;
  }
  std::mt19937_64 rng(std::stoull(argv[3]));
  std::uniform_real_distribution<double> u(-3, 3);
  auto id = [&](const char* prefix) { return std::string(prefix) + std::to_string(rng() % 1000); };
  RecordingWriter rec(argv[1], 256 + rng() % 2048);
  json truth = json::array();
  std::uint64_t t = 1'700'000'000'000'000'000ULL + rng() % 1'000'000'000'000ULL;
  const int n = 20 + static_cast<int>(rng() % 60);
  for (int i = 0; i < n; ++i) {
    t += 1 + rng() % 10'000'000;
    const auto seq = static_cast<std::uint64_t>(rng() >> 1);
    json j;
    switch (rng() % 3) {
      case 0: {
        msg::JointState m;
        m.robot_id(id("robot_"));
        m.source_stamp_ns(t - rng() % 1000);
        m.sequence_number(seq);
        const int joints = 1 + static_cast<int>(rng() % 16);
        for (int k = 0; k < joints; ++k) m.position_rad().push_back(u(rng));
        m.settled(rng() % 2 == 0);
        rec.write(m, t, m.source_stamp_ns(), static_cast<std::uint32_t>(i));
        j = {{"topic", TopicOf<msg::JointState>::name}, {"robot_id", m.robot_id().to_string()},
             {"source_stamp_ns", std::to_string(m.source_stamp_ns())}, {"sequence_number", std::to_string(seq)},
             {"position_rad", m.position_rad()}, {"settled", m.settled()}};
        break;
      }
      case 1: {
        msg::TrackerPose m;
        m.target_id(id("target_"));
        m.source_stamp_ns(t - rng() % 1000);
        m.sequence_number(seq);
        for (auto& p : m.position_m()) p = u(rng);
        for (auto& q : m.orientation_xyzw()) q = u(rng);
        for (auto& c : m.covariance()) c = u(rng) * 1e-9;
        m.has_orientation(rng() % 2 == 0);
        m.valid(rng() % 2 == 0);
        rec.write(m, t, m.source_stamp_ns(), static_cast<std::uint32_t>(i));
        j = {{"topic", TopicOf<msg::TrackerPose>::name}, {"target_id", m.target_id().to_string()},
             {"source_stamp_ns", std::to_string(m.source_stamp_ns())}, {"sequence_number", std::to_string(seq)},
             {"position_m", m.position_m()}, {"orientation_xyzw", m.orientation_xyzw()}, {"covariance", m.covariance()},
             {"has_orientation", m.has_orientation()}, {"valid", m.valid()}};
        break;
      }
      default: {
        msg::CalibrationState m;
        m.robot_id(id("robot_"));
        m.source_stamp_ns(t - rng() % 1000);
        m.sequence_number(seq);
        m.version(rng() % 100000);
        m.mode(rng() % 2 ? msg::MODE_PERIODIC : msg::MODE_CONTINUOUS);
        m.health(static_cast<msg::CalibrationHealth>(rng() % 4));
        m.poses_used(static_cast<std::uint32_t>(rng() % 5000));
        const int params = static_cast<int>(rng() % 40);
        std::vector<std::string> names;
        for (int k = 0; k < params; ++k) {
          names.push_back("joint" + std::to_string(k) + ".a_m");
          m.parameter_names().push_back(names.back());
          m.parameter_values().push_back(u(rng));
          m.parameter_stddevs().push_back(std::abs(u(rng)) * 1e-5);
        }
        std::vector<std::string> exts;
        for (int k = 0; k < static_cast<int>(rng() % 3); ++k) {
          exts.push_back("joint_compliance:" + std::to_string(1 + rng() % 6));
          m.model_extensions().push_back(exts.back());
        }
        m.residual_rms_position_m(std::abs(u(rng)) * 1e-4);
        m.verification_mean_position_m(std::abs(u(rng)) * 1e-4);
        m.robot_model(id("model_"));
        rec.write(m, t, m.source_stamp_ns(), static_cast<std::uint32_t>(i));
        j = {{"topic", TopicOf<msg::CalibrationState>::name}, {"robot_id", m.robot_id().to_string()},
             {"source_stamp_ns", std::to_string(m.source_stamp_ns())}, {"sequence_number", std::to_string(seq)},
             {"version", std::to_string(m.version())}, {"mode", static_cast<int>(m.mode())},
             {"health", static_cast<int>(m.health())}, {"poses_used", m.poses_used()}, {"parameter_names", names},
             {"parameter_values", m.parameter_values()}, {"parameter_stddevs", m.parameter_stddevs()},
             {"model_extensions", exts}, {"residual_rms_position_m", m.residual_rms_position_m()},
             {"verification_mean_position_m", m.verification_mean_position_m()}, {"robot_model", m.robot_model().to_string()}};
      }
    }
    j["log_time_ns"] = std::to_string(t);
    truth.push_back(j);
  }
  rec.file().close();
  std::ofstream(argv[2]) << truth.dump(1) << "\n";
  return 0;
}
