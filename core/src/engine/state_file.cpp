#include "cellcal/core/engine/state_file.hpp"

#include "write_all.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

namespace cellcal {

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kStateFormat = "cellcal-engine-state/1";

// Atomic replace: a reader (or a restart after SIGKILL) sees the old file or the new one, never a mix.
void atomicWrite(const std::string& path, const std::string& data) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error(tmp + ": cannot create: " + std::strerror(errno));
  try {
    detail::writeAll(fd, data.data(), data.size(), tmp);
  } catch (...) {
    ::close(fd);
    ::unlink(tmp.c_str());
    throw;
  }
  if (::close(fd) != 0) {  // NFS and some filesystems report a full disk only here
    const std::string err = std::strerror(errno);
    ::unlink(tmp.c_str());
    throw std::runtime_error(tmp + ": close failed: " + err);
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string err = std::strerror(errno);
    ::unlink(tmp.c_str());
    throw std::runtime_error(path + ": rename failed: " + err);
  }
}

template <typename V>
std::vector<double> values(const V& v) {
  return std::vector<double>(v.data(), v.data() + v.size());
}

Eigen::VectorXd vectorOf(const std::vector<double>& v) {
  return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size()));
}

// A square matrix stored column-major.
Eigen::MatrixXd squareOf(const std::vector<double>& v, const char* what) {
  const auto n = static_cast<Eigen::Index>(std::llround(std::sqrt(static_cast<double>(v.size()))));
  if (n * n != static_cast<Eigen::Index>(v.size())) throw std::runtime_error(std::string(what) + " is not square");
  return Eigen::Map<const Eigen::MatrixXd>(v.data(), n, n);
}

json driversToJson(const Drivers& d) {
  return {{"motion_direction", values(d.motion_direction)}, {"recent_steps_rad", values(d.recent_steps_rad)}};
}

Drivers driversFromJson(const json& j) {
  Drivers d;
  const auto m = j.at("motion_direction").get<std::vector<double>>();
  const auto r = j.at("recent_steps_rad").get<std::vector<double>>();
  d.motion_direction = vectorOf(m);
  if (r.size() != m.size() * kPlayHistory) throw std::runtime_error("recent_steps_rad size");
  d.recent_steps_rad = Eigen::Map<const Eigen::MatrixXd>(r.data(), static_cast<Eigen::Index>(m.size()), kPlayHistory);
  return d;
}

json readingToJson(const PairedReading& p) {
  const Observation& o = p.observation;
  const Eigen::Quaterniond qn(o.measured_in_tracker.linear());
  return {{"q_rad", values(o.q_rad)},
          {"position_m", {o.measured_in_tracker.translation().x(), o.measured_in_tracker.translation().y(),
                          o.measured_in_tracker.translation().z()}},
          {"orientation_xyzw", {qn.x(), qn.y(), qn.z(), qn.w()}},
          {"pose6d", o.kind == MeasurementKind::kPose6D},
          {"sigma_position_m", o.sigma_position_m},
          {"sigma_orientation_rad", o.sigma_orientation_rad},
          {"tracker_stamp_ns", p.tracker_stamp_ns},
          {"tracker_sequence", p.tracker_sequence},
          {"joint_stamp_ns", p.joint_stamp_ns}};
}

PairedReading readingFromJson(const json& j) {
  PairedReading p;
  p.observation.q_rad = vectorOf(j.at("q_rad").get<std::vector<double>>());
  const auto pos = j.at("position_m").get<std::vector<double>>();
  const auto ori = j.at("orientation_xyzw").get<std::vector<double>>();
  p.observation.measured_in_tracker = Pose::Identity();
  p.observation.measured_in_tracker.translation() = Eigen::Vector3d(pos.at(0), pos.at(1), pos.at(2));
  p.observation.measured_in_tracker.linear() =
      Eigen::Quaterniond(ori.at(3), ori.at(0), ori.at(1), ori.at(2)).normalized().toRotationMatrix();
  p.observation.kind = j.at("pose6d").get<bool>() ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  p.observation.sigma_position_m = j.at("sigma_position_m").get<double>();
  p.observation.sigma_orientation_rad = j.at("sigma_orientation_rad").get<double>();
  p.tracker_stamp_ns = j.at("tracker_stamp_ns").get<std::int64_t>();
  p.tracker_sequence = j.at("tracker_sequence").get<std::uint64_t>();
  p.joint_stamp_ns = j.at("joint_stamp_ns").get<std::int64_t>();
  return p;
}

}  // namespace

std::string stateFilePath(const std::string& dir, const std::string& robot_id) {
  return (fs::path(dir) / (robot_id + ".state.json")).string();
}

std::string unusableStateMessage(const std::string& path, const std::string& why) {
  return path + ": " + why + " (move the file away to start this robot's calibration over)";
}

std::string engineStateToJson(const EngineState& s) {
  json j;
  j["format"] = kStateFormat;
  j["robot_id"] = s.robot_id;
  j["robot_name"] = s.robot_name;
  j["num_params"] = s.num_params;
  j["version"] = s.version;
  j["poses_used"] = s.poses_used;
  j["mode"] = s.mode == EngineMode::kContinuous ? "continuous" : "periodic";
  j["last_measurement_stamp_ns"] = s.last_measurement_stamp_ns;
  j["last_tracker_sequence"] = s.last_tracker_sequence;
  j["last_update_stamp_ns"] = s.last_update_stamp_ns;
  j["nominal"] = values(s.nominal);
  j["params"] = values(s.params);
  j["estimated"] = s.estimated;
  j["covariance"] = values(s.covariance);
  j["consecutive_outliers"] = s.consecutive_outliers;
  j["gate_window"] = s.gate_window;
  if (s.last_good) {
    const EngineState::Good& g = *s.last_good;
    j["last_good"] = {{"version", g.version},
                      {"params", values(g.params)},
                      {"extension_params", values(g.extension_params)},
                      {"estimated", g.estimated},
                      {"covariance", values(g.covariance)}};
  }
  j["extensions"] = s.extensions;
  j["extension_params"] = values(s.extension_params);
  j["estimated_extension"] = s.estimated_extension;
  if (s.play) {
    json play = json::array();
    for (const auto& J : s.play->joints) {
      json turns = json::array();
      for (const auto& t : J.turns) turns.push_back({t.stamp_ns, t.q_rad});
      play.push_back({{"turns", turns}, {"direction", J.direction}, {"extreme", {J.extreme.stamp_ns, J.extreme.q_rad}}});
    }
    j["play"] = {{"joints", play}, {"last_stamp_ns", s.play->last_stamp_ns}};
  }
  json recent = json::array();
  for (const auto& r : s.recent) recent.push_back({r.prior_error_m, r.post_error_m, r.post_error_rad, r.nis_per_row});
  j["recent"] = recent;
  json batch = json::array();
  for (const auto& b : s.pending_batch) {
    json o = readingToJson(b.reading);
    if (b.drivers) o["drivers"] = driversToJson(*b.drivers);
    batch.push_back(o);
  }
  j["pending_batch"] = batch;
  if (s.started_from)
    j["started_from"] = *s.started_from == EngineState::Start::kNominal           ? "nominal"
                        : *s.started_from == EngineState::Start::kCalibrationFile ? "calibration_file"
                                                                                  : "nominal_calibration_file_refused";
  j["file_drift_pending_since_ns"] = s.file_drift_pending_since_ns;
  j["start_warning"] = s.start_warning;
  return j.dump();
}

EngineState engineStateFromJson(const std::string& text) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    throw std::runtime_error(std::string("not a readable engine state: ") + e.what());
  }
  EngineState s;
  try {
    if (j.at("format") != kStateFormat) throw std::runtime_error("unknown format '" + j.at("format").dump() + "'");
    s.robot_id = j.at("robot_id").get<std::string>();
    s.robot_name = j.at("robot_name").get<std::string>();
    s.num_params = j.at("num_params").get<int>();
    s.mode = j.contains("mode") && j.at("mode") == "periodic" ? EngineMode::kPeriodic : EngineMode::kContinuous;
    s.nominal = vectorOf(j.at("nominal").get<std::vector<double>>());
    s.params = vectorOf(j.at("params").get<std::vector<double>>());
    s.estimated = j.at("estimated").get<std::vector<int>>();
    s.covariance = squareOf(j.at("covariance").get<std::vector<double>>(), "covariance");
    if (j.contains("extensions")) s.extensions = j.at("extensions").get<std::vector<std::string>>();
    if (j.contains("extension_params")) s.extension_params = vectorOf(j.at("extension_params").get<std::vector<double>>());
    if (j.contains("estimated_extension")) s.estimated_extension = j.at("estimated_extension").get<std::vector<int>>();
    if (j.contains("play")) {
      const json& pl = j.at("play");
      EngineState::Play play;
      for (const auto& J : pl.at("joints")) {
        PlayTracker::Joint x;
        for (const auto& t : J.at("turns")) x.turns.push_back({t.at(0).get<std::int64_t>(), t.at(1).get<double>()});
        x.direction = J.at("direction").get<int>();
        x.extreme = {J.at("extreme").at(0).get<std::int64_t>(), J.at("extreme").at(1).get<double>()};
        play.joints.push_back(std::move(x));
      }
      play.last_stamp_ns = pl.at("last_stamp_ns").get<std::int64_t>();
      s.play = std::move(play);
    }
    s.version = j.at("version").get<std::uint64_t>();
    s.poses_used = j.at("poses_used").get<std::uint32_t>();
    s.last_measurement_stamp_ns = j.at("last_measurement_stamp_ns").get<std::int64_t>();
    s.last_tracker_sequence = j.at("last_tracker_sequence").get<std::uint64_t>();
    s.last_update_stamp_ns = j.at("last_update_stamp_ns").get<std::int64_t>();
    for (const auto& r : j.at("recent"))
      s.recent.push_back({r.at(0).get<double>(), r.at(1).get<double>(), r.at(2).get<double>(), r.at(3).get<double>()});
    for (const auto& b : j.at("pending_batch"))
      s.pending_batch.push_back(
          {readingFromJson(b), b.contains("drivers") ? std::optional<Drivers>(driversFromJson(b.at("drivers"))) : std::nullopt});
    if (j.contains("consecutive_outliers")) s.consecutive_outliers = j.at("consecutive_outliers").get<int>();
    if (j.contains("gate_window")) s.gate_window = j.at("gate_window").get<std::vector<double>>();
    if (j.contains("last_good")) {
      const json& g = j.at("last_good");
      EngineState::Good good;
      good.version = g.at("version").get<std::uint64_t>();
      good.params = vectorOf(g.at("params").get<std::vector<double>>());
      good.extension_params = vectorOf(g.at("extension_params").get<std::vector<double>>());
      good.estimated = g.at("estimated").get<std::vector<int>>();
      good.covariance = squareOf(g.at("covariance").get<std::vector<double>>(), "last_good: covariance");
      s.last_good = std::move(good);
    }
    if (j.contains("started_from")) {
      const std::string v = j.at("started_from").get<std::string>();
      if (v == "nominal") s.started_from = EngineState::Start::kNominal;
      else if (v == "calibration_file") s.started_from = EngineState::Start::kCalibrationFile;
      else if (v == "nominal_calibration_file_refused") s.started_from = EngineState::Start::kNominalFileRefused;
      else throw std::runtime_error("started_from: unknown value '" + v + "'");
    }
    if (j.contains("file_drift_pending_since_ns"))
      s.file_drift_pending_since_ns = j.at("file_drift_pending_since_ns").get<std::int64_t>();
    if (j.contains("start_warning")) s.start_warning = j.at("start_warning").get<std::string>();
  } catch (const json::exception& e) {
    throw std::runtime_error(std::string("missing or malformed field: ") + e.what());
  }
  return s;
}

void saveEngineState(const std::string& path, const EngineState& state) {
  std::error_code ec;
  const fs::path dir = fs::path(path).parent_path();
  if (!dir.empty()) fs::create_directories(dir, ec);
  atomicWrite(path, engineStateToJson(state));
}

std::optional<EngineState> loadEngineState(const std::string& path) {
  std::ifstream in(path);
  if (!in) return std::nullopt;
  std::ostringstream text;
  text << in.rdbuf();
  try {
    return engineStateFromJson(text.str());
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(unusableStateMessage(path, e.what()));
  }
}

void syncStateFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error(path + ": cannot open to fsync: " + std::strerror(errno));
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) throw std::runtime_error(path + ": fsync failed: " + std::strerror(err));
  const fs::path p(path);
  const int dfd = ::open(p.parent_path().empty() ? "." : p.parent_path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace cellcal
