// BeyondRange and DriverRange (prediction.hpp): a joint's error, or a position error, beyond the range of a model's
// data. Apart from extensionTransfer,
// which measures it, so that the robot file's parser (and its fuzz target) reaches it without the solvers.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/cause.hpp"

namespace cellcal {

double distanceBeyond(double x, double lower, double upper) {
  return x < lower ? lower - x : x > upper ? x - upper : 0.0;
}

double sigmaBeyond(double sigma_at_1, int growth, double d, double checked) {
  if (d <= 0 || sigma_at_1 <= 0) return 0.0;
  if (checked > 0) d = std::min(d, checked);
  return sigma_at_1 * std::pow(d, growth);
}

namespace {

// The gap of b that q lies in, within b's range; nullptr where none.
const std::pair<double, double>* gapAt(const BeyondRange& b, double q_rad) {
  if (distanceBeyond(q_rad, b.lower_rad, b.upper_rad) > 0) return nullptr;
  for (const auto& g : b.gaps_rad)
    if (q_rad > g.first && q_rad < g.second) return &g;
  return nullptr;
}

}  // namespace

double BeyondRange::beyondRad(double q_rad) const {
  if (const auto* g = gapAt(*this, q_rad)) return std::min(q_rad - g->first, g->second - q_rad);
  return distanceBeyond(q_rad, lower_rad, upper_rad);
}

bool BeyondRange::inGap(double q_rad) const { return gapAt(*this, q_rad) != nullptr; }

std::vector<std::pair<double, double>> rangeGaps(std::vector<double> x, double min_width) {
  std::sort(x.begin(), x.end());
  std::vector<std::pair<double, double>> gaps;
  for (size_t i = 1; i < x.size(); ++i)
    if (x[i] - x[i - 1] > min_width) gaps.emplace_back(x[i - 1], x[i]);
  return gaps;
}

std::string BeyondRange::gapsText() const {
  if (gaps_rad.empty()) return "";
  std::string t = " (no data in";
  for (size_t k = 0; k < gaps_rad.size(); ++k) {
    char g[64];
    std::snprintf(g, sizeof g, "%s [%.1f, %.1f]", k == 0 ? "" : k + 1 == gaps_rad.size() ? " and" : ",",
                  gaps_rad[k].first * 180 / kPi, gaps_rad[k].second * 180 / kPi);
    t += g;
  }
  return t + " deg)";
}

double BeyondRange::sigmaRad(double q_rad) const {
  return sigmaBeyond(sigma_at_1_rad, growth, beyondRad(q_rad), checked_rad);
}

bool BeyondRange::judged(double q_rad) const { return beyondRad(q_rad) <= checked_rad; }

const BeyondRange* firstUnjudged(const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad) {
  for (const BeyondRange& b : ranges)
    if (b.joint >= 0 && b.joint < q_rad.size() && !b.judged(q_rad[b.joint])) return &b;
  return nullptr;
}

const BeyondRange* firstBeyond(const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad) {
  for (const BeyondRange& b : ranges)
    if (b.joint >= 0 && b.joint < q_rad.size() && b.beyondRad(q_rad[b.joint]) > 0) return &b;
  return nullptr;
}

std::string BeyondRange::rangeText() const {
  char t[80];
  std::snprintf(t, sizeof t, "[%.1f, %.1f] deg", lower_rad * 180 / kPi, upper_rad * 180 / kPi);
  return t;
}

std::string unjudgedText(const BeyondRange& b, double q_rad) {
  char t[400], u[80];
  if (const auto* gap = gapAt(b, q_rad)) {
    std::snprintf(t, sizeof t, "joint %d at %.1f deg lies %.1f deg inside [%.1f, %.1f] deg, a stretch of %s, the range "
                  "its model extensions were fitted on, that its data never reached; ", b.joint + 1, q_rad * 180 / kPi,
                  b.beyondRad(q_rad) * 180 / kPi, gap->first * 180 / kPi, gap->second * 180 / kPi, b.rangeText().c_str());
    if (b.checked_rad > 0) std::snprintf(u, sizeof u, "they were judged up to %.1f deg from their data", b.checked_rad * 180 / kPi);
    else std::snprintf(u, sizeof u, "they were not judged beyond their data");
    return std::string(t) + u;
  }
  std::snprintf(t, sizeof t, "joint %d at %.1f deg lies %.1f deg beyond %s, the range its model extensions were fitted "
                "on; ", b.joint + 1, q_rad * 180 / kPi, b.beyondRad(q_rad) * 180 / kPi, b.rangeText().c_str());
  if (b.checked_rad > 0) std::snprintf(u, sizeof u, "they were judged up to %.1f deg beyond it", b.checked_rad * 180 / kPi);
  else std::snprintf(u, sizeof u, "they were not judged beyond it");
  return std::string(t) + u;
}

const char* BeyondRange::growthText() const {
  return growth == 0 ? "" : growth == 1 ? " per rad beyond" : " per rad^2 beyond";
}

bool BeyondRange::IsValid(int num_joints, std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (joint < 0 || joint >= num_joints) return fail("joint " + std::to_string(joint + 1) + " out of range");
  if (!std::isfinite(lower_rad) || !std::isfinite(upper_rad) || lower_rad > upper_rad)
    return fail("lower and upper must be finite, lower <= upper");
  if (!(sigma_at_1_rad >= 0) || !std::isfinite(sigma_at_1_rad)) return fail("sigma must be finite and >= 0");
  if (growth < 0 || growth > 2) return fail("growth must be 0, 1 or 2");
  if (!(checked_rad >= 0) || !std::isfinite(checked_rad)) return fail("checked must be finite and >= 0");
  double after = lower_rad;
  for (const auto& [a, b] : gaps_rad) {
    if (!std::isfinite(a) || !std::isfinite(b) || !(a < b))
      return fail("a gap must be finite with its lower end below its upper one");
    if (a < after || b > upper_rad)
      return fail("the gaps must lie within the range, in order and apart");
    after = b;
  }
  return true;
}

double DriverRange::beyond(double x) const { return distanceBeyond(x, lower, upper); }

double DriverRange::checked(double x) const { return x < lower ? checked_below : x > upper ? checked_above : 0.0; }

double DriverRange::sigmaM(double x) const { return sigmaBeyond(sigma_at_1_m, growth, beyond(x), checked(x)); }

bool DriverRange::judged(double x) const { return beyond(x) <= checked(x); }

double DriverRange::value(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad,
                          const Drivers& drivers) const {
  return causeModel(extension.cause).rangeValue(model, params, extension, q_rad, drivers);
}

bool DriverRange::IsValid(const RobotModel& model, std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (extension.cause == Cause::kNone) return fail("no extension");
  const CauseModel& c = causeModel(extension.cause);
  if (c.regionJoint(extension) >= 0 || std::isnan(c.rangeValue(model, model.nominal, extension,
                                                               Eigen::VectorXd::Zero(model.numJoints()), Drivers{})))
    return fail(extensionSpec(extension) + " is bounded by a joint's range or by none, not by a driver");
  if (!std::isfinite(lower) || !std::isfinite(upper) || lower > upper)
    return fail("lower and upper must be finite, lower <= upper");
  if (!(sigma_at_1_m >= 0) || !std::isfinite(sigma_at_1_m)) return fail("sigma must be finite and >= 0");
  if (growth < 0 || growth > 2) return fail("growth must be 0, 1 or 2");
  for (double c : {checked_below, checked_above})
    if (!(c >= 0) || !std::isfinite(c)) return fail("checked_below and checked_above must be finite and >= 0");
  return true;
}

const DriverRange* firstUnjudged(const RobotModel& model, const Eigen::VectorXd& params,
                                 const std::vector<DriverRange>& ranges, const Eigen::VectorXd& q_rad,
                                 const Drivers& drivers, double* x) {
  for (const DriverRange& r : ranges) {
    const double v = r.value(model, params, q_rad, drivers);
    if (std::isfinite(v) && !r.judged(v)) {
      if (x) *x = v;
      return &r;
    }
  }
  return nullptr;
}

const DriverRange* firstBeyond(const RobotModel& model, const Eigen::VectorXd& params,
                               const std::vector<DriverRange>& ranges, const Eigen::VectorXd& q_rad,
                               const Drivers& drivers, double* x) {
  for (const DriverRange& r : ranges) {
    const double v = r.value(model, params, q_rad, drivers);
    if (std::isfinite(v) && r.beyond(v) > 0) {
      if (x) *x = v;
      return &r;
    }
  }
  return nullptr;
}

namespace {
// Where a label's " (unit)" at its end begins; npos without one.
size_t unitStart(const std::string& label) {
  return !label.empty() && label.back() == ')' ? label.rfind(" (") : std::string::npos;
}
}  // namespace

std::string DriverRange::quantity() const { return label.substr(0, unitStart(label)); }

std::string DriverRange::unit() const {
  const size_t open = unitStart(label);
  return open == std::string::npos ? "" : label.substr(open + 2, label.size() - open - 3);
}

std::string DriverRange::growthText() const {
  return growth == 0 ? "" : " per " + unit() + (growth == 1 ? "" : "^2") + " beyond";
}

std::string DriverRange::rangeText() const {
  char t[300];
  std::snprintf(t, sizeof t, "%s [%.3g, %.3g] %s", quantity().c_str(), lower, upper, unit().c_str());
  return t;
}

std::string DriverRange::judgedText() const {
  auto end = [&](double c, const char* side) {
    char t[80];
    if (c > 0) std::snprintf(t, sizeof t, "%.3g %s %s it", c, unit().c_str(), side);
    else std::snprintf(t, sizeof t, "not %s it", side);
    return std::string(t);
  };
  if (checked_below <= 0 && checked_above <= 0) return "not judged beyond it";
  return "judged up to " + end(checked_below, "below") + " and " + end(checked_above, "above");
}

std::string unjudgedText(const DriverRange& r, double x) {
  const std::string u = r.unit();
  char t[500];
  std::snprintf(t, sizeof t, "%s at %.3g %s lies %.3g %s beyond [%.3g, %.3g] %s, the range %s was fitted on; ",
                r.quantity().c_str(), x, u.c_str(), r.beyond(x), u.c_str(), r.lower, r.upper, u.c_str(),
                causeModel(r.extension.cause).label(r.extension).c_str());
  char c[120];
  if (r.checked(x) > 0) std::snprintf(c, sizeof c, "it was judged up to %.3g %s beyond it", r.checked(x), u.c_str());
  else std::snprintf(c, sizeof c, "it was not judged beyond it");
  return std::string(t) + c;
}

double driverRangeVariance(const RobotModel& model, const Eigen::VectorXd& params,
                           const std::vector<DriverRange>& ranges, const Eigen::VectorXd& q_rad, const Drivers& drivers) {
  double v = 0;
  for (const DriverRange& r : ranges) {
    if (r.sigma_at_1_m <= 0) continue;
    const double x = r.value(model, params, q_rad, drivers);
    if (std::isfinite(x)) v += std::pow(r.sigmaM(x), 2);
  }
  return v;
}

}  // namespace cellcal
