#include "cellcal/core/model/model_extension.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>

#include "causes/cause_support.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

namespace {
constexpr double kStillRad = 1e-4;  // a joint that moved less than this keeps its last direction
}  // namespace

const char* causeName(Cause c) { return c == Cause::kNone ? "none" : causeModel(c).name(); }

std::optional<Cause> causeFromName(const std::string& name) {
  if (name == "none") return Cause::kNone;
  for (const CauseModel* c : causeModels())
    if (name == c->name()) return c->id();
  return std::nullopt;
}

const std::vector<Cause>& extensionCauses() {
  static const std::vector<Cause> diagnosed = [] {
    std::vector<Cause> out;
    for (const CauseModel* c : causeModels())
      if (c->diagnosed()) out.push_back(c->id());
    return out;
  }();
  return diagnosed;
}

bool followsThermalDriver(Cause c) {
  return c != Cause::kNone && causeModel(c).driver() == CauseModel::Driver::kThermal;
}

bool followsPath(Cause c) { return c != Cause::kNone && causeModel(c).driver() == CauseModel::Driver::kPath; }

double warmUpDriver(double t_h, double tau_h) {
  return tau_h > 0 && std::isfinite(tau_h) ? tau_h * -std::expm1(-t_h / tau_h) : t_h;
}

double thermalDriverValue(const Extension& ext, const Drivers& drivers) {
  return drivers.thermal_is_time ? warmUpDriver(drivers.thermal, ext.time_constant_h) : drivers.thermal;
}

DriverTable driversFromSequence(const std::vector<Eigen::VectorXd>& q_rad,
                                const std::vector<std::optional<double>>& temperature_c,
                                const std::vector<std::optional<double>>& stamp_s) {
  DriverTable t;
  const size_t n = q_rad.size();
  t.rows.resize(n);
  bool all_temp = n > 0 && temperature_c.size() == n, all_stamp = n > 0 && stamp_s.size() == n;
  for (size_t i = 0; i < n; ++i) {
    all_temp = all_temp && temperature_c[i].has_value();
    all_stamp = all_stamp && stamp_s[i].has_value();
  }
  if (all_temp) {
    double mean_c = 0, lo = INFINITY, hi = -INFINITY;
    for (const auto& c : temperature_c) {
      mean_c += *c;
      lo = std::min(lo, *c);
      hi = std::max(hi, *c);
    }
    mean_c /= static_cast<double>(n);
    if (hi - lo < kConstantTemperatureC) {
      t.constant_temperature_c = mean_c;
      all_temp = false;
    }
  }
  if (all_temp) {
    double mean_c = 0;
    for (const auto& c : temperature_c) mean_c += *c;
    mean_c /= static_cast<double>(n);
    for (size_t i = 0; i < n; ++i) t.rows[i].thermal = *temperature_c[i] - mean_c;
    t.has_thermal = true;
    t.thermal_source = "temperature_c";
  } else if (all_stamp) {
    for (size_t i = 0; i < n; ++i) {
      t.rows[i].thermal = (*stamp_s[i] - *stamp_s[0]) / 3600.0;
      t.rows[i].thermal_is_time = true;
    }
    t.has_thermal = true;
    t.thermal_source = "stamp_s";
  }
  if (all_stamp)
    for (size_t i = 0; i < n; ++i) t.rows[i].elapsed_h = (*stamp_s[i] - *stamp_s[0]) / 3600.0;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Index nj = q_rad[i].size();
    Drivers& d = t.rows[i];
    d.motion_direction = i == 0 ? Eigen::VectorXd::Zero(nj) : t.rows[i - 1].motion_direction;
    d.recent_steps_rad = Eigen::MatrixXd::Zero(nj, kPlayHistory);
    if (i == 0) continue;
    if (t.rows[i - 1].recent_steps_rad.rows() == nj)
      d.recent_steps_rad.leftCols(kPlayHistory - 1) = t.rows[i - 1].recent_steps_rad.rightCols(kPlayHistory - 1);
    for (Eigen::Index j = 0; j < nj; ++j) {
      const double dq = q_rad[i][j] - q_rad[i - 1][j];
      d.recent_steps_rad(j, kPlayHistory - 1) = dq;
      if (std::abs(dq) >= kStillRad) d.motion_direction[j] = dq > 0 ? 1.0 : -1.0;
    }
  }
  return t;
}

bool hasBacklash(const std::vector<Extension>& extensions) {
  return std::any_of(extensions.begin(), extensions.end(), [](const Extension& e) { return followsPath(e.cause); });
}

bool playStateUnknown(const std::vector<Extension>& extensions, const Drivers& drivers) {
  for (const auto& e : extensions)
    if (followsPath(e.cause) &&
        (drivers.motion_direction.size() <= e.joint || drivers.motion_direction[e.joint] == 0.0))
      return true;
  return false;
}

double playState(const Drivers& drivers, int j, double width_rad) {
  if (!(width_rad > 0)) return drivers.motion_direction.size() > j ? drivers.motion_direction[j] : 0.0;
  if (drivers.recent_steps_rad.rows() <= j) return 0.0;
  double s = 0.0;
  for (Eigen::Index c = 0; c < drivers.recent_steps_rad.cols(); ++c) s = playStep(s, drivers.recent_steps_rad(j, c), width_rad);
  return s;
}

std::vector<Pose> chainFrames(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad) {
  const int n = model.numJoints();
  std::vector<Pose> F;
  F.reserve(n + 2);
  PoseT<double> X;
  auto push = [&]() {
    Pose P = Pose::Identity();
    P.linear() = X.R;
    P.translation() = X.p;
    F.push_back(P);
  };
  const int base_last = model.baseParam(FrameParam::kRoll), tool_last = model.toolParam(FrameParam::kRoll);
  detail::walkChain<double>(model, params.data(), q_rad.data(), [&](int index, bool rot, int axis, double v) {
    if (rot)
      detail::rotateLocal(X, axis, v);
    else
      detail::translateLocal(X, axis, v);
    // Frame 0 after the base (and the mount, when there is one), frame j after joint j, the tool after the flange.
    if ((index == base_last && !model.hasMount()) || index == detail::kMountEnd || index == tool_last ||
        (index >= 0 && index < 5 * n && index % 5 == 4))
      push();
  });
  return F;
}

Eigen::VectorXd gravityTorques(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad) {
  const int n = model.numJoints();
  Eigen::VectorXd tau = Eigen::VectorXd::Zero(n);
  if (model.links.empty()) return tau;
  const std::vector<Pose> F = chainFrames(model, params, q_rad);
  const Eigen::Vector3d g = causes::gravityInTracker(model, F);
  for (int j = 0; j < n; ++j)
    for (int i = j + 1; i <= n; ++i)
      tau[j] += model.links[i - 1].mass_kg * causes::unitTorque(F, j, F[i] * model.links[i - 1].com_m, g);
  return tau;
}

double complianceDriver(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad, int j) {
  if (!model.links.empty()) return gravityTorques(model, params, q_rad)[j];
  const std::vector<Pose> F = chainFrames(model, params, q_rad);
  return causes::unitTorque(F, j, F.back().translation(), causes::gravityInTracker(model, F));
}

double linkLength(const RobotModel& model, const Eigen::VectorXd& params, int j) {
  if (j < 0 || j + 1 >= model.numJoints() + 1) throw std::invalid_argument("linkLength: no such link");
  const std::vector<Pose> F = chainFrames(model, params, Eigen::VectorXd::Zero(model.numJoints()));
  return (F[j + 1].translation() - F[j].translation()).norm();
}

bool applicable(const RobotModel& model, const Extension& ext, bool has_thermal) {
  return ext.cause != Cause::kNone && causeModel(ext.cause).applicable(model, ext.joint, has_thermal);
}

int numExtensionParams(const RobotModel& model, const Extension& ext) {
  return ext.cause == Cause::kNone ? 0 : causeModel(ext.cause).numParams(model, ext.joint);
}

std::vector<std::string> extensionParamNames(const RobotModel& model, const Extension& ext) {
  if (ext.cause == Cause::kNone) return {};
  return causeModel(ext.cause).paramNames(model, ext.joint);
}

Eigen::MatrixXd extensionBasis(const RobotModel& model, const Eigen::VectorXd& params, const Extension& ext,
                               const Eigen::VectorXd& q_rad, const Drivers& drivers, double backlash_width_rad) {
  const int k = numExtensionParams(model, ext);
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(model.numParams(), k);
  if (k == 0) return B;
  causeModel(ext.cause).basis(BasisPoint{model, params, ext, q_rad, drivers, backlash_width_rad}, B);
  return B;
}

int numExtensionParams(const RobotModel& model, const std::vector<Extension>& exts) {
  int k = 0;
  for (const auto& e : exts) k += numExtensionParams(model, e);
  return k;
}

std::vector<std::string> extensionParamNames(const RobotModel& model, const std::vector<Extension>& exts) {
  std::vector<std::string> out;
  for (const auto& e : exts)
    for (auto& n : extensionParamNames(model, e)) out.push_back(std::move(n));
  return out;
}

Eigen::MatrixXd extensionBasis(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                               const Eigen::VectorXd& q_rad, const Drivers& drivers, const Eigen::VectorXd& evaluated_at) {
  Eigen::MatrixXd B(model.numParams(), numExtensionParams(model, exts));
  int c = 0;
  for (const auto& e : exts) {
    const int k = numExtensionParams(model, e);
    const double width = followsPath(e.cause) && evaluated_at.size() > c ? std::abs(evaluated_at[c]) : 0.0;
    B.middleCols(c, k) = extensionBasis(model, params, e, q_rad, drivers, width);
    c += k;
  }
  return B;
}

std::string extensionSpec(const Extension& ext) {
  std::string s = causeName(ext.cause);
  if (ext.joint >= 0) s += ":" + std::to_string(ext.joint + 1);
  return s;
}

Extension parseExtension(const std::string& item, const RobotModel& model, bool has_thermal) {
  const auto colon = item.find(':');
  const std::string name = item.substr(0, colon);
  const auto cause = causeFromName(name);
  if (!cause || *cause == Cause::kNone) {
    std::string known;
    for (const CauseModel* c : causeModels()) known += (known.empty() ? "" : ", ") + std::string(c->name());
    throw std::invalid_argument("'" + name + "' is not a cause (" + known + ")");
  }
  const CauseModel& cm = causeModel(*cause);
  using Subject = CauseModel::Subject;
  Extension e{*cause, -1};
  if (colon != std::string::npos) {
    const std::string joint = item.substr(colon + 1);
    size_t used = 0;
    int j = 0;
    try {
      j = std::stoi(joint, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != joint.size())
      throw std::invalid_argument("'" + item + "': the joint after ':' must be a number (1-based)");
    if (j < 1 || j > model.numJoints())
      throw std::invalid_argument("'" + item + "': " + model.name + " has joints 1.." + std::to_string(model.numJoints()) +
                                  (cm.subject() == Subject::kLink ? " (link j: between the axes of joints j and j+1)" : ""));
    if (cm.subject() == Subject::kBase)
      throw std::invalid_argument("'" + item + "': " + name + " has no joint (the base frame)");
    e.joint = j - 1;
  } else if (cm.subject() == Subject::kJoint || cm.subject() == Subject::kLink) {
    throw std::invalid_argument("'" + item + "' needs a joint, e.g. " + name + ":2");
  }
  if (!applicable(model, e, has_thermal))
    throw std::invalid_argument("'" + item + "' does not apply to " + model.name + cm.whyNot(model, e.joint, has_thermal));
  return e;
}

std::vector<Extension> parseExtensionList(const std::string& spec, const RobotModel& model, bool has_thermal) {
  std::vector<Extension> out;
  std::stringstream ss(spec);
  std::string item;
  while (std::getline(ss, item, ',')) {
    item.erase(0, item.find_first_not_of(" \t"));
    item.erase(item.find_last_not_of(" \t") + 1);
    const Extension e = parseExtension(item, model, has_thermal);
    for (const auto& o : out)
      if (o.cause == e.cause && o.joint == e.joint) throw std::invalid_argument("'" + item + "' is listed twice");
    out.push_back(e);
  }
  if (out.empty()) throw std::invalid_argument("empty list of extensions");
  return out;
}

Eigen::VectorXd extendedParams(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                               const Eigen::VectorXd& extension_params, const Eigen::VectorXd& q_rad,
                               const Drivers& drivers) {
  if (exts.empty()) return params;
  return params + extensionBasis(model, params, exts, q_rad, drivers, extension_params) * extension_params;
}

Eigen::VectorXd extensionPriorSigma(const RobotModel& model, const Eigen::VectorXd& params,
                                    const std::vector<Extension>& exts, double joint_error_rad) {
  const int n = model.numJoints();
  constexpr int kSamples = 64;
  std::mt19937_64 rng(20261123);
  Eigen::VectorXd ms = Eigen::VectorXd::Zero(numExtensionParams(model, exts));
  for (int s = 0; s < kSamples; ++s) {
    Eigen::VectorXd q(n);
    for (int j = 0; j < n; ++j) {
      const double lo = std::max(model.limits[j].lower_rad, -kPi), hi = std::min(model.limits[j].upper_rad, kPi);
      q[j] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    Drivers d;
    d.motion_direction = Eigen::VectorXd::Constant(n, s % 2 ? 1.0 : -1.0);
    d.thermal = 1.0;
    const Eigen::MatrixXd B = extensionBasis(model, params, exts, q, d, Eigen::VectorXd());
    ms += B.colwise().squaredNorm().transpose();
  }
  // Relative to the other parameters of the same extension: a column at rounding level does not act.
  Eigen::VectorXd sigma = Eigen::VectorXd::Zero(ms.size());
  Eigen::Index c = 0;
  for (const auto& e : exts) {
    const int k = numExtensionParams(model, e);
    const Eigen::VectorXd rms = (ms.segment(c, k) / kSamples).cwiseSqrt();
    for (int i = 0; i < k; ++i)
      if (rms[i] > 1e-9 * rms.maxCoeff()) sigma[c + i] = joint_error_rad / rms[i];
    c += k;
  }
  return sigma;
}

PlayTracker::PlayTracker(int joints, double hysteresis_rad)
    : hysteresis_rad_(hysteresis_rad), joints_(static_cast<size_t>(joints)) {}

void PlayTracker::add(std::int64_t stamp_ns, const Eigen::VectorXd& q_rad) {
  if (q_rad.size() != static_cast<Eigen::Index>(joints_.size()) || stamp_ns < last_ns_ || !q_rad.allFinite()) return;
  last_ns_ = stamp_ns;
  for (size_t j = 0; j < joints_.size(); ++j) {
    Joint& J = joints_[j];
    const Turn now{stamp_ns, q_rad[static_cast<Eigen::Index>(j)]};
    if (J.turns.empty()) {
      J.turns.push_back(now);
      J.extreme = now;
      continue;
    }
    if (J.direction == 0) {
      const double d = now.q_rad - J.turns.back().q_rad;
      if (std::abs(d) > hysteresis_rad_) {
        J.direction = d > 0 ? 1 : -1;
        J.extreme = now;
      }
      continue;
    }
    if ((now.q_rad - J.extreme.q_rad) * J.direction > 0) {
      J.extreme = now;
    } else if ((J.extreme.q_rad - now.q_rad) * J.direction > hysteresis_rad_) {
      J.turns.push_back(J.extreme);
      while (J.turns.size() > kMaxTurns) J.turns.pop_front();
      J.direction = -J.direction;
      J.extreme = now;
    }
  }
}

Drivers PlayTracker::driversAt(std::int64_t stamp_ns, const Eigen::VectorXd& q_rad) const {
  const auto n = static_cast<Eigen::Index>(joints_.size());
  Drivers d;
  d.motion_direction = Eigen::VectorXd::Zero(n);
  d.recent_steps_rad = Eigen::MatrixXd::Zero(n, kPlayHistory);
  if (q_rad.size() != n) return d;
  for (Eigen::Index j = 0; j < n; ++j) {
    const auto& turns = joints_[static_cast<size_t>(j)].turns;
    // Turning points up to the pose, then the pose itself.
    std::vector<double> pts;
    for (const auto& t : turns)
      if (t.stamp_ns <= stamp_ns) pts.push_back(t.q_rad);
    if (pts.empty()) continue;
    pts.push_back(q_rad[j]);
    const size_t first = pts.size() > static_cast<size_t>(kPlayHistory) + 1 ? pts.size() - kPlayHistory - 1 : 0;
    const size_t steps = pts.size() - 1 - first;
    for (size_t k = 0; k < steps; ++k)
      d.recent_steps_rad(j, kPlayHistory - static_cast<Eigen::Index>(steps) + static_cast<Eigen::Index>(k)) =
          pts[first + k + 1] - pts[first + k];
    for (Eigen::Index c = kPlayHistory - 1; c >= 0; --c)
      if (std::abs(d.recent_steps_rad(j, c)) >= kStillRad) {
        d.motion_direction[j] = d.recent_steps_rad(j, c) > 0 ? 1.0 : -1.0;
        break;
      }
  }
  return d;
}

void PlayTracker::restore(std::vector<Joint> joints, std::int64_t last_stamp_ns) {
  joints_ = std::move(joints);
  last_ns_ = last_stamp_ns;
}

}  // namespace cellcal
