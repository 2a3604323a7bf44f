// The region check of diagnosis.hpp: a cause chosen on part of the workspace or of a joint's range must not make the
// error worse beyond it. Two kinds of draw, each a campaign (diagnosed with alternate rows verifying, as `cellcal
// diagnose` does by default) and rows beyond it that no campaign row reached, which grade the model chosen against
// the campaign's own geometric fit:
//  - a library cause (hidden_effect.hpp: every kind, joint and size) over the whole workspace, the campaign the rows
//    on one side of a random plane (60 % of them): the check must keep it;
//  - a joint with a local defect outside the library (an error bump over 0.2 rad of its angle) measured on 60 % of
//    its range: a cyclic term follows the bump inside and is off by millimetres beyond; the check must leave it out.
// And the workspace split itself against a plain computation.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdlib>

#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/cause.hpp"
#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

int drawsOr(int fallback) {
  const char* env = std::getenv("CELLCAL_DIAGNOSIS_DRAWS");
  return env ? std::atoi(env) : fallback;
}

// A campaign and the rows beyond it.
struct Campaign {
  DiagnosisData data;                  // the campaign's rows, alternate split
  Eigen::VectorXd start;               // frames registered on its identification rows
  std::vector<Observation> beyond;
  std::vector<Drivers> beyond_drivers;
  std::string text;
};

// Rows in visiting order: those `inside` form the campaign (alternate rows verify), the others are beyond it.
Campaign campaignOf(const RobotModel& model, const std::vector<Observation>& rows, const std::vector<Drivers>& drivers,
                    const std::vector<bool>& inside, bool has_thermal, const std::string& thermal_source) {
  Campaign c;
  int k = 0;
  for (size_t i = 0; i < rows.size(); ++i) {
    if (!inside[i]) {
      c.beyond.push_back(rows[i]);
      c.beyond_drivers.push_back(drivers[i]);
      continue;
    }
    const bool verify = k++ % 2 == 1;
    (verify ? c.data.verification : c.data.identification).push_back(rows[i]);
    (verify ? c.data.verification_drivers : c.data.identification_drivers).push_back(drivers[i]);
  }
  c.data.has_thermal = has_thermal;
  c.data.thermal_source = thermal_source;
  c.start = registerFrames(model, model.nominal, c.data.identification).params;
  return c;
}

// A library cause over the whole workspace; the campaign on one side of a random plane.
Campaign libraryCause(const test::HiddenEffectData& h, std::mt19937_64& rng) {
  std::vector<Observation> rows;
  std::vector<Drivers> drivers;
  for (size_t i = 0; i < h.data.identification.size() + h.data.verification.size(); ++i) {
    const bool ident = i % 2 == 0;
    rows.push_back((ident ? h.data.identification : h.data.verification)[i / 2]);
    drivers.push_back((ident ? h.data.identification_drivers : h.data.verification_drivers)[i / 2]);
  }
  std::normal_distribution<double> g;
  const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
  std::vector<double> x;
  for (const auto& o : rows) x.push_back(dir.dot(o.measured_in_tracker.translation()));
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const double cut = sorted[sorted.size() * 6 / 10];
  std::vector<bool> inside;
  for (double v : x) inside.push_back(v < cut);
  Campaign c = campaignOf(h.model, rows, drivers, inside, h.data.has_thermal, h.data.thermal_source);
  c.text = h.draw.describe();
  return c;
}

// A joint (2 or 3) with an error bump of 0.06-0.3 deg over 0.2 rad (1 sigma) of its angle (a damaged stretch of a
// gear, a cable that snags: nothing in the library) in the middle of the 60 % of its range the campaign works on.
Campaign bumpedJoint(const RobotModel& model, const test::RandomDraw& d, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  SimulationConfig sc = d.steadySc();
  const SimulatedCell cell(model, sc);
  const int j = 1 + static_cast<int>(u(rng) * 2);
  const double amplitude_rad = (0.06 + 0.24 * u(rng)) * kPi / 180;
  const std::vector<Eigen::VectorXd> qs = cell.randomConfigurations(900, rng);
  std::vector<double> sorted;
  for (const auto& q : qs) sorted.push_back(q[j]);
  std::sort(sorted.begin(), sorted.end());
  const bool low = u(rng) < 0.5;  // the lower or the upper 60 % of the joint's range
  const double cut = sorted[low ? sorted.size() * 6 / 10 : sorted.size() * 4 / 10];
  const double centre = sorted[low ? sorted.size() * 3 / 10 : sorted.size() * 7 / 10];
  std::vector<Observation> rows;
  std::vector<bool> inside;
  for (const auto& q : qs) {
    Eigen::VectorXd qt = q;
    qt[j] += amplitude_rad * std::exp(-0.5 * (q[j] - centre) * (q[j] - centre) / (0.2 * 0.2));
    rows.push_back(cell.measurePose(cell.truePose(qt, 0.0), q, rng, d.kind));
    inside.push_back(low ? q[j] < cut : q[j] >= cut);
  }
  // The drivers of each part in its own visiting order (what a file of that part would give).
  std::vector<Eigen::VectorXd> in_q, out_q;
  for (size_t i = 0; i < qs.size(); ++i) (inside[i] ? in_q : out_q).push_back(qs[i]);
  const DriverTable in_d = driversFromSequence(in_q, {}, {}), out_d = driversFromSequence(out_q, {}, {});
  std::vector<Drivers> drivers;
  size_t a = 0, b = 0;
  for (size_t i = 0; i < qs.size(); ++i) drivers.push_back(inside[i] ? in_d.rows[a++] : out_d.rows[b++]);
  Campaign c = campaignOf(model, rows, drivers, inside, false, "");
  char t[200];
  std::snprintf(t, sizeof t, "%s %s, joint %d bump %.3f deg at %.2f rad, campaign on its %s 60 %%", d.name.c_str(),
                d.kind == MeasurementKind::kPose6D ? "6D" : "points", j + 1, amplitude_rad * 180 / kPi, centre,
                low ? "lower" : "upper");
  c.text = t;
  return c;
}

// Diagnosis without and with the check, graded beyond the campaign.
struct Graded {
  DiagnosisResult off, on;
  double geometric_mm = 0, off_mm = 0, on_mm = 0;  // mean position error beyond the campaign
};
Graded grade(const RobotModel& model, const Campaign& c) {
  Graded g;
  DiagnosisOptions no_check;
  no_check.region_check = false;
  g.off = diagnose(model, c.start, c.data, no_check);
  g.on = diagnose(model, c.start, c.data);
  auto beyond = [&](const ExtendedFit& f) { return errorStats(model, f, c.beyond, c.beyond_drivers).mean_mm; };
  g.geometric_mm = beyond(g.off.geometric.fit);
  g.off_mm = beyond(g.off.best().fit);
  g.on_mm = beyond(g.on.best().fit);
  std::string checks;
  for (const auto& r : g.on.region_checks) {
    char t[200];
    std::snprintf(t, sizeof t, " [%s by %s: %+.1f %%, z %.1f]", extensionLabel(r.cause).c_str(), r.split.c_str(),
                  r.gain_pct, r.z);
    checks += t;
  }
  std::printf("  %s\n    without the check %s, with it %s; beyond: geometric %.4f, without %.4f, with %.4f mm;%s\n",
              c.text.c_str(), modelLabel(g.off.causes()).c_str(), modelLabel(g.on.causes()).c_str(), g.geometric_mm,
              g.off_mm, g.on_mm, checks.c_str());
  return g;
}

TEST(RegionCheck, LibraryCausesAreKept) {
  const int draws = drawsOr(12);
  std::mt19937_64 rng(test::testSeed());
  int dropped = 0, real = 0, named_off = 0, named_on = 0;
  double sum_off = 0, sum_on = 0, sum_geo = 0;
  int dropped_above_noise = 0;  // causes left out whose effect was over twice the noise
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = test::DrawCategory::kSingle;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const Campaign c = libraryCause(h, rng);
    const Graded g = grade(h.model, c);
    sum_geo += g.geometric_mm, sum_off += g.off_mm, sum_on += g.on_mm;
    dropped += !g.on.not_transferred.empty();
    if (!g.on.not_transferred.empty()) {
      dropped_above_noise += h.draw.effects.front().effect_rms_mm > 2 * h.noise_rms_mm;
      std::printf("  left out: effect %.4f mm over noise %.4f mm (%.1fx); beyond the campaign %.4f -> %.4f mm\n",
                  h.draw.effects.front().effect_rms_mm, h.noise_rms_mm,
                  h.draw.effects.front().effect_rms_mm / h.noise_rms_mm, g.off_mm, g.on_mm);
    }
    if (h.draw.effects.front().effect_rms_mm > h.noise_rms_mm) {
      ++real;
      auto hit = [&](const DiagnosisResult& d) {
        const auto got = d.causes();
        return !got.empty() && got.front().cause == h.draw.effects.front().cause;
      };
      named_off += hit(g.off);
      named_on += hit(g.on);
    }
  }
  std::printf("  summary: %d draws, %d causes left out; causes above the noise named first %d/%d without the check, "
              "%d/%d with it; mean beyond the campaign: geometric %.4f, without the check %.4f, with it %.4f mm\n",
              draws, dropped, named_off, real, named_on, real, sum_geo / draws, sum_off / draws, sum_on / draws);
  // Measured over 300 draws (CELLCAL_TEST_SEED=11 CELLCAL_DIAGNOSIS_DRAWS=300): none left out, the lowest z 2.8. Before
  // the fits' variances were taken off the judged errors, seed 787736568605020234 left out a true cyclic error of the
  // UR10's joint 1 near the noise (-15.9 %, z -2.2; now +10.3 %, z 1.4) and failed the mean then judged.
  // With no cause left out the check changes nothing (the same models), so what it costs is the causes it leaves out:
  // at most one draw in 12, and only a cause near the noise, whose region folds' fits are the least sure. The mean of the
  // draws used to be judged instead (within 2 % of the mean without the check); a random seed, 7950451516401482702, left
  // out a cyclic error of the UR10's joint 2 1.3x the noise (folds' z -2.5; the one run of 80 random seeds that failed),
  // which cost that one draw 0.035 -> 0.057 mm and the mean 3.6 %.
  EXPECT_LE(dropped, 1);
  EXPECT_EQ(dropped_above_noise, 0) << "a cause over twice the noise left out";
  EXPECT_GE(named_on, named_off - 1);
}

TEST(RegionCheck, ACyclicTermFittedOnPartOfAJointsRangeIsLeftOut) {
  const int draws = drawsOr(8);
  std::mt19937_64 rng(test::testSeed());
  int worse_off = 0, worse_on = 0, left_out = 0;
  for (int k = 0; k < draws; ++k) {
    const test::RandomDraw d = test::randomDraw(rng);
    const RobotModel model = test::robot(d.name);
    const Campaign c = bumpedJoint(model, d, rng);
    const Graded g = grade(model, c);
    worse_off += !g.off.selection.empty() && g.off_mm > g.geometric_mm;
    worse_on += !g.on.selection.empty() && g.on_mm > g.geometric_mm;
    left_out += !g.on.not_transferred.empty();
    if (!g.on.not_transferred.empty()) {
      EXPECT_NE(describeVerdict(g.on).find("left out: " + modelLabel(g.on.not_transferred)), std::string::npos)
          << describeVerdict(g.on);
    }
  }
  std::printf("  summary: %d draws; worse than geometric beyond the campaign: %d without the check, %d with it (%d "
              "left out)\n",
              draws, worse_off, worse_on, left_out);
  // Measured over 40 draws (CELLCAL_DIAGNOSIS_DRAWS=40): worse beyond without the check in 37 (by 0.65-111 mm), never
  // with it; over 3 x 40 more, 109 without, never with; over 60 (CELLCAL_TEST_SEED=12), 55 without, never with, as
  // before the fits' variances were taken off. One draw in about 130 slips through: seed
  // 17643739216847302122, a 0.067 deg bump on the UR10's joint 3, judged 6.9 % worse at the ends of the campaign's
  // range (z -0.9, not significant; +4.1 %, z 0.5 with the variances off) and kept; beyond the campaign 0.215 mm
  // against the geometric 0.028 mm. The check sees 15 % of the range beyond the fit, the grading 40 %: a weak cause
  // that hurts only far out escapes it (issue #35, regions the model never saw). So one such draw in 8 is allowed, two are not (0.2 % of runs by that rate).
  EXPECT_GE(worse_off, draws / 2) << "the draws do not make the failure the check is for";
  EXPECT_LE(worse_on, 1);
}

// A campaign of the rows `inside` (rows and drivers in visiting order), a model of `e` fitted on its identification
// rows as `calibrate` fits it, what extensionTransfer measures of it beyond them, and its prediction there.
struct FittedCampaign {
  Campaign c;
  ExtendedFit fit;
  ExtensionTransfer transfer;
  PredictionModel pm;
};
FittedCampaign fitCampaign(const RobotModel& model, const std::vector<Observation>& rows,
                           const std::vector<Eigen::VectorXd>& qs, const std::vector<bool>& inside, const Extension& e) {
  FittedCampaign f;
  f.c = campaignOf(model, rows, driversFromSequence(qs, {}, {}).rows, inside, false, "");
  DiagnosisOptions o;
  o.identifiability.prior_sigma = plausibleDeviation(model);
  const DiagnosisData& d = f.c.data;
  f.fit = fitExtended(model, f.c.start, d.identification, d.identification_drivers, {e}, o.solver, o.identifiability);
  f.transfer = extensionTransfer(model, f.c.start, f.fit, d.identification, d.identification_drivers, o);
  f.pm = predictionModel(model, f.fit, d.identification, d.identification_drivers);
  return f;
}

// A joint (2 or 3) measured on 60 % of its range, with an error of one of two kinds, and a model that names a cause of
// that joint (cyclic_transmission or joint_scale, drawn):
//  - `library`: the named cause is the truth, over the whole range (hidden_effect.hpp's scaling, 0.02-0.1 deg RMS);
//  - otherwise an error outside the library that grows smoothly from the campaign's middle (a quadratic in the angle,
//    0.02-0.1 deg RMS over the campaign), which the named cause follows inside and only partly beyond.
// The model is fitted on the campaign's identification rows (plausible ranges on) and predicts the rows beyond it.
struct Carried {
  double ratio_without = 0, ratio_with = 0;  // RMS of actual / sqrt(predicted^2 + noise) beyond the campaign
  double near_without = 0, near_with = 0;    // the same on the rows within the distance the folds checked
  int near = 0;
  double far_with = 0;    // the same on the rows farther (firstUnjudged: flagged as extrapolated)
  int far = 0;
  int bad = 0, bad_flagged = 0;  // rows predicted more than 3x too low with the beyond term; of them flagged
  Cause cause = Cause::kJointScale;
  // Sum of actual^2 / (predicted^2 + noise) with the beyond term, and rows, by distance beyond the range in quarters
  // of the judged distance (the last bin: 2 or more).
  std::array<double, 9> by_distance_sum{}, by_distance_rows{};
  ExtensionTransfer transfer;
  std::string text;
};
Carried carriedBeyond(bool library, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const test::RandomDraw d = test::randomDraw(rng);
  const RobotModel model = test::robot(d.name);
  SimulationConfig sc = d.steadySc();
  const int j = 1 + static_cast<int>(u(rng) * 2);
  const Cause cause = u(rng) < 0.5 ? Cause::kCyclicTransmission : Cause::kJointScale;
  const double size_rad = (0.02 + 0.08 * u(rng)) * kPi / 180;
  std::vector<Eigen::VectorXd> qs = SimulatedCell(model, sc).randomConfigurations(700, rng);
  std::vector<double> sorted;
  for (const auto& q : qs) sorted.push_back(q[j]);
  std::sort(sorted.begin(), sorted.end());
  const bool low = u(rng) < 0.5;
  const double cut = sorted[low ? sorted.size() * 6 / 10 : sorted.size() * 4 / 10];
  const double centre = sorted[low ? sorted.size() * 3 / 10 : sorted.size() * 7 / 10];
  std::vector<bool> inside;
  for (const auto& q : qs) inside.push_back(low ? q[j] < cut : q[j] >= cut);
  if (library) {
    const SimulatedCell plain(model, sc);
    sc.hidden = scaledHiddenEffect(model, plain.trueParams(0), cause, j, size_rad, {}, qs, rng);
  }
  const SimulatedCell cell(model, sc);
  double ms = 0;
  int n_in = 0;
  for (size_t i = 0; i < qs.size(); ++i)
    if (inside[i]) ms += std::pow(qs[i][j] - centre, 4), ++n_in;
  const double curvature = size_rad / std::sqrt(ms / n_in) * (u(rng) < 0.5 ? 1 : -1);
  std::vector<Observation> rows;
  for (const auto& q : qs) {
    Eigen::VectorXd qt = q;
    if (!library) qt[j] += curvature * (q[j] - centre) * (q[j] - centre);
    rows.push_back(library ? cell.measure(q, 0.0, rng, d.kind) : cell.measurePose(cell.truePose(qt, 0.0), q, rng, d.kind));
  }
  const FittedCampaign f = fitCampaign(model, rows, qs, inside, Extension{cause, j});
  const Campaign& c = f.c;
  const ExtendedFit& fit = f.fit;
  const PredictionModel& pm = f.pm;
  Carried out;
  out.cause = cause;
  out.transfer = f.transfer;
  PredictionModel wide = pm;
  wide.beyond = out.transfer.beyond();
  const std::vector<Eigen::Vector3d> res = positionResiduals(model, fit, c.beyond, c.beyond_drivers);
  double sum0 = 0, sum1 = 0, near0 = 0, near1 = 0;
  int near = 0;
  const BeyondRange& br = out.transfer.joints.front().beyond;
  for (size_t i = 0; i < c.beyond.size(); ++i) {
    const double noise2 = 3 * pm.variance_factor_position * std::pow(c.beyond[i].sigma_position_m, 2);
    const double p0 = predictedPositionSigma(model, fit, pm, c.beyond[i].q_rad, c.beyond_drivers[i]);
    const double p1 = predictedPositionSigma(model, fit, wide, c.beyond[i].q_rad, c.beyond_drivers[i]);
    sum0 += res[i].squaredNorm() / (p0 * p0 + noise2);
    sum1 += res[i].squaredNorm() / (p1 * p1 + noise2);
    const double q = c.beyond[i].q_rad[j];
    const bool flagged = firstUnjudged(wide.beyond, c.beyond[i].q_rad) != nullptr;
    const double r1 = res[i].squaredNorm() / (p1 * p1 + noise2);
    if (br.checked_rad > 0) {
      const auto bin = static_cast<size_t>(std::min(8.0, std::floor(4 * br.beyondRad(q) / br.checked_rad)));
      out.by_distance_sum[bin] += r1;
      ++out.by_distance_rows[bin];
    }
    if (r1 > 9) ++out.bad, out.bad_flagged += flagged;
    if (flagged) out.far_with += r1, ++out.far;
    if ((q < br.lower_rad && br.lower_rad - q <= br.checked_rad) || (q > br.upper_rad && q - br.upper_rad <= br.checked_rad)) {
      near0 += res[i].squaredNorm() / (p0 * p0 + noise2);
      near1 += res[i].squaredNorm() / (p1 * p1 + noise2);
      ++near;
    }
  }
  out.far_with = out.far ? std::sqrt(out.far_with / out.far) : 0;
  out.near_without = near ? std::sqrt(near0 / near) : 0;
  out.near_with = near ? std::sqrt(near1 / near) : 0;
  out.near = near;
  out.ratio_without = std::sqrt(sum0 / c.beyond.size());
  out.ratio_with = std::sqrt(sum1 / c.beyond.size());
  char t[500];
  const JointTransfer& jt = out.transfer.joints.front();
  std::snprintf(t, sizeof t, "%s %s, joint %d, %s %.3f deg, model %s: folds %.2f -> %.2f (sigma %.3g deg, growth %d, width power %d of %d inner rows); beyond: ratio %.2f -> %.2f, %d rows within %.1f deg: %.2f -> %.2f, %d farther: %.2f; %d of %d rows over 3x flagged",
                d.name.c_str(), d.kind == MeasurementKind::kPose6D ? "6D" : "points", j + 1,
                library ? "true" : "quadratic", size_rad * 180 / kPi, causeName(cause), jt.ratio_rms_without,
                jt.ratio_rms_with, jt.beyond.sigma_at_1_rad * 180 / kPi, jt.beyond.growth, jt.width_power, jt.inner_rows, out.ratio_without, out.ratio_with, out.near, jt.beyond.checked_rad * 180 / kPi, out.near_without, out.near_with, out.far, out.far_with, out.bad_flagged,
                out.bad);
  out.text = t;
  std::printf("  %s\n", t);
  return out;
}

// Measured over 120 draws of each kind (CELLCAL_DIAGNOSIS_DRAWS=40, seeds 1-3), on the rows beyond the campaign within
// the distance the folds judged (BeyondRange::checked_rad): of the 91 partial draws whose prediction was more than
// 1.5x too low there (median 3.65x), 74 came to 1.5x or less and 80 to 2x or less with the joint's BeyondRange (median
// 1.16x); joint_scale 62 of 66 to 1.5x, cyclic_transmission 12 of 25 (a periodic term's folds often see nothing: fitted
// on less of the range, its own posterior is wide). Before the width law (JointTransfer::width_power): median 1.44x,
// 60 to 1.5x, joint_scale 52 and cyclic_transmission 8. The width law was found in 69 partial draws and 4 true ones.
// The true causes: median ratio with / without 1.00, 4 of 120 below 0.7 (3 before). On all rows beyond (farther than
// the folds judged, the error held at its value there): partial median 8.95x -> 2.29x (2.93x before), true causes
// median 0.95x (lowest 0.26x). Of the partial draws' rows beyond predicted more than 3x too low with the BeyondRange,
// 8,021 of 8,460 lie farther than the folds judged (firstUnjudged flags them). Over 295 seeds (6000-6294) of the 36
// draws this test makes: that share 0.90 or more (0.96 on average), the width law in 11-26 partial draws and 0-5 true
// ones, the partial median 3.17-4.14x without the beyond term and 0.98-1.51x with it, none failing. At 12 draws the
// share's tail reached the 0.85 asked in 2 of 200 seeds (0.83, 0.84): 36 draws are ~1.5 s more.
TEST(ExtensionTransfer, APredictionBeyondTheDataCoversWhatTheExtensionsDoThere) {
  const int draws = drawsOr(36);
  std::mt19937_64 rng(test::testSeed());
  std::vector<double> problem_without, problem_with, true_change;
  int bad = 0, bad_flagged = 0, widened[2] = {0, 0};  // draws whose sigma grew with the fitted width: partial, true
  int true_overstated = 0;  // true causes predicted below 0.4x of their error within the judged distance
  std::array<double, 9> by_distance[2][2] = {};  // [cyclic?][sum, rows], partial draws
  for (int k = 0; k < draws; ++k) {
    const Carried p = carriedBeyond(false, rng);
    bad += p.bad;
    bad_flagged += p.bad_flagged;
    for (size_t b = 0; b < 9; ++b) {
      by_distance[p.cause == Cause::kCyclicTransmission][0][b] += p.by_distance_sum[b];
      by_distance[p.cause == Cause::kCyclicTransmission][1][b] += p.by_distance_rows[b];
    }
    if (p.near > 0 && p.near_without > 1.5) {
      problem_without.push_back(p.near_without);
      problem_with.push_back(p.near_with);
    }
    const Carried t = carriedBeyond(true, rng);
    widened[0] += p.transfer.joints.front().width_power > 0;
    widened[1] += t.transfer.joints.front().width_power > 0;
    if (t.near > 0) true_change.push_back(t.near_with / t.near_without);
    if (t.near_with < 0.4) {
      ++true_overstated;
      std::printf("  a true cause overstated: %s\n", t.text.c_str());
    }
    for (const Carried* c : {&p, &t}) {
      const BeyondRange& b = c->transfer.joints.front().beyond;
      EXPECT_GT(b.checked_rad, 0) << c->text;
      // Every joint's judged range is kept, held (sigma 0) or not: rows beyond it are flagged either way.
      ASSERT_EQ(c->transfer.beyond().size(), 1u) << c->text;
      EXPECT_EQ(c->transfer.beyond().front().checked_rad, b.checked_rad) << c->text;
      EXPECT_LE(c->transfer.joints.front().ratio_rms_with, std::max(1.0, c->transfer.joints.front().ratio_rms_without) + 1e-9);
    }
  }
  using test::median;
  std::printf("  summary: %zu of %d partial draws predicted more than 1.5x too low within the checked distance (median "
              "%.2fx, with the beyond term %.2fx); true causes: median change %.2f; of the partial draws' rows beyond "
              "the campaign predicted more than 3x too low with the beyond term, %d of %d lie beyond the judged "
              "distance (flagged as extrapolated); the sigma grown with the fitted width in %d partial and %d true draws\n",
              problem_without.size(), draws, median(problem_without), median(problem_with), median(true_change),
              bad_flagged, bad, widened[0], widened[1]);
  // Where within and past the judged distance the partial draws' predictions fail: the RMS ratio by quarter of it.
  for (int cyclic = 0; cyclic < 2; ++cyclic) {
    std::string line;
    for (size_t b = 0; b < 9; ++b) {
      char t[64];
      const double n = by_distance[cyclic][1][b];
      std::snprintf(t, sizeof t, " %s%.2f (%d)", b == 8 ? ">=2: " : "", n > 0 ? std::sqrt(by_distance[cyclic][0][b] / n) : 0.0,
                    static_cast<int>(n));
      line += t;
    }
    std::printf("  partial %s, RMS ratio with the beyond term by quarter of the judged distance beyond the range:%s\n",
                cyclic ? "cyclic_transmission" : "joint_scale", line.c_str());
  }
  ASSERT_GT(bad, 0) << "the draws do not make the failure the flag is for";
  EXPECT_GE(bad_flagged, 0.85 * bad);
  ASSERT_GE(problem_without.size(), 2u) << "the draws do not make the failure the beyond term is for";
  EXPECT_GE(median(problem_without), 2.5) << "the draws do not make the failure the beyond term is for";
  EXPECT_LE(median(problem_with), 2.5);
  EXPECT_GE(median(true_change), 0.85);
  // A true cause's folds can err beyond their data (a fold's fit of a periodic term on a narrower range, its excitation
  // held): its beyond term then overstates the error, rarely. Judged over the draws, not each: one draw in 12 (a
  // random CI seed, 18289738715820366498, drew a true cyclic term whose folds erred 2.52x, predicted 0.26x of its error)
  // is the tail; more is a fault.
  EXPECT_LE(true_overstated, std::max(1, draws / 12)) << "true causes overstated by their beyond term";
  // The width law is the partial draws' (their error beyond grows with the range the cause was made to follow), not
  // the true causes' (a likelihood ratio test at 1 %).
  EXPECT_GT(widened[0], widened[1]) << "the width law is found as often for true causes as for stand-ins";
}

// A link's deflection beyond the gravity across it that the campaign saw (link_deflection's driver): the campaign
// the rows on one side of a quantile of that gravity (drawn: 60 % from below or from above), the rows beyond graded.
// The truth is a library link deflection (linear in the gravity across the link) or, outside the library, one that is
// not linear in it: quadratic (a joint that softens under load) or saturating (a play taken up at a load drawn within
// the campaign's range). Each at a size drawn like the library draws' (a joint error of 0.02-0.1 deg at the link's
// end), on a drawn robot, measurement kind, tracker placement and target offset.
struct CarriedDriver {
  bool library = false;
  int form = 0;  // 0 linear (library), 1 quadratic, 2 saturating
  double near_without = 0, near_with = 0;  // RMS actual / predicted on the rows beyond within the judged distance
  int near = 0;
  int bad = 0, bad_flagged = 0;  // rows predicted more than 3x too low with the driver term; of them flagged
  int rows = 0, far = 0;         // rows beyond the campaign; of them flagged (farther than judged)
  ExtensionTransfer transfer;
  std::string text;
};
CarriedDriver deflectionBeyond(bool library, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const test::RandomDraw d = test::randomDraw(rng);
  const RobotModel model = test::robot(d.name);
  SimulationConfig sc = d.steadySc();
  const SimulatedCell cell(model, sc);
  const Eigen::VectorXd truth = cell.trueParams(0);
  std::vector<int> beams;
  for (int j = 0; j < model.numJoints(); ++j)
    if (applicable(model, Extension{Cause::kLinkDeflection, j}, false)) beams.push_back(j);
  const int link = beams[static_cast<size_t>(u(rng) * beams.size())];
  const Extension e{Cause::kLinkDeflection, link};
  const CauseModel& cause = causeModel(Cause::kLinkDeflection);
  const std::vector<Eigen::VectorXd> qs = cell.randomConfigurations(700, rng);
  std::vector<double> x;  // the gravity across the link (g)
  for (const auto& q : qs) x.push_back(cause.rangeValue(model, truth, e, q, Drivers{}));
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const bool low = u(rng) < 0.5;
  const double cut = sorted[low ? sorted.size() * 6 / 10 : sorted.size() * 4 / 10];
  std::vector<bool> inside;
  for (double v : x) inside.push_back(low ? v < cut : v >= cut);
  const int form = library ? 0 : 1 + static_cast<int>(u(rng) * 2);  // 0 linear, 1 quadratic, 2 saturating
  // Saturating: at a load drawn within the campaign's middle half.
  const double knee = sorted[static_cast<size_t>((low ? 0.15 + 0.3 * u(rng) : 0.55 + 0.3 * u(rng)) * sorted.size())];
  double mean_in = 0;
  int n_in = 0;
  for (size_t i = 0; i < x.size(); ++i)
    if (inside[i]) mean_in += x[i], ++n_in;
  mean_in /= n_in;
  const double size_rad = (0.02 + 0.08 * u(rng)) * kPi / 180 * (u(rng) < 0.5 ? 1 : -1);
  const double length = linkLength(model, truth, link);
  test::detail::Cartesian bend;
  bend.link = link;
  const double sag_m = size_rad * length, slope_rad = (4.0 / 3.0 + u(rng) / 6.0) * sag_m / length;
  std::vector<Observation> rows;
  for (size_t i = 0; i < qs.size(); ++i) {
    // The factor on a linear deflection (whose sag is sag_m at 1 g across the link).
    const double f = form == 0 ? 1.0 : form == 1 ? x[i] / mean_in : std::min(x[i], knee) / std::max(x[i], 1e-9);
    bend.sag_m = sag_m * f;
    bend.slope_rad = slope_rad * f;
    const Pose T = bend.apply(model, truth, qs[i], forwardKinematics(model, truth, qs[i]), 0.0);
    rows.push_back(cell.measurePose(T, qs[i], rng, d.kind));
  }
  const FittedCampaign f = fitCampaign(model, rows, qs, inside, e);
  const Campaign& c = f.c;
  const ExtendedFit& fit = f.fit;
  const PredictionModel& pm = f.pm;
  CarriedDriver out;
  out.library = library;
  out.form = form;
  out.transfer = f.transfer;
  PredictionModel wide = pm;
  wide.beyond_drivers = out.transfer.beyondDrivers();
  const std::vector<Eigen::Vector3d> res = positionResiduals(model, fit, c.beyond, c.beyond_drivers);
  double near0 = 0, near1 = 0;
  int& far = out.far;
  out.rows = static_cast<int>(c.beyond.size());
  const DriverRange* range = out.transfer.drivers.empty() ? nullptr : &out.transfer.drivers.front().range;
  for (size_t i = 0; i < c.beyond.size() && range; ++i) {
    const double noise2 = 3 * pm.variance_factor_position * std::pow(c.beyond[i].sigma_position_m, 2);
    const double p0 = predictedPositionSigma(model, fit, pm, c.beyond[i].q_rad, c.beyond_drivers[i]);
    const double p1 = predictedPositionSigma(model, fit, wide, c.beyond[i].q_rad, c.beyond_drivers[i]);
    const double r1 = res[i].squaredNorm() / (p1 * p1 + noise2);
    const bool flagged =
        firstUnjudged(model, fit.params, wide.beyond_drivers, c.beyond[i].q_rad, c.beyond_drivers[i], nullptr) != nullptr;
    if (r1 > 9) ++out.bad, out.bad_flagged += flagged;
    far += flagged;
    const double v = range->value(model, fit.params, c.beyond[i].q_rad, c.beyond_drivers[i]);
    if (range->beyond(v) > 0 && range->judged(v)) {
      near0 += res[i].squaredNorm() / (p0 * p0 + noise2);
      near1 += r1;
      ++out.near;
    }
  }
  out.near_without = out.near ? std::sqrt(near0 / out.near) : 0;
  out.near_with = out.near ? std::sqrt(near1 / out.near) : 0;
  char t[600];
  const char* forms[] = {"linear (library)", "quadratic", "saturating"};
  std::snprintf(t, sizeof t, "%s %s, link %d, %s deflection %.3f deg, campaign %s %.2f g: %s; beyond: %d rows within the "
                "judged distance %.2f -> %.2f, %d farther flagged; %d of %d rows over 3x flagged",
                d.name.c_str(), d.kind == MeasurementKind::kPose6D ? "6D" : "points", link + 1, forms[form],
                size_rad * 180 / kPi, low ? "below" : "from", cut,
                range ? (range->rangeText() + ", sigma " + std::to_string(range->sigma_at_1_m * 1e3) + " mm growth " +
                         std::to_string(range->growth) + ", " + range->judgedText() + ", folds " +
                         std::to_string(out.transfer.drivers.front().ratio_rms_without) + " -> " +
                         std::to_string(out.transfer.drivers.front().ratio_rms_with)).c_str()
                      : "not measured",
                out.near, out.near_without, out.near_with, far, out.bad_flagged, out.bad);
  out.text = t;
  std::printf("  %s\n", t);
  return out;
}

// What link_deflection does beyond the gravity its data saw, measured on folds by that gravity (DriverRange).
TEST(ExtensionTransfer, APredictionBeyondALinksLoadCoversWhatItsDeflectionDoesThere) {
  const int draws = drawsOr(36);
  std::mt19937_64 rng(test::testSeed() + 35);
  std::vector<double> problem_without, problem_with, true_change, by_form[2][2];  // [quadratic, saturating][without, with]
  int bad = 0, bad_flagged = 0, beyond_rows = 0, flagged_rows = 0;
  int true_overstated = 0;  // library deflections predicted below 0.4x of their error within the judged distance
  int unflagged_draws = 0;  // non-linear draws with more than 3 rows predicted over 3x too low and not flagged
  for (int k = 0; k < draws; ++k) {
    const CarriedDriver p = deflectionBeyond(false, rng);
    const CarriedDriver t = deflectionBeyond(true, rng);
    for (const CarriedDriver* c : {&p, &t}) {
      ASSERT_EQ(c->transfer.drivers.size(), 1u) << c->text << "\n" << c->transfer.text;
      ASSERT_EQ(c->transfer.beyondDrivers().size(), 1u);
      const DriverTransfer& dt = c->transfer.drivers.front();
      EXPECT_GT(std::max(dt.range.checked_below, dt.range.checked_above), 0) << c->text;
      EXPECT_EQ(dt.range.label, "gravity across link " + std::to_string(dt.range.extension.joint + 1) + " (g)");
      EXPECT_LE(dt.ratio_rms_with, std::max(1.0, dt.ratio_rms_without) + 1e-9) << c->text;
      EXPECT_TRUE(c->transfer.not_measured.empty()) << c->transfer.text;
    }
    bad += p.bad;
    bad_flagged += p.bad_flagged;
    unflagged_draws += p.bad - p.bad_flagged > 3;
    if (p.near > 0 && p.near_without > 1.5) {
      problem_without.push_back(p.near_without);
      problem_with.push_back(p.near_with);
      by_form[p.form - 1][0].push_back(p.near_without);
      by_form[p.form - 1][1].push_back(p.near_with);
    }
    if (t.near > 0) true_change.push_back(t.near_with / t.near_without);
    if (t.near_with < 0.4) {
      ++true_overstated;
      std::printf("  a library deflection overstated: %s\n", t.text.c_str());
    }
    beyond_rows += p.rows + t.rows;
    flagged_rows += p.far + t.far;
  }
  using test::median;
  std::printf("  summary: %zu of %d non-linear draws predicted more than 1.5x too low within the judged distance "
              "(median %.2fx, with the driver term %.2fx); library deflections: median change %.2f; of the non-linear "
              "draws' rows beyond predicted more than 3x too low with the driver term, %d of %d flagged\n",
              problem_without.size(), draws, median(problem_without), median(problem_with), median(true_change),
              bad_flagged, bad);
  std::printf("  of those, quadratic %zu (median %.2fx -> %.2fx), saturating %zu (%.2fx -> %.2fx); %d of %d rows beyond "
              "the campaigns flagged as farther than judged\n", by_form[0][0].size(), median(by_form[0][0]),
              median(by_form[0][1]), by_form[1][0].size(), median(by_form[1][0]), median(by_form[1][1]), flagged_rows,
              beyond_rows);
  ASSERT_GE(problem_without.size(), static_cast<size_t>(draws) / 3) << "the draws do not make the failure the term is for";
  EXPECT_GE(median(problem_without), 1.6) << "the draws do not make the failure the driver term is for";
  EXPECT_LE(median(problem_with), 1.5);
  EXPECT_GE(median(true_change), 0.9);
  std::printf("  non-linear draws with more than 3 rows over 3x too low not flagged: %d of %d\n", unflagged_draws, draws);
  // The rows predicted over 3x too low lie farther than judged (flagged) in all but a few draws. A share of the rows
  // pooled over the draws is one draw's: a quadratic deflection whose growth-1 term falls short within the judged
  // distance left 13 of 37 such rows unflagged (CI's random seed 2825976806543871125, 12 draws), 25 of 62 at another
  // seed. Over seeds 7200-7279 of 36 draws, such draws: none at 59 seeds, one at 18, two at 2, three at 1 (none failed;
  // at 12 draws, 2 of 150 seeds failed the count of draws making the failure the term is for, 3 of 12 against 4).
  EXPECT_LE(unflagged_draws, std::max(1, draws / 9)) << bad_flagged << " of " << bad << " flagged";
  // Judged over the draws, not each, as for a joint's range above: one in 12 is the tail.
  EXPECT_LE(true_overstated, std::max(1, draws / 12)) << "library deflections overstated by their driver term";
}

// regionSplit against a plain computation: the covariance's major axis by power iteration, the median by a full sort.
TEST(RegionSplit, HalvesAlongTheLargestSpreadAtTheMedian) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g;
  for (int draw = 0; draw < 20; ++draw) {
    const int n = 9 + static_cast<int>(rng() % 300);
    const Eigen::Matrix3d R = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    const Eigen::Vector3d scale(0.2 + std::abs(g(rng)), 0.2 + std::abs(g(rng)), 0.2 + std::abs(g(rng)));
    std::vector<Observation> obs(static_cast<size_t>(n));
    for (auto& o : obs)
      o.measured_in_tracker.translation() = R * scale.cwiseProduct(Eigen::Vector3d(g(rng), g(rng), g(rng))) +
                                            Eigen::Vector3d(3, -1, 2);
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& o : obs) mean += o.measured_in_tracker.translation();
    mean /= n;
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& o : obs) {
      const Eigen::Vector3d d = o.measured_in_tracker.translation() - mean;
      C += d * d.transpose();
    }
    Eigen::Vector3d v(1, 1, 1);
    for (int it = 0; it < 2000; ++it) v = (C * v).normalized();
    std::vector<double> x;
    for (const auto& o : obs) x.push_back(v.dot(o.measured_in_tracker.translation() - mean));
    std::vector<double> sorted = x;
    std::sort(sorted.begin(), sorted.end());
    const double median = sorted[static_cast<size_t>(n / 2)];
    const std::vector<bool> side = regionSplit(obs);
    int agree = 0, flipped = 0;
    for (int i = 0; i < n; ++i) {
      const bool plain = x[static_cast<size_t>(i)] >= median;
      agree += side[static_cast<size_t>(i)] == plain;
      flipped += side[static_cast<size_t>(i)] != plain;
    }
    // The axis' sign is either way round: one half or the other is "true".
    EXPECT_TRUE(agree == n || flipped == n || std::min(agree, flipped) <= 1) << agree << " of " << n;
    const int trues = static_cast<int>(std::count(side.begin(), side.end(), true));
    EXPECT_LE(std::abs(2 * trues - n), 2) << trues << " of " << n;
  }
  EXPECT_EQ(regionSplit(std::vector<Observation>(7)), std::vector<bool>(7, false));
}

}  // namespace
}  // namespace cellcal
