#include "cellcal/lab/continuous_scenario.hpp"

#include <chrono>
#include <cmath>
#include <stdexcept>

#include "cellcal/core/identification/registration.hpp"

namespace cellcal {

namespace {

// k indices evenly spaced over [begin, end).
std::vector<size_t> evenlySpaced(size_t begin, size_t end, int k) {
  std::vector<size_t> out;
  const size_t n = end - begin;
  if (n == 0 || k <= 0) return out;
  if (static_cast<size_t>(k) >= n) {
    for (size_t i = begin; i < end; ++i) out.push_back(i);
    return out;
  }
  for (int j = 0; j < k; ++j) out.push_back(begin + static_cast<size_t>((j + 0.5) * static_cast<double>(n) / k));
  return out;
}

}  // namespace

bool ContinuousScenarioOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (!(update_interval_h > 0)) return fail("update_interval_h must be > 0");
  if (!(initial_h > 0)) return fail("initial_h must be > 0");
  if (poses_per_update < 1) return fail("poses_per_update must be >= 1");
  if (initial_poses < 8) return fail("initial_poses must be >= 8");
  if (!(drift_scale >= 0)) return fail("drift_scale must be >= 0");
  for (const auto& e : extensions)
    if (e.cause == Cause::kNone) return fail("extensions: 'none' is not an extension");
  return true;
}

ContinuousScenarioResult runContinuousScenario(const ContinuousScenario& sc) {
  std::string err;
  if (!sc.model) throw std::invalid_argument("runContinuousScenario: no model");
  if (!sc.options.IsValid(&err)) throw std::invalid_argument("ContinuousScenarioOptions: " + err);
  const RobotModel& model = *sc.model;
  const auto& rows = sc.rows;
  for (size_t i = 1; i < rows.size(); ++i)
    if (rows[i].stamp_s < rows[i - 1].stamp_s)
      throw std::invalid_argument("runContinuousScenario: row " + std::to_string(i) + " goes back in time");
  const auto t_start = std::chrono::steady_clock::now();

  // Intervals: the initial period, then consecutive rows within update_interval_h of the interval's first row.
  std::vector<std::pair<size_t, size_t>> intervals;
  size_t initial_end = 0;
  while (initial_end < rows.size() && rows[initial_end].stamp_s - rows[0].stamp_s < sc.options.initial_h * 3600.0)
    ++initial_end;
  intervals.emplace_back(0, initial_end);
  for (size_t i = initial_end; i < rows.size();) {
    size_t j = i;
    while (j < rows.size() && rows[j].stamp_s - rows[i].stamp_s < sc.options.update_interval_h * 3600.0) ++j;
    intervals.emplace_back(i, j);
    i = j;
  }
  if (intervals.size() < 2) throw std::invalid_argument("runContinuousScenario: the stamps span less than two intervals");

  // Causal drivers: moves between consecutive rows; thermal relative to the first row.
  std::vector<Eigen::VectorXd> q;
  for (const auto& r : rows) q.push_back(r.observation.q_rad);
  DriverTable drivers = driversFromSequence(q, {}, {});
  bool all_temp = true;
  for (const auto& r : rows) all_temp = all_temp && r.temperature_c.has_value();
  for (size_t i = 0; i < rows.size(); ++i)
    drivers.rows[i].thermal = all_temp ? *rows[i].temperature_c - *rows[0].temperature_c
                                       : (rows[i].stamp_s - rows[0].stamp_s) / 3600.0;

  // Initial batch from the initial period: registration, geometric (and extended) fit.
  ContinuousScenarioResult res;
  res.initial_rows = static_cast<int>(intervals[0].second - intervals[0].first);
  std::vector<Observation> batch;
  std::vector<Drivers> batch_drivers;
  for (size_t i : evenlySpaced(intervals[0].first, intervals[0].second, sc.options.initial_poses)) {
    batch.push_back(rows[i].observation);
    batch_drivers.push_back(drivers.rows[i]);
  }
  if (batch.size() < 8) throw std::invalid_argument("runContinuousScenario: fewer than 8 rows in the initial period");
  const Eigen::VectorXd start = registerFrames(model, model.nominal, batch).params;
  const ExtendedFit geo = fitExtended(model, start, batch, batch_drivers, std::vector<Extension>{});
  res.initial_fit = errorStats(model, geo, batch, batch_drivers);
  const bool extended = !sc.options.extensions.empty();
  const ExtendedFit ext =
      extended ? fitExtended(model, start, batch, batch_drivers, sc.options.extensions, {}, {}, &geo.params) : geo;
  RlsCalibrator rls(model, geo), rls_ext(model, ext);
  res.poses_used = static_cast<int>(batch.size());
  const Eigen::VectorXd drift_sigma = sc.options.drift.sigmas(model) * sc.options.drift_scale;

  ErrorStatsAccumulator all_static, all_rls, all_ext;
  KinematicsData kd(model);
  double last_update_s = rows[intervals[0].second - 1].stamp_s;
  for (size_t w = 1; w < intervals.size(); ++w) {
    const auto [b, e] = intervals[w];
    IntervalResult ir;
    ir.start_h = (rows[b].stamp_s - rows[0].stamp_s) / 3600.0;
    ir.end_h = (rows[e - 1].stamp_s - rows[0].stamp_s) / 3600.0;
    ir.rows = static_cast<int>(e - b);
    double temp = 0;
    ErrorStatsAccumulator acc_static, acc_rls, acc_ext;
    for (size_t i = b; i < e; ++i) {
      const Observation& o = rows[i].observation;
      const Pose p_static = forwardKinematics(model, kd, geo.params, o.q_rad);
      const Pose p_rls = rls.predict(o.q_rad);
      acc_static.add(o, p_static);
      all_static.add(o, p_static);
      acc_rls.add(o, p_rls);
      all_rls.add(o, p_rls);
      if (extended) {
        const Pose p_ext = rls_ext.predict(o.q_rad, &drivers.rows[i]);
        acc_ext.add(o, p_ext);
        all_ext.add(o, p_ext);
      }
      temp += rows[i].temperature_c.value_or(std::nan("")) / static_cast<double>(e - b);
    }
    ir.temperature_c = temp;
    ir.static_model = acc_static.stats();
    ir.rls = acc_rls.stats();
    ir.rls_extended = acc_ext.stats();
    // Update: drift since the last update as process noise, then the interval's fresh poses one by one.
    const double dt_h = (rows[e - 1].stamp_s - last_update_s) / 3600.0;
    if (dt_h > 0 && sc.options.drift_scale > 0) {
      rls.addProcessNoise(drift_sigma * std::sqrt(dt_h), rows[0].observation.kind);
      rls_ext.addProcessNoise(drift_sigma * std::sqrt(dt_h), rows[0].observation.kind);
    }
    for (size_t i : evenlySpaced(b, e, sc.options.poses_per_update)) {
      rls.addObservation(rows[i].observation);
      if (extended) rls_ext.addObservation(rows[i].observation, &drivers.rows[i]);
      ++ir.poses_used;
    }
    last_update_s = rows[e - 1].stamp_s;
    res.poses_used += ir.poses_used;
    ++res.updates;
    res.intervals.push_back(ir);
  }
  res.static_overall = all_static.stats();
  res.rls_overall = all_rls.stats();
  res.rls_extended_overall = all_ext.stats();
  res.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return res;
}

}  // namespace cellcal
