#include "cellcal/core/model_extension.hpp"

#include <cmath>
#include <stdexcept>

#include "cellcal/core/kinematics.hpp"

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
                                  {Cause::kBacklash, "backlash"}};

constexpr double kStillRad = 1e-4;        // a joint that moved less than this keeps its last direction

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
                                       Cause::kJointScale, Cause::kBacklash};
  return c;
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
    double mean_c = 0;
    for (const auto& c : temperature_c) mean_c += *c;
    mean_c /= static_cast<double>(n);
    for (size_t i = 0; i < n; ++i) t.rows[i].thermal = *temperature_c[i] - mean_c;
    t.has_thermal = true;
    t.thermal_source = "temperature_c";
  } else if (all_stamp) {
    for (size_t i = 0; i < n; ++i) t.rows[i].thermal = (*stamp_s[i] - *stamp_s[0]) / 3600.0;
    t.has_thermal = true;
    t.thermal_source = "stamp_s";
  }
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
    if (index == base_last || index == tool_last || (index < 5 * n && index % 5 == 4)) push();
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

bool applicable(const RobotModel& model, const Extension& ext, bool has_thermal) {
  if (ext.cause == Cause::kThermalDrift && ext.joint == -1) return has_thermal;  // lengths only
  if (ext.joint < 0 || ext.joint >= model.numJoints()) return false;
  switch (ext.cause) {
    case Cause::kNone:
      return false;
    case Cause::kJointCompliance:
      return loadedByGravity(model, ext.joint) && numExtensionParams(model, ext) > 0;
    case Cause::kThermalDrift:
      return has_thermal;
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
  }
  return {};
}

Eigen::MatrixXd extensionBasis(const RobotModel& model, const Eigen::VectorXd& params, const Extension& ext,
                               const Eigen::VectorXd& q_rad, const Drivers& drivers, double backlash_width_rad) {
  const int k = numExtensionParams(model, ext);
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(model.numParams(), k);
  if (k == 0) return B;
  const int j = ext.joint;
  if (ext.cause == Cause::kThermalDrift) {  // column 0: every length grows with itself; column 1: joint j's zero
    for (int i = 0; i < model.numJoints(); ++i)
      for (JointParam p : {JointParam::kA, JointParam::kD}) {
        const int idx = model.jointParam(i, p);
        B(idx, 0) = drivers.thermal * params[idx];
      }
    if (j >= 0) B(model.jointParam(j, JointParam::kThetaOffset), 1) = drivers.thermal;
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
  }
  return B;
}

int numExtensionParams(const RobotModel& model, const std::vector<Extension>& exts) {
  int k = 0;
  for (const auto& e : exts) k += numExtensionParams(model, e);
  return k;
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

}  // namespace cellcal
