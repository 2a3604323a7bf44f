// Test generator: a simulated measurement file with physical effects hidden in it, drawn at random (robot, tracker
// placement, target offset, measurement type, causes, joints, sizes, pairs, effects outside cellcal's library, gross
// errors, repeated poses, thermometer or not, seed). The code under test gets only what a user would have: the robot
// file (no frames), joint angles, tracker readings, stamps and (maybe) temperatures; it registers the frames itself.
// The truth stays here, to grade the answer.
//
// Effects:
//   - joint effects (compliance, thermal zero drift, cyclic transmission error, scale, backlash): the simulator's own
//     (SimulatedCell's hidden joint errors), several at once by summing their joint errors;
//   - link deflection: the far end of a link displaced by sag * g_across and turned by slope * (u x g_across), applied
//     to the true pose directly (not through cellcal's parameter mapping);
//   - outside the library: a tracker whose distance scale drifts over hours (positions scaled about the tracker by
//     1 + k t), and a sag growing with the square of the horizontal reach (a Cartesian field no link model has);
//   - not the robot's (only when asked, DrawOptions::force_outside): the robot's base drifting in the tracker's frame as
//     the cell warms up (a stand that grows, a tracker that creeps), either turning about joint 1's axis alone (the
//     same motion as joint 1's zero drifting) or by any small twist about the base;
//   - gross errors: a fraction of the readings displaced by 1-5 mm in a random direction.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "test_support.hpp"

namespace cellcal::test {

enum class DrawCategory { kNoiseOnly, kSingle, kPair, kOutOfLibrary };
enum class OutsideEffect { kNone, kTrackerScaleDrift, kReachSag, kBaseDrift };

inline const char* categoryName(DrawCategory c) {
  switch (c) {
    case DrawCategory::kNoiseOnly: return "noise only";
    case DrawCategory::kSingle: return "single cause";
    case DrawCategory::kPair: return "pair of causes";
    case DrawCategory::kOutOfLibrary: return "outside the library";
  }
  return "?";
}

struct DrawOptions {
  DrawCategory category = DrawCategory::kSingle;
  std::string robot;                 // "" : staubli_tx60 or ur10 at random; a path ending .urdf: that URDF
  // The visiting order: random configurations one after the other (false), or a path through them, each next one
  // the nearest not yet visited (a robot's own task: neighbouring rows share their model error).
  bool path_order = false;
  int kind = -1;                     // -1: points or 6D at random; else a MeasurementKind
  int poses = 400;
  double hours = 4.0;
  double min_amp_deg = 1e-3, max_amp_deg = 5e-2;  // effect sizes, log-uniform (joint error RMS, or its equivalent)
  bool random_frames = true;         // tracker anywhere, target 0-100 mm beside the flange axis; else the simulator's
  double max_outlier_fraction = 0;   // gross errors in a fraction of the rows drawn uniformly in [0, max]
  double repeat_probability = 0.3;   // files where 10 % of the poses are measured again later
  double no_thermometer_probability = 0.5;
  Cause force_cause = Cause::kNone;  // single: this cause instead of a random one
  // outside the library: this effect instead of a random one of the first two (kBaseDrift is drawn only here)
  OutsideEffect force_outside = OutsideEffect::kNone;
};

struct TrueEffect {
  Cause cause = Cause::kNone;
  int joint = -1;                // 0-based joint (link for link_deflection)
  double amplitude_rad = 0;      // RMS over the poses of the joint error it makes (link: sag / link length)
  double effect_rms_mm = 0;      // verification RMS it leaves after a geometric fit to noise-free data
  double joint_effect_rms_mm = 0;  // thermal drift: the joint-zero part alone; else effect_rms_mm
};

struct HiddenEffectDraw {
  DrawCategory category = DrawCategory::kSingle;
  std::string robot;
  MeasurementKind kind = MeasurementKind::kPose6D;
  Eigen::Matrix<double, 6, 1> base = Eigen::Matrix<double, 6, 1>::Zero(), tool = Eigen::Matrix<double, 6, 1>::Zero();
  std::vector<TrueEffect> effects;
  OutsideEffect outside = OutsideEffect::kNone;
  double outside_size = 0;       // scale drift: per hour; reach sag: m per m^2; base drift: rad at the end of the run
  bool base_yaw_only = false;    // base drift: turning about joint 1's axis alone
  double outside_rms_mm = 0;     // what the outside effect leaves after a geometric fit (noise-free)
  bool thermometer = true, repeats = false;
  double outlier_fraction = 0;
  double warmup_tau_h = 0;       // thermal drift: the warm-up's time constant
  std::uint64_t seed = 0;
  std::string describe() const {
    char buf[512];
    std::string e;
    for (const auto& t : effects) {
      char b[128];
      std::snprintf(b, sizeof b, "%s%s %s %d (%.4f deg RMS, leaves %.4f mm)", e.empty() ? "" : " + ", causeName(t.cause),
                    t.cause == Cause::kLinkDeflection ? "link" : "joint", t.joint + 1, t.amplitude_rad * 180 / kPi,
                    t.effect_rms_mm);
      e += b;
    }
    if (outside == OutsideEffect::kTrackerScaleDrift) e += " tracker scale drift " + std::to_string(outside_size * 1e6) + " ppm/h";
    if (outside == OutsideEffect::kReachSag) e += " reach-squared sag";
    if (outside == OutsideEffect::kBaseDrift)
      e += std::string(" base drift (") + (base_yaw_only ? "about joint 1's axis" : "any twist") + ") " +
           std::to_string(outside_size * 180 / kPi) + " deg at the end, warm-up " + std::to_string(warmup_tau_h) + " h";
    if (outside != OutsideEffect::kNone) e += " (leaves " + std::to_string(outside_rms_mm) + " mm)";
    if (e.empty()) e = "none";
    std::snprintf(buf, sizeof buf, "%s: %s | %s %s, tool (%.0f, %.0f, %.0f) mm, %s%s, outliers %.1f %%, seed %llu",
                  categoryName(category), e.c_str(), robot.c_str(), kind == MeasurementKind::kPose6D ? "6D" : "points",
                  tool[0] * 1e3, tool[1] * 1e3, tool[2] * 1e3, thermometer ? "thermometer" : "no thermometer",
                  repeats ? ", repeated poses" : "", 100 * outlier_fraction, static_cast<unsigned long long>(seed));
    return buf;
  }
};

struct HiddenEffectData {
  HiddenEffectDraw draw;
  RobotModel model;                 // the robot file: no base or tool frame (what the user has)
  Eigen::VectorXd start;            // its nominal kinematics with the frames registered on the identification rows
  DiagnosisData data;               // identification = even rows, verification = odd rows, in visiting order
  MeasurementFile file;             // the same rows as a measurement file holds them (stamps, maybe temperatures)
  // Truth, for grading only.
  std::vector<int> outlier_identification, outlier_verification;  // rows with gross errors, ascending
  double effect_rms_mm = 0;         // every effect together: verification RMS left after a geometric fit, noise-free
  double noise_rms_mm = 0;          // verification RMS of the measurement noise alone (readings vs. the true robot)
  double sigma_position_mm = 0;     // per-axis reading noise (tracker at the mean distance and repeatability)
};

// The joints gravity loads noticeably: torque RMS over the poses above 10 % of the largest joint's.
inline std::vector<int> gravityLoadedJoints(const RobotModel& m_with_links, const Eigen::VectorXd& params,
                                            const std::vector<Eigen::VectorXd>& qs) {
  Eigen::VectorXd ms = Eigen::VectorXd::Zero(m_with_links.numJoints());
  for (const auto& q : qs) ms += gravityTorques(m_with_links, params, q).cwiseAbs2();
  ms = (ms / static_cast<double>(qs.size())).cwiseSqrt();
  std::vector<int> out;
  for (int j = 0; j < ms.size(); ++j)
    if (ms[j] > 0.1 * ms.maxCoeff()) out.push_back(j);
  return out;
}

inline std::vector<LinkInertia> randomLinks(const RobotModel& model, const Eigen::VectorXd& params, std::mt19937_64& rng) {
  return plausibleLinks(model, params, rng);
}

// Any rotation, uniformly, as roll, pitch, yaw.
inline Eigen::Vector3d randomRpy(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  Eigen::Quaterniond q(g(rng), g(rng), g(rng), g(rng));
  q.normalize();
  Pose T = Pose::Identity();
  T.linear() = q.toRotationMatrix();
  return xyzRpyFromPose(T).tail<3>();
}

// A tracker 1.5-4 m from the robot in any direction, mounted any way round; a target 0-100 mm beside the flange axis
// in any direction, 0-150 mm out along it, any orientation (a share `on_axis` of them meant to be on the axis).
inline void randomTrackerAndTarget(std::mt19937_64& rng, Eigen::Matrix<double, 6, 1>& base,
                                   Eigen::Matrix<double, 6, 1>& tool, double on_axis = 0.0) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double dist = 1.5 + 2.5 * u(rng), az = 2 * kPi * u(rng), el = (u(rng) - 0.3) * 0.8;
  base.head<3>() << dist * std::cos(az) * std::cos(el), dist * std::sin(az) * std::cos(el), dist * std::sin(el);
  base.tail<3>() = randomRpy(rng);
  const double side = on_axis > 0 && u(rng) < on_axis ? 0.0 : 0.1 * u(rng), dir = 2 * kPi * u(rng);
  tool.head<3>() << side * std::cos(dir), side * std::sin(dir), 0.15 * u(rng);
  tool.tail<3>() = randomRpy(rng);
}

// A test's draw: a robot (by its file's name), a measurement type, the tracker and target placed at random.
struct RandomDraw {
  std::string name;
  MeasurementKind kind = MeasurementKind::kPose6D;
  SimulationConfig sc;
  // sc with a robot that neither warms up nor drifts: the effect a test draws is the only one beside the noise.
  SimulationConfig steadySc() const {
    SimulationConfig s = sc;
    s.warmup_K = 0;
    s.zero_drift_per_K_max_rad = 0;
    s.zero_wear_per_h_max_rad = 0;
    return s;
  }
};
inline RandomDraw randomDraw(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RandomDraw d;
  d.name = u(rng) < 0.5 ? "staubli_tx60" : "ur10";
  d.kind = u(rng) < 0.5 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  d.sc.seed = rng();
  randomTrackerAndTarget(rng, d.sc.base_in_tracker, d.sc.tool_in_flange);
  return d;
}

namespace detail {

// How the truth moves a pose beyond the joint errors: link deflection and the effects outside the library.
struct Cartesian {
  int link = -1;
  double sag_m = 0, slope_rad = 0;
  OutsideEffect outside = OutsideEffect::kNone;
  double outside_size = 0;
  // Base drift: a rotation of outside_size * w(t) about `axis` through joint 1's axis (yaw only) or the base origin,
  // and a translation of outside_size * 1 m * w(t) along `shift` (zero for yaw only); w(t) the warm-up, 0 -> 1.
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ(), shift = Eigen::Vector3d::Zero();
  bool yaw_only = false;
  double tau_h = 1, hours = 1;
  Pose apply(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_true, Pose T,
             double t_h) const {
    if (link >= 0) {
      const std::vector<Pose> F = chainFrames(model, params, q_true);
      const Eigen::Vector3d b = F[link + 1].translation();
      const Eigen::Vector3d u = (b - F[link].translation()).normalized();
      const Eigen::Vector3d g = (F[0].linear() * model.gravity_in_base_mps2).normalized();
      const Eigen::Vector3d across = g - g.dot(u) * u;
      const Eigen::Matrix3d R = expSO3(slope_rad * u.cross(across));
      T.translation() = b + R * (T.translation() - b) + sag_m * across;
      T.linear() = R * T.linear();
    }
    if (outside == OutsideEffect::kTrackerScaleDrift) T.translation() *= 1.0 + outside_size * t_h;
    if (outside == OutsideEffect::kBaseDrift) {
      const double w = std::expm1(-t_h / tau_h) / std::expm1(-hours / tau_h);
      const std::vector<Pose> F = chainFrames(model, params, q_true);
      // Joint 1 turns about the z axis of frame 0 (the base, after the mount), through its origin.
      const Eigen::Vector3d a = yaw_only ? Eigen::Vector3d(F[0].linear().col(2)) : axis;
      const Eigen::Vector3d c = F[0].translation();
      const Eigen::Matrix3d R = expSO3(outside_size * w * a);
      T.translation() = c + R * (T.translation() - c) + outside_size * w * shift;
      T.linear() = R * T.linear();
    }
    if (outside == OutsideEffect::kReachSag) {
      const Pose base = chainFrames(model, params, q_true).front();
      const Eigen::Vector3d p = base.inverse() * T.translation();
      T.translation() -= outside_size * p.head<2>().squaredNorm() * base.linear().col(2);
    }
    return T;
  }
};

}  // namespace detail

// Draws a file: `options.poses` poses over `options.hours` hours of work, in the order the robot visits them.
inline HiddenEffectData makeHiddenEffectData(const DrawOptions& options, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto logUniform = [&](double lo, double hi) { return std::exp(std::log(lo) + u(rng) * (std::log(hi) - std::log(lo))); };
  HiddenEffectData h;
  HiddenEffectDraw& d = h.draw;
  d.seed = seed;
  d.category = options.category;
  d.robot = !options.robot.empty() ? options.robot : (u(rng) < 0.5 ? "staubli_tx60" : "ur10");
  d.kind = options.kind >= 0 ? static_cast<MeasurementKind>(options.kind)
                             : (u(rng) < 0.5 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D);
  const RobotModel file_model = d.robot.size() > 5 && d.robot.substr(d.robot.size() - 5) == ".urdf"
                                     ? loadRobotFile(d.robot).model
                                     : robot(d.robot);
  const int n = file_model.numJoints();
  SimulationConfig sc;
  sc.seed = rng();
  if (options.random_frames) {
    randomTrackerAndTarget(rng, d.base, d.tool);
    sc.base_in_tracker = d.base;
    sc.tool_in_flange = d.tool;
  } else {
    d.base = sc.base_in_tracker;
    d.tool = sc.tool_in_flange;
  }
  sc.warmup_K = 0;  // no thermal effect unless drawn
  sc.zero_drift_per_K_max_rad = 0;
  sc.zero_wear_per_h_max_rad = 0;
  const SimulatedCell plain(file_model, sc);
  std::vector<Eigen::VectorXd> qs = plain.randomConfigurations(options.poses, rng);
  if (options.path_order)
    for (size_t i = 1; i < qs.size(); ++i) {
      size_t next = i;
      for (size_t j = i + 1; j < qs.size(); ++j)
        if ((qs[j] - qs[i - 1]).squaredNorm() < (qs[next] - qs[i - 1]).squaredNorm()) next = j;
      std::swap(qs[i], qs[next]);
    }
  d.repeats = u(rng) < options.repeat_probability;
  if (d.repeats)  // 10 % of the poses measured again later in the run
    for (int k = 0; k < options.poses / 10; ++k) {
      const int later = 1 + static_cast<int>(u(rng) * (options.poses - 1));
      qs[static_cast<size_t>(later)] = qs[static_cast<size_t>(u(rng) * later)];
    }
  const Eigen::VectorXd true0 = plain.trueParams(0.0);

  // The causes.
  std::vector<Cause> causes;
  const std::vector<Cause>& library = extensionCauses();  // the registry's (cause_list.hpp) that diagnose tries
  auto pick = [&]() { return library[static_cast<size_t>(u(rng) * library.size())]; };
  if (d.category == DrawCategory::kSingle) causes = {options.force_cause != Cause::kNone ? options.force_cause : pick()};
  if (d.category == DrawCategory::kPair) {
    causes = {pick()};
    Cause second;
    do second = pick();
    while (second == causes[0]);
    causes.push_back(second);
  }
  std::vector<HiddenJointEffect> joint_effects;
  detail::Cartesian cart;
  const bool thermal = std::find(causes.begin(), causes.end(), Cause::kThermalDrift) != causes.end();
  if (thermal) {
    sc.warmup_K = 3.0 + 5.0 * u(rng);
    sc.warmup_tau_h = 0.5 + 2.5 * u(rng);
    d.warmup_tau_h = sc.warmup_tau_h;
  }
  for (Cause cause : causes) {
    TrueEffect t;
    t.cause = cause;
    t.amplitude_rad = logUniform(options.min_amp_deg, options.max_amp_deg) * kPi / 180;
    const double sign = u(rng) < 0.5 ? -1.0 : 1.0;
    HiddenJointEffect e;
    e.cause = cause;
    switch (cause) {
      case Cause::kJointCompliance: {
        RobotModel m = plain.model();
        // The arm's real masses: near the robot file's where it has them (published data are approximate: each
        // mass within +-10 %, each centre of mass within 10 mm), anything plausible where it has none.
        if (m.links.empty()) {
          m.links = randomLinks(m, true0, rng);
        } else {
          for (auto& l : m.links) {
            l.mass_kg *= 1 + 0.1 * (2 * u(rng) - 1);
            l.com_m += 0.01 * Eigen::Vector3d(2 * u(rng) - 1, 2 * u(rng) - 1, 2 * u(rng) - 1) / std::sqrt(3.0);
          }
        }
        const std::vector<int> loaded = gravityLoadedJoints(m, true0, qs);
        const int joint = loaded[static_cast<size_t>(u(rng) * loaded.size())];
        e = scaledHiddenEffect(m, true0, Cause::kJointCompliance, joint, sign * t.amplitude_rad, m.links, qs, rng);
        break;
      }
      case Cause::kThermalDrift: {
        e.joint = static_cast<int>(u(rng) * n);
        // RMS over the run of the zero drift about its mean is what the geometric model cannot take.
        SimulatedCell c(file_model, sc);
        double m = 0, v = 0;
        for (int i = 0; i < options.poses; ++i) m += c.temperatureRiseK(options.hours * i / options.poses) / options.poses;
        for (int i = 0; i < options.poses; ++i) v += std::pow(c.temperatureRiseK(options.hours * i / options.poses) - m, 2) / options.poses;
        e.zero_drift_rad_per_K = sign * t.amplitude_rad / std::sqrt(v);
        break;
      }
      case Cause::kCyclicTransmission:
      case Cause::kJointScale: {
        const int joint = static_cast<int>(u(rng) * n);
        e = scaledHiddenEffect(plain.model(), true0, cause, joint,
                               cause == Cause::kCyclicTransmission ? t.amplitude_rad : sign * t.amplitude_rad, {}, qs, rng);
        break;
      }
      case Cause::kBacklash:
        e.joint = static_cast<int>(u(rng) * n);
        e.backlash_width_rad = 2 * t.amplitude_rad;
        break;
      case Cause::kLinkDeflection: {
        std::vector<int> beams;
        for (int j = 0; j < n; ++j)
          if (applicable(file_model, Extension{Cause::kLinkDeflection, j}, false)) beams.push_back(j);
        cart.link = beams[static_cast<size_t>(u(rng) * beams.size())];
        const double length = linkLength(file_model, true0, cart.link);
        cart.sag_m = t.amplitude_rad * length;  // like a joint error of that size at the link's end
        cart.slope_rad = (4.0 / 3.0 + u(rng) / 6.0) * cart.sag_m / length;  // a uniform load .. a load at the end
        e.joint = cart.link;
        break;
      }
      case Cause::kNone:
      case Cause::kFrameDrift:  // not the robot's: OutsideEffect::kBaseDrift
        break;
    }
    t.joint = e.joint;
    if (cause != Cause::kLinkDeflection) joint_effects.push_back(e);
    d.effects.push_back(t);
  }
  if (d.category == DrawCategory::kOutOfLibrary) {
    d.outside = options.force_outside != OutsideEffect::kNone
                    ? options.force_outside
                    : (u(rng) < 0.5 ? OutsideEffect::kTrackerScaleDrift : OutsideEffect::kReachSag);
    const double amp = logUniform(options.min_amp_deg, options.max_amp_deg) * kPi / 180;
    if (d.outside == OutsideEffect::kBaseDrift) {
      // The cell warms up (a thermometer reads it where there is one); only the base moves with it.
      sc.warmup_K = 3.0 + 5.0 * u(rng);
      sc.warmup_tau_h = 0.5 + 2.5 * u(rng);
      sc.expansion_per_K = 0;
      d.warmup_tau_h = sc.warmup_tau_h;
      d.outside_size = amp;
      d.base_yaw_only = u(rng) < 0.5;
      std::normal_distribution<double> g;
      cart.yaw_only = d.base_yaw_only;
      cart.axis = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      if (!cart.yaw_only) cart.shift = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      cart.tau_h = sc.warmup_tau_h;
      cart.hours = options.hours;
    } else if (d.outside == OutsideEffect::kTrackerScaleDrift) {
      d.outside_size = amp / options.hours;  // a 1e-4 scale error over the run is like 1e-4 rad at 1 m
    } else {
      double r4 = 0;
      for (const auto& q : qs) r4 += std::pow(chainFrames(plain.model(), true0, q).back().translation().squaredNorm(), 2);
      d.outside_size = 3 * amp / std::sqrt(r4 / qs.size());  // most of a smooth field is absorbed by the geometry
    }
    cart.outside = d.outside;
    cart.outside_size = d.outside_size;
  }
  d.thermometer = !(u(rng) < options.no_thermometer_probability);

  // The cells: one per joint effect, on the same true robot.
  std::vector<SimulatedCell> cells;
  for (const auto& e : joint_effects) {
    SimulationConfig c = sc;
    c.hidden = e;
    cells.emplace_back(file_model, c);
  }
  const SimulatedCell truth(file_model, sc);
  auto truePose = [&](int i, const std::vector<HiddenJointState>& states, double t_h, bool cartesian, int only = -1) {
    Eigen::VectorXd dq = Eigen::VectorXd::Zero(n);
    for (size_t k = 0; k < cells.size(); ++k)
      if (only < 0 || static_cast<int>(k) == only) dq += cells[k].hiddenJointErrorRad(qs[i], &states[k], t_h);
    // One effect alone (for grading): the thermal growth of the lengths belongs to the thermal effect only.
    const bool growth = only < 0 || cells[static_cast<size_t>(only)].config().hidden.cause == Cause::kThermalDrift;
    const Eigen::VectorXd params = truth.trueParams(growth ? t_h : 0.0);
    const Eigen::VectorXd q_true = qs[static_cast<size_t>(i)] + dq;
    const Pose T = forwardKinematics(plain.model(), params, q_true);
    return cartesian ? cart.apply(plain.model(), params, q_true, T, t_h) : T;
  };
  // The hidden state along the path (backlash: the play, including moves that cross the gap only partly).
  std::vector<std::vector<HiddenJointState>> states(static_cast<size_t>(options.poses),
                                                    std::vector<HiddenJointState>(cells.size()));
  for (int i = 1; i < options.poses; ++i)
    for (size_t k = 0; k < cells.size(); ++k)
      states[i][k] = cells[k].advanceHiddenState(states[i - 1][k], qs[i - 1], qs[i]);

  std::vector<Observation> all, exact;
  std::vector<std::optional<double>> temperature, stamp;
  std::normal_distribution<double> thermometer(0.0, 0.01);  // a PT100 read to 0.01 K
  double distance = 0;
  for (int i = 0; i < options.poses; ++i) {
    const double t_h = options.hours * i / options.poses;
    const Pose T = truePose(i, states[i], t_h, true);
    all.push_back(plain.measurePose(T, qs[i], rng, d.kind));
    Observation x = all.back();
    x.measured_in_tracker = T;
    exact.push_back(x);
    distance += T.translation().norm() / options.poses;
    temperature.push_back(truth.temperatureC(t_h) + thermometer(rng));
    stamp.push_back(t_h * 3600.0);
  }
  h.sigma_position_mm = std::hypot(sc.tracker.sigmaPosition(distance), sc.repeatability_m / 2) * 1e3;
  // Gross errors.
  d.outlier_fraction = options.max_outlier_fraction * u(rng);
  std::vector<bool> gross(static_cast<size_t>(options.poses), false);
  for (int k = 0; k < static_cast<int>(std::round(d.outlier_fraction * options.poses)); ++k) {
    const auto i = static_cast<size_t>(u(rng) * options.poses);
    if (gross[i]) continue;
    gross[i] = true;
    std::normal_distribution<double> g;
    const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    all[i].measured_in_tracker.translation() += (1e-3 + 4e-3 * u(rng)) * dir;
  }
  for (int i = 0; i < options.poses; ++i) {
    MeasurementRow row;
    row.line = i + 2;
    row.q_rad = qs[static_cast<size_t>(i)];
    row.position_m = all[static_cast<size_t>(i)].measured_in_tracker.translation();
    if (d.kind == MeasurementKind::kPose6D)
      row.orientation = Eigen::Quaterniond(all[static_cast<size_t>(i)].measured_in_tracker.linear());
    row.stamp_s = stamp[static_cast<size_t>(i)];
    if (d.thermometer) row.temperature_c = temperature[static_cast<size_t>(i)];
    h.file.rows.push_back(row);
  }
  const DriverTable table = driversFromSequence(qs, d.thermometer ? temperature : std::vector<std::optional<double>>{}, stamp);
  for (int i = 0; i < options.poses; ++i) {
    const bool ident = i % 2 == 0;
    (ident ? h.data.identification : h.data.verification).push_back(all[static_cast<size_t>(i)]);
    (ident ? h.data.identification_drivers : h.data.verification_drivers).push_back(table.rows[static_cast<size_t>(i)]);
    if (gross[static_cast<size_t>(i)]) (ident ? h.outlier_identification : h.outlier_verification).push_back(i / 2);
  }
  h.data.has_thermal = table.has_thermal;
  h.data.thermal_source = table.thermal_source;
  h.model = file_model;
  h.start = registerFrames(file_model, file_model.nominal, h.data.identification).params;

  // Grading figures from the truth, on noise-free rows: what an effect leaves after a geometric fit.
  auto leftAfterGeometricFit = [&](const std::function<Pose(int)>& pose) {
    std::vector<Observation> ident, verify;
    for (int i = 0; i < options.poses; ++i) {
      Observation x = exact[static_cast<size_t>(i)];
      x.measured_in_tracker = pose(i);
      (i % 2 == 0 ? ident : verify).push_back(x);
    }
    const ExtendedFit geo = fitExtended(file_model, h.start, ident, h.data.identification_drivers, Extension{});
    return errorStats(file_model, geo, verify, h.data.verification_drivers).rms_mm;
  };
  h.effect_rms_mm = leftAfterGeometricFit([&](int i) { return exact[static_cast<size_t>(i)].measured_in_tracker; });
  size_t k = 0;
  for (auto& t : d.effects) {
    if (t.cause == Cause::kLinkDeflection) {
      detail::Cartesian only = cart;
      only.outside = OutsideEffect::kNone;
      t.effect_rms_mm = leftAfterGeometricFit([&](int i) {
        const Eigen::VectorXd params = truth.trueParams(0.0);
        return only.apply(plain.model(), params, qs[static_cast<size_t>(i)],
                          forwardKinematics(plain.model(), params, qs[static_cast<size_t>(i)]), 0.0);
      });
      t.joint_effect_rms_mm = t.effect_rms_mm;
      continue;
    }
    const int cell = static_cast<int>(k++);
    t.effect_rms_mm = leftAfterGeometricFit([&](int i) {
      return truePose(i, states[static_cast<size_t>(i)], options.hours * i / options.poses, false, cell);
    });
    t.joint_effect_rms_mm = t.effect_rms_mm;
    if (t.cause == Cause::kThermalDrift) {  // the joint-zero part alone: without the lengths' growth
      SimulationConfig zeros_only = sc;
      zeros_only.expansion_per_K = 0;
      zeros_only.hidden = joint_effects[static_cast<size_t>(cell)];
      const SimulatedCell z(file_model, zeros_only);
      t.joint_effect_rms_mm = leftAfterGeometricFit(
          [&](int i) { return z.truePose(qs[static_cast<size_t>(i)], options.hours * i / options.poses); });
    }
  }
  if (d.outside != OutsideEffect::kNone) {
    detail::Cartesian only = cart;
    only.link = -1;
    d.outside_rms_mm = leftAfterGeometricFit([&](int i) {
      const double t_h = options.hours * i / options.poses;
      const Eigen::VectorXd params = truth.trueParams(t_h);
      return only.apply(plain.model(), params, qs[static_cast<size_t>(i)],
                        forwardKinematics(plain.model(), params, qs[static_cast<size_t>(i)]), t_h);
    });
  }
  double noise = 0;
  int clean = 0;
  for (int i = 1; i < options.poses; i += 2) {
    if (gross[static_cast<size_t>(i)]) continue;
    noise += (all[static_cast<size_t>(i)].measured_in_tracker.translation() -
              exact[static_cast<size_t>(i)].measured_in_tracker.translation())
                 .squaredNorm();
    ++clean;
  }
  h.noise_rms_mm = std::sqrt(noise / std::max(1, clean)) * 1e3;
  return h;
}

}  // namespace cellcal::test
