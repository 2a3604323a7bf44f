#include "cellcal/core/engine/state_journal.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <array>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <type_traits>

#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/files/crc32.hpp"
#include "write_all.hpp"

namespace cellcal {

namespace {

namespace fs = std::filesystem;

// Record: magic, payload length, CRC-32 of the payload, payload. The magic also tells the byte order.
constexpr std::uint32_t kRecordMagic = 0x314a4343;  // "CCJ1" read little-endian
constexpr std::uint32_t kPayloadFormat = 1;
constexpr std::size_t kHeaderBytes = 12;
constexpr std::uint32_t kMaxRecordBytes = 256u << 20;

class Writer {
 public:
  template <class T>
  void pod(T v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  void size(std::size_t n) { pod(static_cast<std::uint64_t>(n)); }
  void str(const std::string& s) {
    size(s.size());
    out.append(s);
  }
  void doubles(const double* p, std::size_t n) {
    size(n);
    out.append(reinterpret_cast<const char*>(p), n * sizeof(double));
  }
  void vec(const Eigen::VectorXd& v) { doubles(v.data(), static_cast<std::size_t>(v.size())); }
  void vec(const std::vector<double>& v) { doubles(v.data(), v.size()); }
  void ints(const std::vector<int>& v) {
    size(v.size());
    for (int x : v) pod(static_cast<std::int32_t>(x));
  }
  // A square matrix, column-major (as the JSON snapshot).
  void square(const Eigen::MatrixXd& m) {
    if (m.rows() != m.cols()) throw std::runtime_error("covariance is not square");
    doubles(m.data(), static_cast<std::size_t>(m.size()));
  }
  std::string out;
};

class Reader {
 public:
  explicit Reader(const std::string& b) : bytes(b) {}
  template <class T>
  T pod(const char* what) {
    T v;
    need(sizeof v, what);
    std::memcpy(&v, bytes.data() + at, sizeof v);
    at += sizeof v;
    return v;
  }
  // A count of items of `item_bytes` each: never more than what is left.
  std::size_t size(std::size_t item_bytes, const char* what) {
    const auto n = pod<std::uint64_t>(what);
    if (item_bytes > 0 && n > (bytes.size() - at) / item_bytes)
      throw std::runtime_error(std::string(what) + ": count " + std::to_string(n) + " beyond the record");
    return static_cast<std::size_t>(n);
  }
  std::string str(const char* what) {
    const std::size_t n = size(1, what);
    std::string s = bytes.substr(at, n);
    at += n;
    return s;
  }
  std::vector<double> doubles(const char* what) {
    const std::size_t n = size(sizeof(double), what);
    std::vector<double> v(n);
    if (n) std::memcpy(v.data(), bytes.data() + at, n * sizeof(double));
    at += n * sizeof(double);
    return v;
  }
  Eigen::VectorXd vec(const char* what) {
    const auto v = doubles(what);
    return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size()));
  }
  std::vector<int> ints(const char* what) {
    const std::size_t n = size(sizeof(std::int32_t), what);
    std::vector<int> v(n);
    for (auto& x : v) x = pod<std::int32_t>(what);
    return v;
  }
  Eigen::MatrixXd square(const char* what) {
    const auto v = doubles(what);
    Eigen::Index n = 0;
    while (static_cast<std::size_t>(n * n) < v.size()) ++n;
    if (static_cast<std::size_t>(n * n) != v.size()) throw std::runtime_error(std::string(what) + " is not square");
    return Eigen::Map<const Eigen::MatrixXd>(v.data(), n, n);
  }
  bool flag(const char* what) {
    const auto b = pod<std::uint8_t>(what);
    if (b > 1) throw std::runtime_error(std::string(what) + ": not a flag");
    return b == 1;
  }
  void need(std::size_t n, const char* what) const {
    if (bytes.size() - at < n) throw std::runtime_error(std::string(what) + ": the record ends early");
  }
  bool done() const { return at == bytes.size(); }

 private:
  const std::string& bytes;
  std::size_t at = 0;
};

void writeReading(Writer& w, const PairedReading& p) {
  const Observation& o = p.observation;
  w.vec(o.q_rad);
  // The pose whole (translation, rotation matrix column-major): a record restores it bit for bit, where the snapshot
  // keeps its quaternion.
  const Eigen::Matrix4d m = o.measured_in_tracker.matrix();
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 3; ++r) w.pod(m(r, c));
  w.pod(static_cast<std::uint8_t>(o.kind == MeasurementKind::kPose6D));
  w.pod(o.sigma_position_m);
  w.pod(o.sigma_orientation_rad);
  w.pod(p.tracker_stamp_ns);
  w.pod(p.tracker_sequence);
  w.pod(p.joint_stamp_ns);
}

PairedReading readReading(Reader& r) {
  PairedReading p;
  p.observation.q_rad = r.vec("q_rad");
  p.observation.measured_in_tracker = Pose::Identity();
  Eigen::Matrix4d& m = p.observation.measured_in_tracker.matrix();
  for (int c = 0; c < 4; ++c)
    for (int k = 0; k < 3; ++k) m(k, c) = r.pod<double>("pose");
  p.observation.kind = r.flag("pose6d") ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  p.observation.sigma_position_m = r.pod<double>("sigma_position_m");
  p.observation.sigma_orientation_rad = r.pod<double>("sigma_orientation_rad");
  p.tracker_stamp_ns = r.pod<std::int64_t>("tracker_stamp_ns");
  p.tracker_sequence = r.pod<std::uint64_t>("tracker_sequence");
  p.joint_stamp_ns = r.pod<std::int64_t>("joint_stamp_ns");
  return p;
}

// The whole file; "" when there is none.
std::string readWholeFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return "";
    throw std::runtime_error(path + ": cannot open: " + std::strerror(errno));
  }
  std::string data;
  char buf[1 << 16];
  for (;;) {
    const ssize_t k = ::read(fd, buf, sizeof buf);
    if (k < 0) {
      if (errno == EINTR) continue;
      const std::string err = std::strerror(errno);
      ::close(fd);
      throw std::runtime_error(path + ": read failed: " + err);
    }
    if (k == 0) break;
    data.append(buf, static_cast<std::size_t>(k));
  }
  ::close(fd);
  return data;
}

}  // namespace

std::string stateJournalPath(const std::string& state_file) {
  return fs::path(state_file).replace_extension(".journal").string();
}

std::string engineStateToBinary(const EngineState& s) {
  Writer w;
  w.pod(kPayloadFormat);
  w.str(s.robot_id);
  w.str(s.robot_name);
  w.pod(static_cast<std::int32_t>(s.num_params));
  w.pod(s.version);
  w.pod(s.poses_used);
  w.pod(static_cast<std::uint8_t>(s.mode == EngineMode::kPeriodic));
  w.pod(s.last_measurement_stamp_ns);
  w.pod(s.last_tracker_sequence);
  w.pod(s.last_update_stamp_ns);
  w.vec(s.nominal);
  w.vec(s.params);
  w.ints(s.estimated);
  w.square(s.covariance);
  w.pod(static_cast<std::int32_t>(s.consecutive_outliers));
  w.vec(s.gate_window);
  w.pod(static_cast<std::uint8_t>(s.last_good.has_value()));
  if (s.last_good) {
    w.pod(s.last_good->version);
    w.vec(s.last_good->params);
    w.vec(s.last_good->extension_params);
    w.ints(s.last_good->estimated);
    w.square(s.last_good->covariance);
  }
  w.size(s.extensions.size());
  for (const auto& e : s.extensions) w.str(e);
  w.vec(s.extension_params);
  w.ints(s.estimated_extension);
  w.pod(static_cast<std::uint8_t>(s.play.has_value()));
  if (s.play) {
    w.size(s.play->joints.size());
    for (const auto& j : s.play->joints) {
      w.size(j.turns.size());
      for (const auto& t : j.turns) {
        w.pod(t.stamp_ns);
        w.pod(t.q_rad);
      }
      w.pod(static_cast<std::int32_t>(j.direction));
      w.pod(j.extreme.stamp_ns);
      w.pod(j.extreme.q_rad);
    }
    w.pod(s.play->last_stamp_ns);
  }
  w.size(s.recent.size());
  for (const auto& r : s.recent)
    for (double v : {r.prior_error_m, r.post_error_m, r.post_error_rad, r.nis_per_row}) w.pod(v);
  w.size(s.pending_batch.size());
  for (const auto& b : s.pending_batch) {
    writeReading(w, b.reading);
    w.pod(static_cast<std::uint8_t>(b.drivers.has_value()));
    if (b.drivers) {
      if (b.drivers->recent_steps_rad.size() != b.drivers->motion_direction.size() * kPlayHistory)
        throw std::runtime_error("pending_batch drivers: recent_steps_rad size");
      w.vec(b.drivers->motion_direction);
      w.doubles(b.drivers->recent_steps_rad.data(), static_cast<std::size_t>(b.drivers->recent_steps_rad.size()));
    }
  }
  // Appended fields (records written before them end above and read as their defaults).
  w.pod(static_cast<std::uint8_t>(s.started_from.has_value()));
  if (s.started_from) w.pod(static_cast<std::uint8_t>(*s.started_from));
  w.pod(s.file_drift_pending_since_ns);
  w.str(s.start_warning);
  return std::move(w.out);
}

EngineState engineStateFromBinary(const std::string& bytes) {
  Reader r(bytes);
  const auto format = r.pod<std::uint32_t>("format");
  if (format != kPayloadFormat) throw std::runtime_error("unknown record format " + std::to_string(format));
  EngineState s;
  s.robot_id = r.str("robot_id");
  s.robot_name = r.str("robot_name");
  s.num_params = r.pod<std::int32_t>("num_params");
  s.version = r.pod<std::uint64_t>("version");
  s.poses_used = r.pod<std::uint32_t>("poses_used");
  s.mode = r.flag("mode") ? EngineMode::kPeriodic : EngineMode::kContinuous;
  s.last_measurement_stamp_ns = r.pod<std::int64_t>("last_measurement_stamp_ns");
  s.last_tracker_sequence = r.pod<std::uint64_t>("last_tracker_sequence");
  s.last_update_stamp_ns = r.pod<std::int64_t>("last_update_stamp_ns");
  s.nominal = r.vec("nominal");
  s.params = r.vec("params");
  s.estimated = r.ints("estimated");
  s.covariance = r.square("covariance");
  s.consecutive_outliers = r.pod<std::int32_t>("consecutive_outliers");
  s.gate_window = r.doubles("gate_window");
  if (r.flag("last_good")) {
    EngineState::Good g;
    g.version = r.pod<std::uint64_t>("last_good.version");
    g.params = r.vec("last_good.params");
    g.extension_params = r.vec("last_good.extension_params");
    g.estimated = r.ints("last_good.estimated");
    g.covariance = r.square("last_good.covariance");
    s.last_good = std::move(g);
  }
  const std::size_t n_ext = r.size(8, "extensions");
  for (std::size_t i = 0; i < n_ext; ++i) s.extensions.push_back(r.str("extensions"));
  s.extension_params = r.vec("extension_params");
  s.estimated_extension = r.ints("estimated_extension");
  if (r.flag("play")) {
    EngineState::Play play;
    const std::size_t joints = r.size(8 + 4 + 16, "play.joints");
    for (std::size_t j = 0; j < joints; ++j) {
      PlayTracker::Joint x;
      const std::size_t turns = r.size(16, "play.turns");
      for (std::size_t t = 0; t < turns; ++t) {
        const auto stamp = r.pod<std::int64_t>("play.turns");
        x.turns.push_back({stamp, r.pod<double>("play.turns")});
      }
      x.direction = r.pod<std::int32_t>("play.direction");
      const auto stamp = r.pod<std::int64_t>("play.extreme");
      x.extreme = {stamp, r.pod<double>("play.extreme")};
      play.joints.push_back(std::move(x));
    }
    play.last_stamp_ns = r.pod<std::int64_t>("play.last_stamp_ns");
    s.play = std::move(play);
  }
  const std::size_t n_recent = r.size(32, "recent");
  for (std::size_t i = 0; i < n_recent; ++i) {
    EngineState::Recent x;
    x.prior_error_m = r.pod<double>("recent");
    x.post_error_m = r.pod<double>("recent");
    x.post_error_rad = r.pod<double>("recent");
    x.nis_per_row = r.pod<double>("recent");
    s.recent.push_back(x);
  }
  const std::size_t n_batch = r.size(8, "pending_batch");
  for (std::size_t i = 0; i < n_batch; ++i) {
    EngineState::PendingPose p;
    p.reading = readReading(r);
    if (r.flag("pending_batch.drivers")) {
      Drivers d;
      d.motion_direction = r.vec("drivers.motion_direction");
      const auto steps = r.doubles("drivers.recent_steps_rad");
      if (steps.size() != static_cast<std::size_t>(d.motion_direction.size()) * kPlayHistory)
        throw std::runtime_error("recent_steps_rad size");
      d.recent_steps_rad =
          Eigen::Map<const Eigen::MatrixXd>(steps.data(), d.motion_direction.size(), kPlayHistory);
      p.drivers = std::move(d);
    }
    s.pending_batch.push_back(std::move(p));
  }
  if (!r.done()) {  // the fields appended since the first records
    if (r.flag("started_from")) {
      const auto v = r.pod<std::uint8_t>("started_from");
      if (v > static_cast<std::uint8_t>(EngineState::Start::kNominalFileRefused))
        throw std::runtime_error("started_from: unknown value " + std::to_string(v));
      s.started_from = static_cast<EngineState::Start>(v);
    }
    s.file_drift_pending_since_ns = r.pod<std::int64_t>("file_drift_pending_since_ns");
    s.start_warning = r.str("start_warning");
  }
  if (!r.done()) throw std::runtime_error("bytes after the state");
  return s;
}

LoadedState loadDurableState(const std::string& state_file) {
  LoadedState out;
  out.state = loadEngineState(state_file);
  const std::string journal = stateJournalPath(state_file);
  const std::string data = readWholeFile(journal);
  std::size_t at = 0;
  while (at < data.size()) {
    std::string why;
    std::uint32_t head[3] = {0, 0, 0};
    if (data.size() - at < kHeaderBytes) {
      why = "a record header cut short";
    } else {
      std::memcpy(head, data.data() + at, kHeaderBytes);
      if (head[0] != kRecordMagic)
        why = "no record starts here";
      else if (head[1] > kMaxRecordBytes || head[1] > data.size() - at - kHeaderBytes)
        why = "a record cut short";
      else if (crc32(data.data() + at + kHeaderBytes, head[1]) != head[2])
        why = "a record whose CRC-32 does not match";
    }
    if (why.empty()) {
      try {
        out.state = engineStateFromBinary(data.substr(at + kHeaderBytes, head[1]));
      } catch (const std::runtime_error& e) {
        // The CRC matched: not a torn write but a record this version cannot read.
        throw std::runtime_error(unusableStateMessage(journal, "record " + std::to_string(out.journal_records + 1) +
                                                                   " at byte " + std::to_string(at) + ": " + e.what()));
      }
      ++out.journal_records;
      at += kHeaderBytes + head[1];
      continue;
    }
    out.torn_bytes = data.size() - at;
    out.torn_reason = why + " at byte " + std::to_string(at);
    break;
  }
  return out;
}

DurableState::DurableState(std::string state_file, Options options)
    : state_file_(std::move(state_file)), journal_file_(stateJournalPath(state_file_)), options_(options) {}

DurableState::~DurableState() {
  if (fd_ >= 0) ::close(fd_);
}

const std::string& DurableState::savedPath() const {
  return options_.durability == Durability::kJournal ? journal_file_ : state_file_;
}

std::optional<EngineState> DurableState::load() {
  LoadedState l = loadDurableState(state_file_);
  // Later records must never follow a torn one: what was read becomes the snapshot, the journal starts empty.
  if (l.state && (l.journal_records > 0 || l.torn_bytes > 0)) compact(*l.state);
  else if (!l.state && l.torn_bytes > 0) fs::remove(journal_file_);  // a first record cut short: nothing was published
  return std::move(l.state);
}

void DurableState::openJournal() {
  if (fd_ >= 0) return;
  std::error_code ec;
  const fs::path dir = fs::path(journal_file_).parent_path();
  if (!dir.empty()) fs::create_directories(dir, ec);
  fd_ = ::open(journal_file_.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error(journal_file_ + ": cannot open for appending: " + std::strerror(errno));
  struct stat st {};
  journal_bytes_ = ::fstat(fd_, &st) == 0 ? static_cast<std::uint64_t>(st.st_size) : 0;
}

void DurableState::save(const EngineState& state) {
  if (options_.durability == Durability::kSnapshot) {
    saveEngineState(state_file_, state);
    return;
  }
  openJournal();
  const std::string payload = engineStateToBinary(state);
  std::string record(kHeaderBytes, '\0');
  const std::uint32_t head[3] = {kRecordMagic, static_cast<std::uint32_t>(payload.size()),
                                 crc32(payload.data(), payload.size())};
  std::memcpy(record.data(), head, kHeaderBytes);
  record += payload;
  try {
    detail::writeAll(fd_, record.data(), record.size(), journal_file_);
  } catch (...) {
    // A partial record (disk full): cut it off so the next one follows whole records.
    if (::ftruncate(fd_, static_cast<off_t>(journal_bytes_)) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
    throw;
  }
  journal_bytes_ += record.size();
}

bool DurableState::compactionDue() const {
  return options_.durability == Durability::kJournal && journal_bytes_ >= options_.compact_after_bytes;
}

void DurableState::compact(const EngineState& state) {
  // While running, `state` may be newer than the last record (a failed save): it becomes the last record first, so
  // a crash before the journal is emptied still reads it last.
  if (fd_ >= 0) save(state);
  saveEngineState(state_file_, state);  // atomic: the journal still holds the same state until it is emptied
  syncStateFile(state_file_);           // on disk before the records that led to it go
  if (fd_ >= 0) {
    if (::ftruncate(fd_, 0) != 0) throw std::runtime_error(journal_file_ + ": cannot empty: " + std::strerror(errno));
  } else if (::truncate(journal_file_.c_str(), 0) != 0 && errno != ENOENT) {
    throw std::runtime_error(journal_file_ + ": cannot empty: " + std::strerror(errno));
  }
  journal_bytes_ = 0;
  ++compactions_;
}

void DurableState::close(const EngineState& state) {
  if (options_.durability == Durability::kJournal && journal_bytes_ > 0) compact(state);
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace cellcal
