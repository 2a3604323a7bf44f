// Test generator: a simulated data set with one physical effect hidden in it, drawn at random (cause, joint, size,
// seed). The code under test gets only what a user would have (nominal model, joint angles, tracker readings,
// temperatures, stamps); the truth stays here, to grade the answer.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/diagnosis.hpp"
#include "cellcal/core/kinematics.hpp"
#include "cellcal/core/measurement_csv.hpp"
#include "cellcal/core/simulation.hpp"

namespace cellcal::test {

struct HiddenEffectDraw {
  Cause cause = Cause::kNone;
  int joint = -1;            // 0-based, -1 for none
  double amplitude_rad = 0;  // RMS (over the poses) of the joint error the effect makes
  std::uint64_t seed = 0;
  MeasurementKind kind = MeasurementKind::kPose6D;
  std::string describe() const {
    char buf[200];
    std::snprintf(buf, sizeof buf, "%s joint %d, %.5f deg RMS, %s, seed %llu", causeName(cause), joint + 1,
                  amplitude_rad * 180 / kPi, kind == MeasurementKind::kPose6D ? "6D" : "position-only",
                  static_cast<unsigned long long>(seed));
    return buf;
  }
};

struct HiddenEffectData {
  HiddenEffectDraw draw;
  SimulationConfig config;
  RobotModel model;            // what the user knows: nominal with registered frames, no link masses
  DiagnosisData data;          // identification = even rows, verification = odd rows, in visiting order
  MeasurementFile file;        // the same rows as a measurement file would hold them (stamps, temperatures)
  // Truth, for grading only.
  double effect_rms_mm = 0;    // verification RMS the effect leaves after a geometric fit to noise-free data
  double noise_rms_mm = 0;     // verification RMS of the measurement noise alone (readings vs. the true robot)
  double joint_effect_rms_mm = 0;  // the same for the joint's part alone (thermal drift: without the lengths' growth)
};

inline std::vector<LinkInertia> randomLinks(const RobotModel& model, const Eigen::VectorXd& params, std::mt19937_64& rng) {
  return plausibleLinks(model, params, rng);
}

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

// Draws an effect and makes the data: `poses` poses over `hours` hours of work, in the order the robot visits them.
// amplitudes log-uniform in [min_amp_deg, max_amp_deg].
inline HiddenEffectData makeHiddenEffectData(const RobotModel& nominal, std::uint64_t seed, MeasurementKind kind,
                                             int poses = 400, double hours = 4.0, double min_amp_deg = 1e-3,
                                             double max_amp_deg = 5e-2) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  HiddenEffectData h;
  h.draw.seed = seed;
  h.draw.kind = kind;
  const std::vector<Cause> causes = {Cause::kNone,         Cause::kJointCompliance, Cause::kThermalDrift,
                                     Cause::kCyclicTransmission, Cause::kJointScale, Cause::kBacklash};
  h.draw.cause = causes[std::uniform_int_distribution<size_t>(0, causes.size() - 1)(rng)];
  h.draw.amplitude_rad = std::exp(std::log(min_amp_deg) + u(rng) * (std::log(max_amp_deg) - std::log(min_amp_deg))) *
                         kPi / 180;
  const double sign = u(rng) < 0.5 ? -1.0 : 1.0;

  SimulationConfig& sc = h.config;
  sc.seed = rng();
  sc.warmup_K = 0;  // no thermal effect unless drawn
  sc.zero_drift_per_K_max_rad = 0;
  sc.zero_wear_per_h_max_rad = 0;
  const int n = nominal.numJoints();
  SimulatedCell plain(nominal, sc);
  const std::vector<Eigen::VectorXd> qs = plain.randomConfigurations(poses, rng);
  const Eigen::VectorXd true0 = plain.trueParams(0.0);

  HiddenJointEffect& e = sc.hidden;
  e.cause = h.draw.cause;
  const double amp = h.draw.amplitude_rad;
  switch (h.draw.cause) {
    case Cause::kNone:
      h.draw.amplitude_rad = 0;
      break;
    case Cause::kJointCompliance: {
      RobotModel m = plain.model();
      m.links = randomLinks(m, true0, rng);
      const std::vector<int> loaded = gravityLoadedJoints(m, true0, qs);
      const int joint = loaded[std::uniform_int_distribution<size_t>(0, loaded.size() - 1)(rng)];
      e = scaledHiddenEffect(m, true0, Cause::kJointCompliance, joint, sign * amp, m.links, qs, rng);
      break;
    }
    case Cause::kThermalDrift:
      e.joint = std::uniform_int_distribution<int>(0, n - 1)(rng);
      sc.warmup_K = 3.0 + 5.0 * u(rng);
      // RMS over the run of the zero drift about its mean is what the geometric model cannot take.
      {
        SimulatedCell c(nominal, sc);
        std::vector<double> dT;
        for (int i = 0; i < poses; ++i) dT.push_back(c.temperatureRiseK(hours * i / poses));
        double m = 0, v = 0;
        for (double x : dT) m += x / poses;
        for (double x : dT) v += (x - m) * (x - m) / poses;
        e.zero_drift_rad_per_K = sign * amp / std::sqrt(v);
      }
      break;
    case Cause::kCyclicTransmission:
    case Cause::kJointScale: {
      const int joint = std::uniform_int_distribution<int>(0, n - 1)(rng);
      // Cyclic: the harmonics' random direction carries the sign.
      e = scaledHiddenEffect(plain.model(), true0, h.draw.cause, joint,
                             h.draw.cause == Cause::kCyclicTransmission ? amp : sign * amp, {}, qs, rng);
      break;
    }
    case Cause::kBacklash:
      e.joint = std::uniform_int_distribution<int>(0, n - 1)(rng);
      e.backlash_width_rad = 2 * amp;
      break;
  }
  h.draw.joint = e.cause == Cause::kNone ? -1 : e.joint;

  const SimulatedCell cell(nominal, sc);
  h.model = cell.model();
  std::vector<Observation> all;
  std::vector<std::optional<double>> temperature, stamp;
  std::normal_distribution<double> thermometer(0.0, 0.01);  // a PT100 read to 0.01 K
  // The hidden state along the path (backlash: the play, exact, including moves that cross the gap only partly).
  std::vector<HiddenJointState> state(poses);
  for (int i = 1; i < poses; ++i) state[i] = cell.advanceHiddenState(state[i - 1], qs[i - 1], qs[i]);
  for (int i = 0; i < poses; ++i) {
    const double t_h = hours * i / poses;
    all.push_back(cell.measure(qs[i], &state[i], t_h, rng, kind));
    temperature.push_back(cell.temperatureC(t_h) + thermometer(rng));
    stamp.push_back(t_h * 3600.0);
    MeasurementRow row;
    row.line = i + 2;
    row.q_rad = qs[i];
    row.position_m = all.back().measured_in_tracker.translation();
    if (kind == MeasurementKind::kPose6D) row.orientation = Eigen::Quaterniond(all.back().measured_in_tracker.linear());
    row.stamp_s = stamp.back();
    row.temperature_c = temperature.back();
    h.file.rows.push_back(row);
  }
  const DriverTable d = driversFromSequence(qs, temperature, stamp);
  for (int i = 0; i < poses; ++i) {
    const bool ident = i % 2 == 0;
    (ident ? h.data.identification : h.data.verification).push_back(all[i]);
    (ident ? h.data.identification_drivers : h.data.verification_drivers).push_back(d.rows[i]);
  }
  h.data.has_thermal = d.has_thermal;
  h.data.thermal_source = d.thermal_source;

  // Grading figures from the truth: the rows as a cell's true robot reaches them, without noise.
  auto exactRows = [&](const SimulatedCell& c, std::vector<Observation>& ident, std::vector<Observation>& verify) {
    for (int i = 0; i < poses; ++i) {
      Observation x = all[i];
      x.measured_in_tracker = c.truePose(qs[i], hours * i / poses, &state[i]);
      (i % 2 == 0 ? ident : verify).push_back(x);
    }
  };
  auto unabsorbedMm = [&](const std::vector<Observation>& ident, const std::vector<Observation>& verify) {
    const ExtendedFit geo = fitExtended(h.model, h.model.nominal, ident, h.data.identification_drivers, Extension{});
    return errorStats(h.model, geo, verify, h.data.verification_drivers).rms_mm;
  };
  std::vector<Observation> exact_ident, exact_verify;
  exactRows(cell, exact_ident, exact_verify);
  h.effect_rms_mm = unabsorbedMm(exact_ident, exact_verify);
  h.joint_effect_rms_mm = h.effect_rms_mm;
  if (h.draw.cause == Cause::kThermalDrift) {
    SimulationConfig zeros_only = sc;
    zeros_only.expansion_per_K = 0;
    std::vector<Observation> ident, verify;
    exactRows(SimulatedCell(nominal, zeros_only), ident, verify);
    h.joint_effect_rms_mm = unabsorbedMm(ident, verify);
  }
  double noise = 0;
  for (size_t i = 0; i < exact_verify.size(); ++i)
    noise += (h.data.verification[i].measured_in_tracker.translation() - exact_verify[i].measured_in_tracker.translation())
                 .squaredNorm();
  h.noise_rms_mm = std::sqrt(noise / static_cast<double>(exact_verify.size())) * 1e3;
  return h;
}

}  // namespace cellcal::test
