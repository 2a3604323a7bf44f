#include "cellcal/core/engine/state_file.hpp"

#include "state_fields.hpp"
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

using state_fields::Presence;

// The state file's codec (state_fields.hpp): a JSON object by name; a tuple is an array by position.
class JsonWriter {
 public:
  static constexpr bool kReads = false;
  explicit JsonWriter(json& node, bool positional = false) : node_(node), positional_(positional) {}
  void text(const char* n, std::string& v, Presence = Presence::kRequired) { put(n, v); }
  template <class Stored, class T>
  void number(const char* n, T& v, Presence = Presence::kRequired) { put(n, v); }
  void flag(const char* n, bool& v, Presence = Presence::kRequired) { put(n, v); }
  void vec(const char* n, Eigen::VectorXd& v, Presence = Presence::kRequired) { put(n, values(v)); }
  void doubles(const char* n, std::vector<double>& v, Presence = Presence::kRequired) { put(n, v); }
  void ints(const char* n, std::vector<int>& v, Presence = Presence::kRequired) { put(n, v); }
  void square(const char* n, Eigen::MatrixXd& v, Presence = Presence::kRequired) { put(n, values(v)); }
  void texts(const char* n, std::vector<std::string>& v, Presence = Presence::kRequired) { put(n, v); }
  template <class E>
  void choice(const char* n, E& v, std::initializer_list<const char*> names, Presence = Presence::kRequired) {
    put(n, names.begin()[static_cast<int>(v)]);
  }
  template <class E>
  void choice(const char* n, std::optional<E>& v, std::initializer_list<const char*> names, Presence p) {
    if (v) choice(n, *v, names, p);
  }
  template <class T, class F>
  void object(const char* n, std::optional<T>& v, F fields, Presence = Presence::kOptional) {
    if (!v) return;
    json o = json::object();
    JsonWriter w(o);
    fields(w, *v);
    put(n, o);
  }
  template <class Seq, class F>
  void objects(const char* n, Seq& v, std::size_t, F fields, Presence = Presence::kRequired) {
    put(n, items(v, fields, false));
  }
  template <class Seq, class F>
  void tuples(const char* n, Seq& v, std::size_t, F fields) { put(n, items(v, fields, true)); }
  template <class T, class F>
  void tuple(const char* n, T& v, F fields) {
    json a = json::array();
    JsonWriter w(a, true);
    fields(w, v);
    put(n, a);
  }
  void pose(Pose& T) {
    const Eigen::Quaterniond q(T.linear());
    put("position_m", std::vector<double>{T.translation().x(), T.translation().y(), T.translation().z()});
    put("orientation_xyzw", std::vector<double>{q.x(), q.y(), q.z(), q.w()});
  }

 private:
  template <class V>
  void put(const char* n, const V& v) {
    if (positional_) node_.push_back(v);
    else node_[n] = v;
  }
  template <class Seq, class F>
  static json items(Seq& v, F fields, bool positional) {
    json a = json::array();
    for (auto& x : v) {
      json o = positional ? json::array() : json::object();
      JsonWriter w(o, positional);
      fields(w, x);
      a.push_back(std::move(o));
    }
    return a;
  }
  json& node_;
  bool positional_;
};

class JsonReader {
 public:
  static constexpr bool kReads = true;
  explicit JsonReader(const json& node, bool positional = false) : node_(node), positional_(positional) {}
  void text(const char* n, std::string& v, Presence p = Presence::kRequired) {
    if (has(n, p)) v = get(n).get<std::string>();
  }
  template <class Stored, class T>
  void number(const char* n, T& v, Presence p = Presence::kRequired) {
    if (has(n, p)) v = get(n).get<T>();
  }
  void flag(const char* n, bool& v, Presence p = Presence::kRequired) {
    if (has(n, p)) v = get(n).get<bool>();
  }
  void vec(const char* n, Eigen::VectorXd& v, Presence p = Presence::kRequired) {
    if (!has(n, p)) return;
    const auto x = get(n).get<std::vector<double>>();
    v = Eigen::Map<const Eigen::VectorXd>(x.data(), static_cast<Eigen::Index>(x.size()));
  }
  void doubles(const char* n, std::vector<double>& v, Presence p = Presence::kRequired) {
    if (has(n, p)) v = get(n).get<std::vector<double>>();
  }
  void ints(const char* n, std::vector<int>& v, Presence p = Presence::kRequired) {
    if (has(n, p)) v = get(n).get<std::vector<int>>();
  }
  // A square matrix stored column-major.
  void square(const char* n, Eigen::MatrixXd& v, Presence p = Presence::kRequired) {
    if (!has(n, p)) return;
    const auto x = get(n).get<std::vector<double>>();
    const auto k = static_cast<Eigen::Index>(std::llround(std::sqrt(static_cast<double>(x.size()))));
    if (k * k != static_cast<Eigen::Index>(x.size())) throw std::runtime_error(std::string(n) + " is not square");
    v = Eigen::Map<const Eigen::MatrixXd>(x.data(), k, k);
  }
  void texts(const char* n, std::vector<std::string>& v, Presence p = Presence::kRequired) {
    if (has(n, p)) v = get(n).get<std::vector<std::string>>();
  }
  template <class E>
  void choice(const char* n, E& v, std::initializer_list<const char*> names, Presence p = Presence::kRequired) {
    if (!has(n, p)) return;
    const std::string x = get(n).get<std::string>();
    for (std::size_t i = 0; i < names.size(); ++i)
      if (x == names.begin()[i]) {
        v = static_cast<E>(i);
        return;
      }
    throw std::runtime_error(std::string(n) + ": unknown value '" + x + "'");
  }
  template <class E>
  void choice(const char* n, std::optional<E>& v, std::initializer_list<const char*> names, Presence p) {
    if (!node_.contains(n)) return;
    E e{};
    choice(n, e, names, p);
    v = e;
  }
  template <class T, class F>
  void object(const char* n, std::optional<T>& v, F fields, Presence = Presence::kOptional) {
    if (!node_.contains(n)) return;
    T x{};
    JsonReader r(node_.at(n));
    fields(r, x);
    v = std::move(x);
  }
  template <class Seq, class F>
  void objects(const char* n, Seq& v, std::size_t, F fields, Presence p = Presence::kRequired) {
    if (has(n, p)) items(n, v, fields, false);
  }
  template <class Seq, class F>
  void tuples(const char* n, Seq& v, std::size_t, F fields) { items(n, v, fields, true); }
  template <class T, class F>
  void tuple(const char* n, T& v, F fields) {
    JsonReader r(get(n), true);
    fields(r, v);
  }
  void pose(Pose& T) {
    const auto p = get("position_m").get<std::vector<double>>();
    const auto q = get("orientation_xyzw").get<std::vector<double>>();
    T = Pose::Identity();
    T.translation() = Eigen::Vector3d(p.at(0), p.at(1), p.at(2));
    T.linear() = Eigen::Quaterniond(q.at(3), q.at(0), q.at(1), q.at(2)).normalized().toRotationMatrix();
  }

 private:
  bool has(const char* n, Presence p) {
    if (positional_ || p == Presence::kRequired) return true;  // absent required fields throw in get()
    return node_.contains(n);
  }
  const json& get(const char* n) { return positional_ ? node_.at(index_++) : node_.at(n); }
  template <class Seq, class F>
  void items(const char* n, Seq& v, F fields, bool positional) {
    for (const auto& o : get(n)) {
      typename Seq::value_type x{};
      JsonReader r(o, positional);
      fields(r, x);
      v.push_back(std::move(x));
    }
  }
  const json& node_;
  bool positional_;
  std::size_t index_ = 0;
};

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
  JsonWriter w(j);
  state_fields::writeFields(w, s);
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
    JsonReader r(j);
    state_fields::engineState(r, s);
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
