// Strict YAML reading shared by the robot file and the cell file (private to core/src).
// Every error throws ConfigError "<source>:<line>:<column>: <field>: <message>".
#pragma once

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cellcal/core/files/robot_yaml.hpp"

#include <fstream>

namespace cellcal::detail {

// Reads a configuration file (robot or cell file: a few kB) whole. Refuses what cannot be one: missing or unreadable,
// empty, or larger than 1 MiB (a wrong file, or a device such as /dev/zero that would never end). `what` names the
// kind of file in the error ("robot file").
inline std::string readConfigFile(const std::string& path, const char* what) {
  constexpr std::size_t kMaxBytes = 1 << 20;
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path + ": cannot open " + what);
  std::string text(kMaxBytes + 1, '\0');
  in.read(&text[0], static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<std::size_t>(in.gcount()));
  if (text.size() > kMaxBytes)
    throw ConfigError(path + ": more than 1 MiB; a " + what + " is a few kB (the wrong file?)");
  if (text.find_first_not_of(" \t\r\n") == std::string::npos) throw ConfigError(path + ": file is empty");
  return text;
}

class YamlReader {
 public:
  explicit YamlReader(std::string source) : source_(std::move(source)) {}

  [[noreturn]] void fail(const YAML::Node& node, const std::string& field, const std::string& msg) const {
    std::ostringstream s;
    s << source_;
    if (node.IsDefined() && node.Mark().line >= 0) s << ":" << node.Mark().line + 1 << ":" << node.Mark().column + 1;
    s << ": " << field << ": " << msg;
    throw ConfigError(s.str());
  }

  void requireMap(const YAML::Node& node, const std::string& field) const {
    if (!node.IsMap()) fail(node, field, "expected a mapping");
  }

  // Every key of `node` must be in `allowed`; names the first offending key and its line.
  void checkKeys(const YAML::Node& node, const std::string& field, const std::set<std::string>& allowed) const {
    std::set<std::string> seen;
    for (const auto& kv : node) {
      if (!kv.first.IsScalar()) fail(kv.first, field.empty() ? "<document>" : field, "expected a plain key, got a list or mapping as a key");
      const std::string key = kv.first.Scalar();
      const std::string where = field.empty() ? key : field + "." + key;
      if (!allowed.count(key)) {
        std::string list;
        for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
        fail(kv.first, where, "unknown key (allowed: " + list + ")");
      }
      if (!seen.insert(key).second) fail(kv.first, where, "duplicated key");
    }
  }

  YAML::Node required(const YAML::Node& parent, const std::string& key, const std::string& field) const {
    const YAML::Node n = parent[key];
    if (!n.IsDefined() || n.IsNull()) fail(parent, field, "missing required key '" + key + "'");
    return n;
  }

  double number(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(node, field, "expected a number");
    double v = 0;
    try {
      v = node.as<double>();
    } catch (const YAML::Exception&) {
      fail(node, field, "expected a number, got '" + node.Scalar() + "'");
    }
    if (!std::isfinite(v)) fail(node, field, "must be finite, got '" + node.Scalar() + "'");
    return v;
  }

  bool boolean(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(node, field, "expected true or false");
    try {
      return node.as<bool>();
    } catch (const YAML::Exception&) {
      fail(node, field, "expected true or false, got '" + node.Scalar() + "'");
    }
  }

  std::vector<double> vector(const YAML::Node& node, const std::string& field, size_t size) const {
    if (!node.IsSequence() || node.size() != size)
      fail(node, field, "expected a list of " + std::to_string(size) + " numbers");
    std::vector<double> out;
    for (size_t i = 0; i < size; ++i) out.push_back(number(node[i], field + "[" + std::to_string(i) + "]"));
    return out;
  }

  std::string string(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar() || node.Scalar().empty()) fail(node, field, "expected a non-empty string");
    return node.Scalar();
  }

  long long integer(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(node, field, "expected an integer");
    const std::string& t = node.Scalar();
    char* end = nullptr;
    errno = 0;
    const long long v = std::strtoll(t.c_str(), &end, 10);
    if (t.empty() || *end != '\0' || errno == ERANGE) fail(node, field, "expected an integer, got '" + t + "'");
    return v;
  }

  std::uint64_t unsignedInteger(const YAML::Node& node, const std::string& field) const {
    if (!node.IsScalar()) fail(node, field, "expected a non-negative integer");
    const std::string& t = node.Scalar();
    char* end = nullptr;
    errno = 0;
    const unsigned long long v = std::strtoull(t.c_str(), &end, 10);
    if (t.empty() || t[0] == '-' || *end != '\0' || errno == ERANGE)
      fail(node, field, "expected a non-negative integer, got '" + t + "'");
    return v;
  }

  // Parses a whole document; syntax errors name the line and column.
  YAML::Node load(const std::string& text) const {
    try {
      return YAML::Load(text);
    } catch (const YAML::ParserException& e) {
      throw ConfigError(source_ + ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1) +
                        ": YAML syntax error: " + e.msg);
    }
  }

  // A frame { x_mm, y_mm, z_mm, roll_deg, pitch_deg, yaw_deg } as SI (m, rad), all six keys required.
  void frame(const YAML::Node& node, const std::string& field, double out_si[6]) const {
    requireMap(node, field);
    static const char* keys[] = {"x_mm", "y_mm", "z_mm", "roll_deg", "pitch_deg", "yaw_deg"};
    checkKeys(node, field, {keys, keys + 6});
    for (int k = 0; k < 6; ++k) {
      const double v = number(required(node, keys[k], field + "." + keys[k]), field + "." + keys[k]);
      out_si[k] = k < 3 ? v * 1e-3 : v * 3.14159265358979323846 / 180.0;
    }
  }

  const std::string& source() const { return source_; }

 private:
  std::string source_;
};

}  // namespace cellcal::detail
