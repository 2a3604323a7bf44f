#include "cellcal/core/sim/simulation.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

SimulatedCell::SimulatedCell(const RobotModel& nominal, const SimulationConfig& config)
    : config_(config), model_(nominal) {
  const int b = model_.baseParam(FrameParam::kX), t = model_.toolParam(FrameParam::kX);
  for (int k = 0; k < 6; ++k) {
    model_.nominal[b + k] = config.base_in_tracker[k];
    model_.nominal[t + k] = config.tool_in_flange[k];
  }
  std::mt19937_64 rng(config.seed);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signed_uniform = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1.0 : 1.0) * (lo + (hi - lo) * u01(rng)); };
  true0_ = model_.nominal;
  for (int i : model_.canonicalParams())
    true0_[i] += model_.isLength(i) ? signed_uniform(config.length_error_min_m, config.length_error_max_m)
                                    : signed_uniform(config.angle_error_min_rad, config.angle_error_max_rad);
  if (config.true_params) {  // a given true robot: its joints, its frames when given too
    if (config.true_params->size() != model_.numParams())
      throw std::invalid_argument("SimulatedCell: the true robot has another parameter layout");
    const int frames = model_.baseParam(FrameParam::kX);
    true0_.head(frames) = config.true_params->head(frames);
    if (config.true_frames) true0_.tail(12) = config.true_params->tail(12);
  }
  const int n = model_.numJoints();
  zero_drift_per_K_.resize(n);
  zero_wear_per_h_.resize(n);
  for (int j = 0; j < n; ++j) {
    zero_drift_per_K_[j] = (2 * u01(rng) - 1) * config.zero_drift_per_K_max_rad;
    zero_wear_per_h_[j] = (2 * u01(rng) - 1) * config.zero_wear_per_h_max_rad;
  }
}

double SimulatedCell::temperatureRiseK(double t_h) const {
  return config_.warmup_K * (1.0 - std::exp(-t_h / config_.warmup_tau_h));
}

Eigen::VectorXd SimulatedCell::trueParams(double t_h) const {
  Eigen::VectorXd p = true0_;
  const double dT = temperatureRiseK(t_h);
  for (int j = 0; j < model_.numJoints(); ++j) {
    for (JointParam k : {JointParam::kD, JointParam::kA}) {
      const int i = model_.jointParam(j, k);
      p[i] += true0_[i] * config_.expansion_per_K * dT;
    }
    p[model_.jointParam(j, JointParam::kThetaOffset)] += zero_drift_per_K_[j] * dT + zero_wear_per_h_[j] * t_h;
  }
  return p;
}

std::vector<Eigen::VectorXd> SimulatedCell::randomConfigurations(int n, std::mt19937_64& rng) const {
  std::vector<Eigen::VectorXd> out;
  Eigen::VectorXd params = model_.nominal;
  for (int k = 0; k < 6; ++k) params[model_.baseParam(FrameParam::kX) + k] = 0.0;  // flange in the base frame
  KinematicsData data(model_);
  const int nj = model_.numJoints();
  while (static_cast<int>(out.size()) < n) {
    Eigen::VectorXd q(nj);
    for (int j = 0; j < nj; ++j) {
      const double lo = std::max(model_.limits[j].lower_rad, -kPi) * config_.pose_range_fraction;
      const double hi = std::min(model_.limits[j].upper_rad, kPi) * config_.pose_range_fraction;
      q[j] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    const Eigen::Vector3d p = forwardKinematics(model_, data, params, q).translation();
    if (p.z() < config_.pose_min_z_m || p.head<2>().norm() < config_.pose_min_radius_m) continue;
    out.push_back(q);
  }
  return out;
}

Eigen::VectorXd SimulatedCell::hiddenJointErrorRad(const Eigen::VectorXd& q_rad, const HiddenJointState* state,
                                                   double t_h) const {
  const HiddenJointEffect& h = config_.hidden;
  Eigen::VectorXd dq = Eigen::VectorXd::Zero(model_.numJoints());
  if (h.cause == Cause::kNone) return dq;
  if (h.joint < 0 || h.joint >= model_.numJoints()) throw std::invalid_argument("HiddenJointEffect: joint out of range");
  const double q = q_rad[h.joint];
  double& e = dq[h.joint];
  switch (h.cause) {
    case Cause::kNone:
      break;
    case Cause::kJointCompliance: {
      if (h.links.size() != static_cast<size_t>(model_.numJoints()))
        throw std::invalid_argument("HiddenJointEffect: compliance needs one link per joint");
      RobotModel m = model_;
      m.links = h.links;
      e = h.compliance_rad_per_Nm * gravityTorques(m, trueParams(t_h), q_rad)[h.joint];
      break;
    }
    case Cause::kThermalDrift:
      e = h.zero_drift_rad_per_K * temperatureRiseK(t_h);
      break;
    case Cause::kCyclicTransmission:
      e = h.harmonics_rad.dot(Eigen::Vector4d(std::sin(q), std::cos(q), std::sin(2 * q), std::cos(2 * q)));
      break;
    case Cause::kJointScale:
      e = h.scale * q;
      break;
    case Cause::kBacklash:
      e = -0.5 * h.backlash_width_rad * (state ? state->backlash_play : 1.0);
      break;
    case Cause::kLinkDeflection:
    case Cause::kFrameDrift:
      throw std::invalid_argument(std::string("HiddenJointEffect: ") + causeName(h.cause) +
                                  " is not a joint error (a Cartesian effect)");
  }
  return dq;
}

HiddenJointState SimulatedCell::advanceHiddenState(HiddenJointState state, const Eigen::VectorXd& q_from_rad,
                                                   const Eigen::VectorXd& q_to_rad) const {
  const HiddenJointEffect& h = config_.hidden;
  if (h.cause == Cause::kBacklash && h.backlash_width_rad > 0)
    state.backlash_play = playStep(state.backlash_play, q_to_rad[h.joint] - q_from_rad[h.joint], h.backlash_width_rad);
  return state;
}

Pose SimulatedCell::truePose(const Eigen::VectorXd& q_rad, double t_h, const HiddenJointState* state) const {
  if (config_.hidden.cause == Cause::kNone) return forwardKinematics(model_, trueParams(t_h), q_rad);
  return forwardKinematics(model_, trueParams(t_h), Eigen::VectorXd(q_rad + hiddenJointErrorRad(q_rad, state, t_h)));
}

Observation SimulatedCell::measure(const Eigen::VectorXd& q_rad, double t_h, std::mt19937_64& rng,
                                   MeasurementKind kind) const {
  return measure(q_rad, nullptr, t_h, rng, kind);
}

Observation SimulatedCell::measure(const Eigen::VectorXd& q_rad, const HiddenJointState* state, double t_h,
                                   std::mt19937_64& rng, MeasurementKind kind) const {
  return measurePose(truePose(q_rad, t_h, state), q_rad, rng, kind);
}

Observation SimulatedCell::measurePose(const Pose& true_pose, const Eigen::VectorXd& q_rad, std::mt19937_64& rng,
                                       MeasurementKind kind) const {
  std::normal_distribution<double> g(0.0, 1.0);
  Pose T = true_pose;
  const double sigma_rep = config_.repeatability_m / 2.0;
  const double sigma_p = config_.tracker.sigmaPosition(T.translation().norm());
  const double sigma_o = config_.tracker.sigmaOrientation();
  Eigen::Vector3d dp(g(rng), g(rng), g(rng));
  Eigen::Vector3d dr(g(rng), g(rng), g(rng));
  Eigen::Vector3d dw(g(rng), g(rng), g(rng));
  T.translation() += sigma_rep * dr + sigma_p * dp;
  T.linear() = expSO3(sigma_o * dw) * T.linear();
  Observation o;
  o.q_rad = q_rad;
  o.measured_in_tracker = T;
  o.kind = kind;
  o.sigma_position_m = std::hypot(sigma_p, sigma_rep);
  o.sigma_orientation_rad = sigma_o;
  return o;
}

std::vector<LinkInertia> plausibleLinks(const RobotModel& model, const Eigen::VectorXd& params, std::mt19937_64& rng) {
  const int n = model.numJoints();
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g(0.0, 0.02);
  const std::vector<Pose> F = chainFrames(model, params, Eigen::VectorXd::Zero(n));
  std::vector<LinkInertia> links(n);
  for (int i = 1; i <= n; ++i) {
    const Eigen::Vector3d next_in_i = F[i].inverse() * F[i + 1].translation();
    links[i - 1].mass_kg = i <= 3 ? 2.0 + 10.0 * u(rng) : 0.5 + 2.5 * u(rng);
    links[i - 1].com_m = u(rng) * next_in_i + Eigen::Vector3d(g(rng), g(rng), g(rng));
  }
  return links;
}

HiddenJointEffect scaledHiddenEffect(const RobotModel& model, const Eigen::VectorXd& true_params, Cause cause, int joint,
                                     double size_rad, const std::vector<LinkInertia>& links,
                                     const std::vector<Eigen::VectorXd>& qs, std::mt19937_64& rng) {
  HiddenJointEffect e;
  e.cause = cause;
  e.joint = joint;
  auto rms = [&](auto f) {
    double s = 0;
    for (const auto& q : qs) s += f(q) * f(q);
    return std::sqrt(s / static_cast<double>(qs.size()));
  };
  switch (cause) {
    case Cause::kJointCompliance: {
      RobotModel m = model;
      m.links = links;
      e.links = links;
      e.compliance_rad_per_Nm = size_rad / rms([&](const Eigen::VectorXd& q) { return gravityTorques(m, true_params, q)[joint]; });
      break;
    }
    case Cause::kCyclicTransmission: {
      std::normal_distribution<double> g(0.0, 1.0);
      const Eigen::Vector4d v(g(rng), g(rng), g(rng), g(rng));
      e.harmonics_rad = v.normalized() * size_rad * std::sqrt(2.0);
      break;
    }
    case Cause::kJointScale:
      e.scale = size_rad / rms([&](const Eigen::VectorXd& q) { return q[joint]; });
      break;
    default:
      throw std::invalid_argument(std::string("scaledHiddenEffect: ") + causeName(cause) + " is not scaled by size alone");
  }
  return e;
}

}  // namespace cellcal
