#include "cellcal/core/model/model_extension.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

namespace {

struct CauseInfo {
  Cause cause;
  const char* name;
};
constexpr CauseInfo kCauses[] = {{Cause::kNone, "none"},
                                  {Cause::kJointCompliance, "joint_compliance"},
                                  {Cause::kThermalDrift, "thermal_drift"},
                                  {Cause::kCyclicTransmission, "cyclic_transmission"},
                                  {Cause::kJointScale, "joint_scale"},
                                  {Cause::kBacklash, "backlash"},
                                  {Cause::kLinkDeflection, "link_deflection"},
                                  {Cause::kFrameDrift, "frame_drift"}};

constexpr double kStillRad = 1e-4;        // a joint that moved less than this keeps its last direction
constexpr double kMinBeamLengthM = 0.2;   // links shorter than this are not treated as beams

Eigen::Vector3d gravityInTracker(const RobotModel& model, const std::vector<Pose>& F) {
  return F[0].linear() * model.gravity_in_base_mps2;
}

// Torque about joint j's axis of a unit mass at point c (tracker frame), N m per kg.
double unitTorque(const std::vector<Pose>& F, int j, const Eigen::Vector3d& c, const Eigen::Vector3d& g) {
  const Eigen::Vector3d z = F[j].linear().col(2), o = F[j].translation();
  return z.dot((c - o).cross(g));
}

bool loadedByGravity(const RobotModel& model, int j) {
  if (j > 0) return true;
  const std::vector<Pose> F = chainFrames(model, model.nominal, Eigen::VectorXd::Zero(model.numJoints()));
  const Eigen::Vector3d z = F[0].linear().col(2), g = gravityInTracker(model, F);
  return z.cross(g).norm() > 1e-6 * g.norm();
}

}  // namespace

const char* causeName(Cause c) {
  for (const auto& i : kCauses)
    if (i.cause == c) return i.name;
  return "?";
}

std::optional<Cause> causeFromName(const std::string& name) {
  for (const auto& i : kCauses)
    if (name == i.name) return i.cause;
  return std::nullopt;
}

const std::vector<Cause>& extensionCauses() {
  static const std::vector<Cause> c = {Cause::kJointCompliance, Cause::kThermalDrift, Cause::kCyclicTransmission,
                                       Cause::kJointScale, Cause::kBacklash, Cause::kLinkDeflection};
  return c;
}

bool followsThermalDriver(Cause c) { return c == Cause::kThermalDrift || c == Cause::kFrameDrift; }

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
  return std::any_of(extensions.begin(), extensions.end(), [](const Extension& e) { return e.cause == Cause::kBacklash; });
}

bool playStateUnknown(const std::vector<Extension>& extensions, const Drivers& drivers) {
  for (const auto& e : extensions)
    if (e.cause == Cause::kBacklash &&
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
  const Eigen::Vector3d g = gravityInTracker(model, F);
  for (int j = 0; j < n; ++j)
    for (int i = j + 1; i <= n; ++i)
      tau[j] += model.links[i - 1].mass_kg * unitTorque(F, j, F[i] * model.links[i - 1].com_m, g);
  return tau;
}

double complianceDriver(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad, int j) {
  if (!model.links.empty()) return gravityTorques(model, params, q_rad)[j];
  const std::vector<Pose> F = chainFrames(model, params, q_rad);
  return unitTorque(F, j, F.back().translation(), gravityInTracker(model, F));
}

double linkLength(const RobotModel& model, const Eigen::VectorXd& params, int j) {
  if (j < 0 || j + 1 >= model.numJoints() + 1) throw std::invalid_argument("linkLength: no such link");
  const std::vector<Pose> F = chainFrames(model, params, Eigen::VectorXd::Zero(model.numJoints()));
  return (F[j + 1].translation() - F[j].translation()).norm();
}

namespace {
// Gravity across link j at q, in g: the part of the unit gravity vector perpendicular to the link; and the link's
// direction and far end, from the chain frames.
struct LinkLoad {
  Eigen::Vector3d across, direction, far_end;
};
LinkLoad linkLoad(const RobotModel& model, const std::vector<Pose>& F, int j) {
  LinkLoad l;
  l.far_end = F[j + 1].translation();
  l.direction = (l.far_end - F[j].translation()).normalized();
  const Eigen::Vector3d g = gravityInTracker(model, F).normalized();
  l.across = g - g.dot(l.direction) * l.direction;
  return l;
}

// A link of beam length that gravity can load across: over configurations spread through the limits, the gravity
// across it reaches 0.3 g.
bool beamLoadedByGravity(const RobotModel& model, int j) {
  if (j < 0 || j >= model.numJoints() - 1 || linkLength(model, model.nominal, j) < kMinBeamLengthM) return false;
  std::mt19937_64 rng(20261128);
  for (int s = 0; s < 64; ++s) {
    Eigen::VectorXd q(model.numJoints());
    for (int k = 0; k < model.numJoints(); ++k)
      q[k] = std::uniform_real_distribution<double>(std::max(model.limits[k].lower_rad, -kPi),
                                                    std::min(model.limits[k].upper_rad, kPi))(rng);
    if (linkLoad(model, chainFrames(model, model.nominal, q), j).across.norm() > 0.3) return true;
  }
  return false;
}
}  // namespace

bool applicable(const RobotModel& model, const Extension& ext, bool has_thermal) {
  if (ext.cause == Cause::kThermalDrift && ext.joint == -1) return has_thermal;  // lengths only
  if (ext.cause == Cause::kFrameDrift) return ext.joint == -1 && has_thermal;
  if (ext.joint < 0 || ext.joint >= model.numJoints()) return false;
  switch (ext.cause) {
    case Cause::kNone:
      return false;
    case Cause::kJointCompliance:
      return loadedByGravity(model, ext.joint) && numExtensionParams(model, ext) > 0;
    case Cause::kThermalDrift:
      return has_thermal;
    case Cause::kLinkDeflection:
      return beamLoadedByGravity(model, ext.joint);
    default:
      return true;
  }
}

int numExtensionParams(const RobotModel& model, const Extension& ext) {
  switch (ext.cause) {
    case Cause::kNone:
      return 0;
    case Cause::kJointCompliance:
      return model.links.empty() ? 4 * (model.numJoints() - ext.joint) : 1;
    case Cause::kThermalDrift:
      return ext.joint < 0 ? 1 : 2;
    case Cause::kCyclicTransmission:
      return 4;
    case Cause::kJointScale:
    case Cause::kBacklash:
      return 1;
    case Cause::kLinkDeflection:
      return 2;
    case Cause::kFrameDrift:
      return 6;
  }
  return 0;
}

std::vector<std::string> extensionParamNames(const RobotModel& model, const Extension& ext) {
  const std::string j = "joint" + std::to_string(ext.joint + 1) + ".";
  switch (ext.cause) {
    case Cause::kNone:
      return {};
    case Cause::kJointCompliance: {
      if (!model.links.empty()) return {j + "compliance_rad_per_Nm"};
      std::vector<std::string> out;
      for (int i = ext.joint + 1; i <= model.numJoints(); ++i) {
        const std::string l = j + "compliance_link" + std::to_string(i);
        out.push_back(l + "_mass_rad_per_Nm_kg");
        for (const char* a : {"x", "y", "z"}) out.push_back(l + "_moment_" + a + "_rad_per_Nm_kg_m");
      }
      return out;
    }
    case Cause::kThermalDrift:
      if (ext.joint < 0) return {"lengths.expansion_per_unit"};
      return {"lengths.expansion_per_unit", j + "zero_drift_rad_per_unit"};
    case Cause::kCyclicTransmission:
      return {j + "sin1_rad", j + "cos1_rad", j + "sin2_rad", j + "cos2_rad"};
    case Cause::kJointScale:
      return {j + "scale_ratio"};
    case Cause::kBacklash:
      return {j + "backlash_width_rad"};
    case Cause::kLinkDeflection: {
      const std::string l = "link" + std::to_string(ext.joint + 1) + ".";
      return {l + "sag_m", l + "tip_slope_rad"};
    }
    case Cause::kFrameDrift:
      return {"base.drift_x_m_per_unit",        "base.drift_y_m_per_unit",       "base.drift_z_m_per_unit",
              "base.drift_roll_rad_per_unit", "base.drift_pitch_rad_per_unit", "base.drift_yaw_rad_per_unit"};
  }
  return {};
}

Eigen::MatrixXd extensionBasis(const RobotModel& model, const Eigen::VectorXd& params, const Extension& ext,
                               const Eigen::VectorXd& q_rad, const Drivers& drivers, double backlash_width_rad) {
  const int k = numExtensionParams(model, ext);
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(model.numParams(), k);
  if (k == 0) return B;
  const int j = ext.joint;
  if (followsThermalDriver(ext.cause)) {
    double s = drivers.thermal;
    const double tau = ext.time_constant_h;
    if (drivers.thermal_is_time && tau > 0 && std::isfinite(tau)) s = tau * -std::expm1(-drivers.thermal / tau);
    if (ext.cause == Cause::kFrameDrift) {  // each base parameter moves with s
      for (int p = 0; p < 6; ++p) B(model.baseParam(static_cast<FrameParam>(p)), p) = s;
      return B;
    }
    // thermal_drift. Column 0: every length grows with itself; column 1: joint j's zero.
    for (int i = 0; i < model.numJoints(); ++i)
      for (JointParam p : {JointParam::kA, JointParam::kD}) {
        const int idx = model.jointParam(i, p);
        B(idx, 0) = s * params[idx];
      }
    if (j >= 0) B(model.jointParam(j, JointParam::kThetaOffset), 1) = s;
    return B;
  }
  if (ext.cause == Cause::kLinkDeflection) {
    // The twist the bending gives the target (translation, rotation; tracker frame), then the minimum-norm parameter
    // change with that first-order effect: B = J^T (J J^T)^-1 G.
    const std::vector<Pose> F = chainFrames(model, params, q_rad);
    const LinkLoad l = linkLoad(model, F, j);
    const Eigen::Vector3d target = F.back().translation();
    Eigen::Matrix<double, 6, 2> G;
    const Eigen::Vector3d w = l.direction.cross(l.across);
    G.col(0) << l.across, Eigen::Vector3d::Zero();
    G.col(1) << w.cross(target - l.far_end), w;
    KinematicsData data(model);
    forwardKinematics(model, data, params, q_rad);
    Eigen::MatrixXd J(6, model.numParams());
    computePoseJacobian(model, data, J);
    B = J.transpose() * (J * J.transpose()).ldlt().solve(G);
    return B;
  }
  const int th = model.jointParam(j, JointParam::kThetaOffset);
  const double q = q_rad[j];
  switch (ext.cause) {
    case Cause::kNone:
      break;
    case Cause::kJointCompliance: {
      if (!model.links.empty()) {
        B(th, 0) = gravityTorques(model, params, q_rad)[j];
        break;
      }
      // Gravity regressor of the links beyond joint j: a mass m with centre l in frame i loads joint j with
      // m * torque(origin of frame i) + (m l) . R_i^T (g x z_j): linear in (m, m l), four parameters per link.
      const std::vector<Pose> F = chainFrames(model, params, q_rad);
      const Eigen::Vector3d g = gravityInTracker(model, F);
      const Eigen::Vector3d gxz = g.cross(F[j].linear().col(2));
      for (int i = j + 1, c = 0; i <= model.numJoints(); ++i, c += 4) {
        B(th, c) = unitTorque(F, j, F[i].translation(), g);
        B.block<1, 3>(th, c + 1) = (F[i].linear().transpose() * gxz).transpose();
      }
      break;
    }
    case Cause::kThermalDrift:  // above
      break;
    case Cause::kCyclicTransmission:
      B(th, 0) = std::sin(q);
      B(th, 1) = std::cos(q);
      B(th, 2) = std::sin(2 * q);
      B(th, 3) = std::cos(2 * q);
      break;
    case Cause::kJointScale:
      B(th, 0) = q;
      break;
    case Cause::kBacklash:
      B(th, 0) = 0.5 * playState(drivers, j, backlash_width_rad);
      break;
    case Cause::kLinkDeflection:  // above
    case Cause::kFrameDrift:
      break;
  }
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
    const double width = e.cause == Cause::kBacklash && evaluated_at.size() > c ? std::abs(evaluated_at[c]) : 0.0;
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
  if (!cause || *cause == Cause::kNone)
    throw std::invalid_argument("'" + name + "' is not a cause (joint_compliance, thermal_drift, cyclic_transmission, "
                                "joint_scale, backlash, link_deflection, frame_drift)");
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
                                  (*cause == Cause::kLinkDeflection ? " (link j: between the axes of joints j and j+1)" : ""));
    if (*cause == Cause::kFrameDrift) throw std::invalid_argument("'" + item + "': frame_drift has no joint (the base frame)");
    e.joint = j - 1;
  } else if (*cause != Cause::kThermalDrift && *cause != Cause::kFrameDrift) {
    throw std::invalid_argument("'" + item + "' needs a joint, e.g. " + name + ":2");
  }
  if (!applicable(model, e, has_thermal)) {
    std::string why = "does not apply to " + model.name;
    if (followsThermalDriver(e.cause) && !has_thermal) why += " without a temperature or time driver";
    if (e.cause == Cause::kJointCompliance) why += " (gravity does not load that joint)";
    if (e.cause == Cause::kLinkDeflection)
      why += " (link " + std::to_string(e.joint + 1) + ", between the axes of joints " + std::to_string(e.joint + 1) +
             " and " + std::to_string(e.joint + 2) + ", is shorter than 200 mm or never held across gravity)";
    throw std::invalid_argument("'" + item + "' " + why);
  }
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
