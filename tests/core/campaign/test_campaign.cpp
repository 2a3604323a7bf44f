// calibrateCampaign (campaign.hpp) on measurement files drawn at random (robot, tracker placement, target offset,
// points or 6D, a hidden cause, gross errors): its split, its figures and its verdict against a plain reference
// computed here from the forward kinematics and the rules as the header states them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <cmath>
#include <optional>
#include <random>

#include "cellcal/core/campaign/campaign.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/identification/pose_plan.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "core/identification/hidden_effect.hpp"
#include "core/identification/placements.hpp"
#include "core/simulated_arm.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

using test::DrawCategory;
using test::DrawOptions;
using test::HiddenEffectData;
using test::SimulatedArm;
using test::armsToDraw;

// Plain reference: position error (mm) of every row under a geometric model, orientation error (deg) of 6D rows.
ErrorStats plainStats(const RobotModel& robot, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                      const std::vector<int>& skip = {}) {
  ErrorStats s;
  KinematicsData data(robot);
  double sum = 0, sq = 0, osum = 0, osq = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    if (std::count(skip.begin(), skip.end(), static_cast<int>(i))) continue;
    const Pose p = forwardKinematics(robot, data, params, obs[i].q_rad);
    const double e = (p.translation() - obs[i].measured_in_tracker.translation()).norm() * 1e3;
    ++s.rows;
    sum += e;
    sq += e * e;
    s.max_mm = std::max(s.max_mm, e);
    if (obs[i].kind != MeasurementKind::kPose6D) continue;
    const double a = Eigen::AngleAxisd(p.linear().transpose() * obs[i].measured_in_tracker.linear()).angle() * 180 / kPi;
    ++s.oriented;
    osum += a;
    osq += a * a;
    s.max_deg = std::max(s.max_deg, a);
  }
  s.mean_mm = sum / s.rows;
  s.rms_mm = std::sqrt(sq / s.rows);
  if (s.oriented) {
    s.mean_deg = osum / s.oriented;
    s.rms_deg = std::sqrt(osq / s.oriented);
  }
  return s;
}

void expectSame(const ErrorStats& got, const ErrorStats& want, const std::string& what) {
  EXPECT_EQ(got.rows, want.rows) << what;
  EXPECT_EQ(got.oriented, want.oriented) << what;
  EXPECT_NEAR(got.mean_mm, want.mean_mm, 1e-9 * (1 + want.mean_mm)) << what;
  EXPECT_NEAR(got.rms_mm, want.rms_mm, 1e-9 * (1 + want.rms_mm)) << what;
  EXPECT_NEAR(got.max_mm, want.max_mm, 1e-9 * (1 + want.max_mm)) << what;
  EXPECT_NEAR(got.mean_deg, want.mean_deg, 1e-6 * (1 + want.mean_deg)) << what;
  EXPECT_NEAR(got.max_deg, want.max_deg, 1e-6 * (1 + want.max_deg)) << what;
}

InputOptions inputOptions(const HiddenEffectData& h, const std::string& split) {
  InputOptions o;
  o.split = split;
  o.sigma_position_m = h.sigma_position_mm * 1e-3;
  return o;
}

TEST(Campaign, AFileIsSplitAsItsRuleSays) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 4; ++draw) {
    DrawOptions o;
    o.category = DrawCategory::kNoiseOnly;
    o.poses = 60 + static_cast<int>(rng() % 60);
    o.repeat_probability = 1;  // 10 % of the poses measured again later
    const HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    SCOPED_TRACE(h.draw.describe());
    RobotFile rf;
    rf.model = h.model;
    const auto& rows = h.file.rows;
    for (const std::string split : {"alternate", "halves", "positions"}) {
      const CampaignInput in = prepareCampaignInput("drawn.csv", rf, h.file, inputOptions(h, split));
      ASSERT_EQ(in.identification_lines.size() + in.verification_lines.size(), rows.size()) << split;
      std::vector<bool> verify(rows.size() + 2, false);
      for (int line : in.verification_lines) verify[static_cast<size_t>(line)] = true;
      if (split != "positions") {
        for (size_t i = 0; i < rows.size(); ++i)
          EXPECT_EQ(verify[static_cast<size_t>(rows[i].line)], split == "alternate" ? i % 2 == 1 : i >= rows.size() / 2)
              << split << " row " << i;
        continue;
      }
      // A row joins the first position whose first row lies within 20 mm; alternate positions verify. A pose measured
      // again lies on the side of its first visit.
      std::vector<size_t> first;
      for (size_t i = 0; i < rows.size(); ++i) {
        size_t k = 0;
        while (k < first.size() && (rows[first[k]].position_m - rows[i].position_m).norm() > 0.020) ++k;
        if (k == first.size()) first.push_back(i);
        EXPECT_EQ(verify[static_cast<size_t>(rows[i].line)], k % 2 == 1) << "positions row " << i;
        for (size_t j = 0; j < i; ++j)
          if ((rows[j].q_rad - rows[i].q_rad).norm() == 0) {
            EXPECT_EQ(verify[static_cast<size_t>(rows[j].line)], verify[static_cast<size_t>(rows[i].line)]);
          }
      }
    }
    // Too few rows: refused, the file named.
    MeasurementFile few = h.file;
    few.rows.resize(14);  // alternate: 7 to identify, 8 are needed
    try {
      prepareCampaignInput("few.csv", rf, few, inputOptions(h, "alternate"));
      ADD_FAILURE() << "14 rows accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("few.csv: too few rows (14)"), std::string::npos) << e.what();
    }
  }
}

TEST(Campaign, ItsFiguresAndVerdictAreThoseOfAPlainReference) {
  std::mt19937_64 rng(test::testSeed());
  int flagged = 0, gross = 0;
  for (int draw = 0; draw < 6; ++draw) {
    DrawOptions o;
    o.category = draw % 2 ? DrawCategory::kNoiseOnly : DrawCategory::kSingle;
    o.poses = 80 + static_cast<int>(rng() % 120);
    o.max_outlier_fraction = 0.06;
    const HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    SCOPED_TRACE(h.draw.describe());
    RobotFile rf;
    rf.model = h.model;
    CampaignProblem p;
    p.setups = {prepareCampaignInput("drawn.csv", rf, h.file, inputOptions(h, "alternate"))};
    p.provenance = {{"tool", "test"}, {"data_file", "drawn.csv"}};
    const CampaignReport r = calibrateCampaign(p);
    const CampaignInput& in = p.setups.front();
    const RobotModel& robot = in.robot;
    ASSERT_TRUE(r.converged) << r.message;
    ASSERT_FALSE(r.several_setups);
    EXPECT_EQ(r.model_label, "geometric");
    // The figures, from the forward kinematics of the start and of the fitted parameters.
    const auto& e = r.errors;
    const auto& ident = in.data.identification;
    const auto& verify = in.data.verification;
    // 'Before' is registered as 'after' is: the start is the nominal kinematics at their least-squares frames. The
    // reference fits the twelve frame parameters with Ceres' Levenberg-Marquardt from the closed-form registration.
    {
      CalibrationProblem frames{&robot, registerFrames(robot, robot.nominal, ident).params, ident, std::nullopt, {}, {}};
      frames.outliers.enabled = false;
      for (int k = 0; k < 6; ++k) {
        frames.identifiability.candidates.push_back(robot.baseParam(static_cast<FrameParam>(k)));
        frames.identifiability.candidates.push_back(robot.toolParam(static_cast<FrameParam>(k)));
      }
      const CalibrationResult ref = solveLevenbergMarquardt(frames);
      auto cost = [&](const Eigen::VectorXd& params) {
        Eigen::VectorXd res;
        stackResiduals(robot, params, ident, res, nullptr);
        return res.squaredNorm();
      };
      EXPECT_NEAR(cost(in.start), cost(ref.params), 1e-6 * cost(ref.params));
      EXPECT_LE(cost(in.start), cost(frames.initial_params));
      EXPECT_EQ(in.start.head(5 * robot.numJoints()), robot.nominal.head(5 * robot.numJoints()));
    }
    expectSame(e.identification_before, plainStats(robot, in.start, ident), "identification before");
    expectSame(e.identification_after, plainStats(robot, r.after.params, ident), "identification after");
    expectSame(e.verification_before, plainStats(robot, in.start, verify), "verification before");
    expectSame(e.verification_after, plainStats(robot, r.after.params, verify), "verification after");
    const std::vector<int>& vo = e.verification_outliers.rows;
    expectSame(e.verification_kept_before, plainStats(robot, in.start, verify, vo), "verification kept before");
    expectSame(e.verification_kept_after, plainStats(robot, r.after.params, verify, vo), "verification kept after");
    expectSame(e.identification_kept_after, plainStats(robot, r.after.params, ident, e.identification_outliers.rows),
               "identification kept after");
    // The gross errors drawn (1-5 mm) are flagged where nothing but noise is left beside them.
    if (o.category == DrawCategory::kNoiseOnly) {
      for (int row : h.outlier_verification) {
        ++gross;
        flagged += std::count(vo.begin(), vo.end(), row) > 0;
      }
      for (int row : h.outlier_identification) {
        ++gross;
        flagged += std::count(e.identification_outliers.rows.begin(), e.identification_outliers.rows.end(), row) > 0;
      }
    }
    // The verdict, by the rules campaign.hpp and unusableFit state.
    const bool worse = e.verification_kept_after.mean_mm > e.verification_kept_before.mean_mm;
    const bool extrapolates = e.verification_kept_after.max_mm > 3.0 * e.identification_kept_after.max_mm;
    EXPECT_EQ(r.unusable.empty(), !worse && !extrapolates) << r.unusable;
    EXPECT_EQ(r.exitCode(), r.unusable.empty() ? 0 : 4);
    if (r.exitCode() != 0) {
      EXPECT_NE(recommendationText(r).find("do not deploy"), std::string::npos) << recommendationText(r);
      continue;
    }
    char mean[32];
    std::snprintf(mean, sizeof mean, "%.4f mm", e.verification_kept_after.mean_mm);
    EXPECT_NE(recommendationText(r).find("deploy the geometric model: held-out mean " + std::string(mean)), std::string::npos)
        << recommendationText(r);
    // The calibration a robot file saves: the fitted kinematics, the caller's provenance first, then the figures.
    EXPECT_TRUE(r.saved_params.isApprox(r.after.params, 0));
    ASSERT_GE(r.calibration.provenance.size(), 3u);
    EXPECT_EQ(r.calibration.provenance[0], (std::pair<std::string, std::string>{"tool", "test"}));
    EXPECT_EQ(r.calibration.provenance[1].first, "data_file");
    EXPECT_EQ(r.calibration.provenance[2], (std::pair<std::string, std::string>{"rows", std::to_string(h.file.rows.size())}));
    const auto it = std::find_if(r.calibration.provenance.begin(), r.calibration.provenance.end(),
                                 [](const auto& kv) { return kv.first == "verification_mean_mm"; });
    ASSERT_NE(it, r.calibration.provenance.end());
    EXPECT_EQ(it->second + " mm", std::string(mean));
  }
  if (gross > 0) {
    EXPECT_EQ(flagged, gross) << "gross errors flagged";
  }
}

TEST(Campaign, SetUpsShareTheKinematicsAndAModelCarriedKeepsIt) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 3; ++draw) {
    DrawOptions o;
    o.category = DrawCategory::kNoiseOnly;
    o.poses = 120;
    HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    SCOPED_TRACE(h.draw.describe());
    RobotFile rf;
    rf.model = h.model;
    // One file, two labelled set-ups (the same placement: the frames of both must come out alike).
    MeasurementFile two = h.file;
    for (size_t i = 0; i < two.rows.size(); ++i) two.rows[i].setup = i < two.rows.size() / 2 ? "A" : "B";
    CampaignProblem p;
    p.setups = prepareCampaignSetups("two.csv", rf, two, inputOptions(h, "alternate"));
    ASSERT_EQ(p.setups.size(), 2u);
    EXPECT_EQ(p.setups[1].name, "two.csv [setup B]");
    const CampaignReport r = calibrateCampaign(p);
    ASSERT_TRUE(r.several_setups);
    ASSERT_TRUE(r.converged) << r.message;
    ASSERT_EQ(r.setups.size(), 2u);
    const int f0 = h.model.baseParam(FrameParam::kX);
    for (size_t s = 0; s < 2; ++s) {
      const Eigen::VectorXd& params = r.setups_fit.params[s];
      EXPECT_TRUE(params.head(f0).isApprox(r.setups_fit.params[0].head(f0), 0)) << "one kinematic model";
      EXPECT_TRUE(params.segment(f0, 12).isApprox(r.setups[s].frames, 0));
      const CampaignInput& in = p.setups[s];
      expectSame(r.setups[s].errors.verification_after, plainStats(h.model, params, in.data.verification),
                 "set-up " + std::to_string(s + 1) + " verification after");
      expectSame(r.setups[s].errors.identification_before, plainStats(h.model, in.start, in.data.identification),
                 "set-up " + std::to_string(s + 1) + " identification before");
    }
    EXPECT_LT((r.setups[0].frames.head<3>() - r.setups[1].frames.head<3>()).norm(), 2e-3) << "same placement";
    // Carried with frames only: the kinematics stay the file's; only the frames move.
    ASSERT_EQ(r.exitCode(), 0) << r.unusable;
    RobotFile carried;
    carried.model = h.model.withParams(r.saved_params);
    carried.calibration = r.calibration;
    CampaignProblem q;
    q.frames_only = true;
    q.setups = {prepareCampaignInput("again.csv", carried, h.file, inputOptions(h, "alternate"))};
    const CampaignReport c = calibrateCampaign(q);
    ASSERT_TRUE(c.converged);
    EXPECT_TRUE(c.after.params.head(f0).isApprox(r.saved_params.head(f0), 0)) << "kinematics kept";
    EXPECT_LE(c.estimated, 12u);
    for (int col : c.after.estimated) EXPECT_GE(col, f0) << "only frames estimated";
    expectSame(c.errors.verification_after, plainStats(h.model, c.after.params, q.setups[0].data.verification),
               "carried verification after");
  }
}

// A calibration carried to a new set-up (frames only) against the kinematics it started from. The robot of the second
// campaign keeps a random share of the first one's errors (-0.5 to 1.3 of them: re-mastered, repaired, or as it was)
// plus new ones, so the carried model is sometimes better than nominal, sometimes worse. Plain reference: both models
// with their frames registered on the second campaign's identification rows, judged on 400 fresh noise-free poses of
// its robot. Where they differ there by more than twice the standard error of the held-out comparison, the model
// deployed must be the better one in at least 95 % of the draws; 'before' is the nominal kinematics registered alike.
TEST(Campaign, ACarriedCalibrationWorseThanNominalIsNotDeployed) {
  const std::vector<RobotModel> robots =
      armsToDraw({"abb/irb2600_12_165.urdf", "kuka/kr10r1420.urdf", "fanuc/m10ia.urdf", "universal_robots/ur5.urdf"});
  std::mt19937_64 rng(test::testSeed());
  int judged = 0, right = 0, nominal_used = 0;
  for (int draw = 0; draw < 24; ++draw) {
    const RobotModel& file = robots[rng() % robots.size()];
    SimulatedArm arm{file, rng};
    arm.six_d = rng() % 2 == 0;
    arm.sigma_m = 0.01e-3 * (1 + arm.u01());
    // The first campaign, calibrated.
    const Eigen::VectorXd e1 = arm.jointErrors(1.0);
    RobotFile rf;
    rf.model = file;
    CampaignProblem first;
    first.setups = {prepareCampaignInput("first.csv", rf, arm.measure(arm.placed(file.nominal + e1), 120), arm.options())};
    const CampaignReport r1 = calibrateCampaign(first);
    ASSERT_EQ(r1.exitCode(), 0) << r1.unusable << r1.message;
    ASSERT_EQ(r1.calibration.nominal_params.size(), file.numParams());
    EXPECT_TRUE(r1.calibration.nominal_params.isApprox(file.nominal, 0)) << "the kinematics it started from";
    // The second campaign's robot, the first calibration carried to it.
    const double share = -0.5 + 1.8 * arm.u01();
    const Eigen::VectorXd truth2 = arm.placed(file.nominal + share * e1 + arm.jointErrors(0.3));
    RobotFile carried;
    carried.model = file.withParams(r1.saved_params);
    carried.calibration = r1.calibration;
    CampaignProblem second;
    second.frames_only = true;
    second.setups = {prepareCampaignInput("second.csv", carried, arm.measure(truth2, 60), arm.options())};
    const CampaignReport r2 = calibrateCampaign(second);
    ASSERT_TRUE(r2.converged) << r2.message;
    ASSERT_TRUE(r2.against_nominal.has_value());
    // Plain reference: both registered alike on the identification rows, judged on fresh poses of the true robot.
    const CampaignInput& in = second.setups.front();
    auto registered = [&](const Eigen::VectorXd& kinematics) {
      return refineFrames(file, registerFrames(file, kinematics, in.data.identification).params, {}, Eigen::VectorXd(),
                          in.data.identification, in.data.identification_drivers).params;
    };
    const Eigen::VectorXd pc = registered(r1.saved_params), pn = registered(file.nominal);
    expectSame(r2.errors.verification_before, plainStats(file, pn, in.data.verification), "before: nominal registered");
    KinematicsData data(file);
    auto error = [&](const Eigen::VectorXd& p, const Eigen::VectorXd& q, const Eigen::Vector3d& at) {
      return (forwardKinematics(file, data, p, q).translation() - at).norm();
    };
    double fresh_c = 0, fresh_n = 0;
    for (int k = 0; k < 400; ++k) {
      const Eigen::VectorXd q = arm.configuration();
      const Eigen::Vector3d at = forwardKinematics(file, data, truth2, q).translation();
      fresh_c += error(pc, q, at) / 400;
      fresh_n += error(pn, q, at) / 400;
    }
    std::vector<double> d;
    for (const Observation& o : in.data.verification)
      d.push_back(error(pc, o.q_rad, o.measured_in_tracker.translation()) -
                  error(pn, o.q_rad, o.measured_in_tracker.translation()));
    double m = 0, v = 0;
    for (double x : d) m += x / static_cast<double>(d.size());
    for (double x : d) v += (x - m) * (x - m) / static_cast<double>(d.size() - 1);
    const double se = std::sqrt(v / static_cast<double>(d.size()));
    const bool nominal_truly_better = fresh_n < fresh_c;
    const bool differ = std::abs(fresh_c - fresh_n) > 2 * se;
    nominal_used += r2.nominalDeployed();
    std::printf("  %-16s %-6s share %+.2f: fresh carried %.4f mm, nominal %.4f mm (held-out SE %.4f); held-out %.4f "
                "against %.4f: %s%s\n",
                file.name.c_str(), arm.six_d ? "6D" : "points", share, fresh_c * 1e3, fresh_n * 1e3, se * 1e3,
                r2.against_nominal->mean_carried_mm, r2.against_nominal->mean_nominal_mm,
                r2.nominalDeployed() ? "nominal deployed" : "carried deployed",
                !differ ? " (within 2 SE: not judged)" : r2.nominalDeployed() == nominal_truly_better ? "" : "  WRONG");
    if (differ) {
      ++judged;
      right += r2.nominalDeployed() == nominal_truly_better;
    }
    // The deployed model is the one said.
    EXPECT_TRUE(r2.after.params.head(5 * file.numJoints())
                    .isApprox((r2.nominalDeployed() ? file.nominal : r1.saved_params).head(5 * file.numJoints()), 0));
  }
  std::printf("  %d of %d judged draws right; nominal deployed in %d of 24\n", right, judged, nominal_used);
  ASSERT_GE(judged, 12);
  EXPECT_GE(right, static_cast<int>(std::ceil(0.95 * judged)));
  EXPECT_GT(nominal_used, 0);
  EXPECT_LT(nominal_used, 24);
}

// A calibration carried to rows at one tool orientation (a grid, as trackers are often run, through the nominal
// model's inverse kinematics): the rows cannot tell the target's place on the flange from the base's, so the tool
// frame is held at the robot file's value and named, not fitted to wherever the near-singular fit puts it. The
// target stays where the calibration put it: the carried model then lands the held-out rows as well as a fit of
// every frame parameter, and its tool frame is the file's. With rows at many orientations nothing is held.
TEST(Campaign, OneToolOrientationHoldsTheTargetAtTheRobotFilesPlace) {
  const std::vector<RobotModel> robots = armsToDraw({"kuka/kr10r1420.urdf", "abb/irb1600_6_12.urdf"});
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 6; ++draw) {
    const RobotModel& file = robots[rng() % robots.size()];
    SimulatedArm arm{file, rng};
    arm.six_d = rng() % 2 == 0;
    RobotFile rf;
    rf.model = file;
    const Eigen::VectorXd truth = arm.placed(file.nominal + arm.jointErrors(1.0));
    CampaignProblem first;
    first.setups = {prepareCampaignInput("first.csv", rf, arm.measure(truth, 120), arm.options())};
    const CampaignReport r1 = calibrateCampaign(first);
    ASSERT_EQ(r1.exitCode(), 0) << r1.unusable << r1.message;
    // The tracker moved; the robot and its target as they were. Rows at one flange orientation.
    Eigen::VectorXd moved = arm.placed(truth);
    moved.segment<6>(file.toolParam(FrameParam::kX)) = truth.segment<6>(file.toolParam(FrameParam::kX));
    KinematicsData data(file);
    Eigen::VectorXd seed_q = arm.configuration();
    const Pose centre = forwardKinematics(file, data, file.nominal, seed_q);
    MeasurementFile grid;
    for (int k = 0; k < 200 && grid.rows.size() < 80; ++k) {
      Pose target = centre;
      target.translation() += 0.4 * Eigen::Vector3d(arm.u01() - 0.5, arm.u01() - 0.5, arm.u01() - 0.5);
      const IkResult ik = solveInverseKinematics(file, file.nominal, target, seed_q);
      if (!ik.ok()) continue;
      seed_q = ik.q_rad;
      const Pose T = forwardKinematics(file, data, moved, ik.q_rad);
      MeasurementRow row;
      row.line = static_cast<int>(grid.rows.size()) + 2;
      row.q_rad = ik.q_rad;
      row.position_m = T.translation() + arm.sigma_m * Eigen::Vector3d(arm.g(), arm.g(), arm.g());
      if (arm.six_d)
        row.orientation = Eigen::Quaterniond(expSO3(arm.sigma_rad * Eigen::Vector3d(arm.g(), arm.g(), arm.g())) * T.linear());
      grid.rows.push_back(row);
    }
    if (grid.rows.size() < 40) continue;  // the grid not reached from this configuration
    RobotFile carried;
    carried.model = file.withParams(r1.saved_params);
    carried.calibration = r1.calibration;
    CampaignProblem second;
    second.frames_only = true;
    second.setups = {prepareCampaignInput("grid.csv", carried, grid, arm.options())};
    const CampaignReport r2 = calibrateCampaign(second);
    ASSERT_TRUE(r2.converged) << r2.message;
    std::string held;
    for (const auto& [c, sigma] : r2.frames_held) held += " " + file.paramNameHuman(c);
    const int t = file.toolParam(FrameParam::kX);
    const double tool_move_mm = (r2.after.params.segment<3>(t) - r1.saved_params.segment<3>(t)).norm() * 1e3;
    std::printf("  %-16s %-6s one orientation, %zu rows: held%s; the target moved %.4f mm from the file's; held-out "
                "%.4f mm\n",
                file.name.c_str(), arm.six_d ? "6D" : "points", grid.rows.size(), held.c_str(), tool_move_mm,
                r2.errors.verification_kept_after.mean_mm);
    // The translation of the target is held (the rows cannot pin it), and stays the file's.
    for (int k = 0; k < 3; ++k) {
      const int c = t + k;
      EXPECT_TRUE(std::any_of(r2.frames_held.begin(), r2.frames_held.end(), [&](const auto& h) { return h.first == c; }))
          << file.paramNameHuman(c) << " not held";
      EXPECT_FALSE(std::count(r2.after.estimated.begin(), r2.after.estimated.end(), c)) << file.paramNameHuman(c);
    }
    EXPECT_LT(tool_move_mm, 1e-9);
    // And the carried model still lands these rows at the readings' level: the base took the move.
    EXPECT_LT(r2.errors.verification_kept_after.mean_mm, 4 * arm.sigma_m * 1e3 * std::sqrt(3.0)) << held;
    // Rows at many orientations pin the tool: nothing held.
    CampaignProblem spread;
    spread.frames_only = true;
    spread.setups = {prepareCampaignInput("spread.csv", carried, arm.measure(moved, 80), arm.options())};
    const CampaignReport r3 = calibrateCampaign(spread);
    EXPECT_TRUE(r3.frames_held.empty()) << file.name;
  }
}

// A fit at the readings' noise converges and is used: arms of the robot files and of ../shared's URDFs, points or 6D,
// every joint parameter moved, 0.016 mm of noise, 150 rows. The solver's convergence must not hang on directions the
// data barely see.
TEST(Campaign, AFitAtTheNoiseFloorConverges) {
  const std::vector<RobotModel> robots =
      armsToDraw({"kuka/kr10r1420.urdf", "kuka/kr6r900_2.urdf", "abb/irb1600_6_12.urdf", "fanuc/lrmate200ic.urdf",
                  "staubli/tx60l.urdf", "universal_robots/ur10e.urdf"});
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 12; ++draw) {
    const RobotModel& file = robots[rng() % robots.size()];
    SimulatedArm arm{file, rng};
    arm.six_d = rng() % 3 == 0;
    arm.sigma_m = 0.016e-3;
    arm.span = 0.1 + 0.7 * arm.u01();
    RobotFile rf;
    rf.model = file;
    const Eigen::VectorXd truth = arm.placed(file.nominal + arm.jointErrors(1.0));
    for (const CampaignSolver solver : {CampaignSolver::kGaussNewton, CampaignSolver::kLevenbergMarquardt}) {
      CampaignProblem p;
      p.solver = solver;
      p.setups = {prepareCampaignInput("floor.csv", rf, arm.measure(truth, 150), arm.options())};
      const CampaignReport r = calibrateCampaign(p);
      std::printf("  %-16s %-6s span %.2f %s: %s after %d iterations (%s), held-out %.4f mm, cost %.6f\n", file.name.c_str(),
                  arm.six_d ? "6D" : "points", arm.span, solver == CampaignSolver::kGaussNewton ? "GN" : "LM",
                  r.converged ? "converged" : "NOT converged", r.iterations, r.message.c_str(),
                  r.errors.verification_kept_after.mean_mm, r.geometric.final_cost_per_observation);
      EXPECT_TRUE(r.converged) << file.name << ": " << r.message;
      EXPECT_EQ(r.exitCode(), 0) << file.name << ": " << r.unusable;
    }
  }
}

// Issue #35's UR5 case (the two tests below): a grid at one tool orientation (test::gridAtOneOrientation, 7^3 target
// positions, at least 150 reached) on a drawn placement of `file` (an SMR near the flange axis, or a target anywhere),
// points or 6D, and three joints each with an error of 0.02-0.1 deg RMS over the joint's range that is either cyclic
// (cyclic_transmission's form: true) or quadratic in the angle from the grid's middle (outside the library), the same
// robot with the tracker moved beside it. problem(): the grid's rows calibrated with a cyclic_transmission of each
// of the three joints.
// sin q, cos q, sin 2q, cos 2q: a cyclic error's form (its harmonics' weights).
Eigen::Vector4d harmonicBasis(double q) { return {std::sin(q), std::cos(q), std::sin(2 * q), std::cos(2 * q)}; }

struct GridCase {
  struct JointError {
    int j;
    bool cyclic;
    Eigen::Vector4d harmonics;
    double centre, curvature;
  };
  RobotModel file;
  std::optional<SimulatedCell> cell, moved;
  MeasurementKind kind = MeasurementKind::kPosition3D;
  std::vector<Eigen::VectorXd> grid;
  std::vector<int> joints;
  std::vector<JointError> errors;
  std::string what;
  MeasurementFile campaign_rows;
  bool library() const {  // every error of the cyclic form the model names
    return std::all_of(errors.begin(), errors.end(), [](const JointError& e) { return e.cyclic; });
  }
  // The joints the real robot stands at when its controller reads q.
  Eigen::VectorXd trueJoints(const Eigen::VectorXd& q) const {
    Eigen::VectorXd qt = q;
    for (const JointError& e : errors) {
      const double v = q[e.j];
      qt[e.j] += e.cyclic ? e.harmonics.dot(harmonicBasis(v)) : e.curvature * (v - e.centre) * (v - e.centre);
    }
    return qt;
  }
  MeasurementRow measure(const SimulatedCell& c, const Eigen::VectorXd& q, std::mt19937_64& rng) const {
    return test::measuredRow(q, c.measurePose(c.truePose(trueJoints(q), 0.0), q, rng, kind));
  }
  CampaignProblem problem() const {
    RobotFile rf;
    rf.model = file;
    CampaignProblem p;
    p.setups = {prepareCampaignInput("grid.csv", rf, campaign_rows, InputOptions{})};
    p.model = CampaignModel::kNamed;
    for (int j : joints) p.extensions.push_back(Extension{Cause::kCyclicTransmission, j});
    p.identifiability.prior_sigma = plausibleDeviation(file);
    return p;
  }
};
// False where the grid is not reached from the drawn placement (another draw). `part_of_range`: in place of the grid,
// 300 random configurations with joint 2 or 3 (drawn) on the lower or upper 60 % of its range (drawn).
bool drawGridCase(const RobotModel& file, std::mt19937_64& rng, GridCase* g, bool part_of_range = false) {
  std::uniform_real_distribution<double> u(0, 1);
  g->file = file;
  SimulationConfig sc = test::randomPlacement(rng);
  if (u(rng) < 0.5) test::nearAxisTarget(sc, rng);
  g->kind = u(rng) < 0.5 ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  g->cell.emplace(file, sc);
  g->moved.emplace(file, test::trackerMoved(sc, rng));
  if (part_of_range) {
    const int j = 1 + static_cast<int>(2 * u(rng));
    const JointLimits& lim = file.limits[static_cast<size_t>(j)];
    const bool low = u(rng) < 0.5;
    const double cut = lim.lower_rad + (low ? 0.6 : 0.4) * (lim.upper_rad - lim.lower_rad);
    g->grid.clear();
    for (const auto& q : g->cell->randomConfigurations(600, rng))
      if ((low ? q[j] < cut : q[j] > cut) && g->grid.size() < 300) g->grid.push_back(q);
  } else {
    g->grid = test::gridAtOneOrientation(*g->cell, 7, rng);
  }
  if (g->grid.size() < 150) return false;
  // Three joints and their errors.
  g->joints = {0, 1, 2, 3, 4, 5};
  std::shuffle(g->joints.begin(), g->joints.end(), rng);
  g->joints.resize(3);
  std::sort(g->joints.begin(), g->joints.end());
  g->what = file.name + (g->kind == MeasurementKind::kPose6D ? " 6D" : " points") +
            (part_of_range ? ", campaign " : ", grid ") + std::to_string(g->grid.size()) + ":";
  for (int j : g->joints) {
    GridCase::JointError e{j, u(rng) < 0.5, Eigen::Vector4d::Zero(), 0, 0};
    const double size_rad = (0.02 + 0.08 * u(rng)) * kPi / 180;
    std::vector<double> x;
    for (const auto& q : g->grid) x.push_back(q[j]);
    std::sort(x.begin(), x.end());
    e.centre = x[x.size() / 2];
    // The size is the RMS over the joint's whole range (a grid may move a joint by a degree: a size over the grid
    // alone would make a quadratic of tens of degrees elsewhere).
    double ms = 0;
    for (int k = 0; k < 4; ++k) e.harmonics[k] = 2 * u(rng) - 1;
    const JointLimits& lim = file.limits[static_cast<size_t>(j)];
    for (int k = 0; k <= 200; ++k) {
      const double v = lim.lower_rad + (lim.upper_rad - lim.lower_rad) * k / 200.0;
      ms += e.cyclic ? std::pow(e.harmonics.dot(harmonicBasis(v)), 2) : std::pow(v - e.centre, 4);
    }
    const double rms = std::sqrt(ms / 201.0);
    if (e.cyclic) e.harmonics *= size_rad / rms;
    e.curvature = (u(rng) < 0.5 ? 1 : -1) * size_rad / rms;
    g->errors.push_back(e);
    char t[120];
    std::snprintf(t, sizeof t, " joint %d %s %.3f deg (over its range; %s %.0f-%.0f deg)", j + 1,
                  e.cyclic ? "cyclic" : "quadratic", size_rad * 180 / kPi, part_of_range ? "campaign" : "grid",
                  x.front() * 180 / kPi, x.back() * 180 / kPi);
    g->what += t;
  }
  for (const auto& q : g->grid) g->campaign_rows.rows.push_back(g->measure(*g->cell, q, rng));
  return true;
}

// Issue #35's UR5 case, simulated: a model with three cyclic terms identified on a grid at one tool orientation and
// carried (`calibrate --frames-only`) to 20 other poses, its frames registered again on 10 of them, predicts its error
// on the other 10. On the real UR5 it predicted 1.40x too low, before a calibration saved what its extensions do
// beyond their data. Drawn: the robot (TX60, UR10, the UR5 from its URDF where ../shared has it), placements, the
// target (an SMR near the flange axis, or anywhere), points or 6D, the grid, three joints each with an error of 0.02-0.1
// deg RMS over the joint's range that is either cyclic (the named cause, true) or quadratic in the angle from the
// grid's middle (outside the library, which the cyclic term follows on the grid and only partly beyond), the other
// poses random configurations of the same robot with the tracker moved. The verification rows' RMS of actual /
// predicted (the
// campaign's figure, computed again here) with the file's beyond_data and without it, the model carried as it is
// (--keep-extensions) and as calibrate chooses (the extensions or the file's geometric calibration), and on the rows
// not flagged as farther than the folds judged.
TEST(Campaign, AModelWithThreeCyclicTermsCarriedToOtherPosesPredictsItsError) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0, 1);
  const std::vector<RobotModel> robots = test::robotsWithUr5();
  const int want = std::getenv("CELLCAL_DIAGNOSIS_DRAWS") ? std::atoi(std::getenv("CELLCAL_DIAGNOSIS_DRAWS")) : 6;
  // [stripped + keep, full + keep, full as chosen]: sums of ratio^2 and rows; the same on rows not flagged.
  double sq[3] = {0, 0, 0}, sq_kept[3] = {0, 0, 0};
  int rows[3] = {0, 0, 0}, rows_kept[3] = {0, 0, 0};
  std::vector<double> per_draw[3];
  int draws = 0;
  for (int trial = 0; trial < 10 * want && draws < want; ++trial) {
    GridCase g;
    if (!drawGridCase(robots[static_cast<size_t>(trial) % robots.size()], rng, &g)) continue;
    const RobotModel& file = g.file;
    const std::string& what = g.what;
    MeasurementFile other_rows;
    for (const auto& q : g.moved->randomConfigurations(20, rng)) other_rows.rows.push_back(g.measure(*g.moved, q, rng));
    InputOptions io;
    const CampaignReport r = calibrateCampaign(g.problem());
    if (r.exitCode() != 0) {
      std::printf("  %s: the campaign is not deployed (exit %d): %s\n", what.c_str(), r.exitCode(), recommendationText(r).c_str());
      continue;
    }
    ++draws;
    RobotFile carried;
    carried.model = file.withParams(r.saved_params);
    carried.calibration = r.calibration;
    RobotFile stripped = carried;
    stripped.calibration->beyond_data.clear();
    stripped.calibration->beyond_drivers.clear();
    std::string line;
    for (int w = 0; w < 3; ++w) {
      CampaignProblem q;
      q.frames_only = true;
      q.keep_extensions = w < 2;
      q.identifiability.prior_sigma = plausibleDeviation(file);
      q.setups = {prepareCampaignInput("other.csv", w == 0 ? stripped : carried, other_rows, io)};
      const CampaignReport c = calibrateCampaign(q);
      ASSERT_TRUE(c.converged) << what;
      const CampaignInput& in = q.setups.front();
      const RobotModel& robot = in.robot;
      const std::vector<Observation>& verify = in.data.verification;
      // The campaign's figure again: actual over sqrt(predicted^2 + noise^2), RMS over the verification rows.
      KinematicsData data(robot);
      double draw_sq = 0;
      int flagged = 0;
      const std::vector<int>& gross = c.errors.verification_outliers.rows;  // judged without them, as the campaign
      int judged = 0;
      for (size_t i = 0; i < verify.size(); ++i) {
        if (std::count(gross.begin(), gross.end(), static_cast<int>(i))) continue;
        ++judged;
        const Drivers& dr = in.data.verification_drivers[i];
        const Eigen::VectorXd params =
            extendedParams(robot, c.after.params, c.after.extensions, c.after.extension_params, verify[i].q_rad, dr);
        const double actual = (forwardKinematics(robot, data, params, verify[i].q_rad).translation() -
                               verify[i].measured_in_tracker.translation()).norm();
        const double s = predictedPositionSigma(robot, c.after, c.prediction, verify[i].q_rad, dr);
        const double noise2 = 3.0 * c.prediction.variance_factor_position * std::pow(verify[i].sigma_position_m, 2);
        const double r2 = actual * actual / (s * s + noise2);
        draw_sq += r2;
        const bool far = firstUnjudged(c.prediction.beyond, verify[i].q_rad) != nullptr;
        flagged += far;
        if (!far) sq_kept[w] += r2, ++rows_kept[w];
      }
      const double ratio = std::sqrt(draw_sq / judged);
      EXPECT_NEAR(ratio, c.check.ratio_rms, 1e-9 * std::max(1.0, ratio)) << what;
      EXPECT_EQ(flagged, c.check.beyond_checked) << what;
      if (w == 0) {
        EXPECT_EQ(flagged, 0) << what;
      }
      sq[w] += draw_sq;
      rows[w] += judged;
      per_draw[w].push_back(ratio);
      char t[160];
      std::snprintf(t, sizeof t, " %s %.2f (%d of %d flagged%s)",
                    w == 0 ? "without beyond_data" : w == 1 ? "; with it" : "; as chosen", ratio, flagged, judged,
                    w == 2 ? (c.carried && !c.carried->extensions_transfer ? ", geometric" : ", extended") : "");
      line += t;
    }
    std::printf("  %s\n    actual / predicted:%s\n", what.c_str(), line.c_str());
  }
  ASSERT_GE(draws, want / 2) << "the grids were not reached";
  using test::median;
  std::printf("  summary: %d draws, RMS of actual / predicted on the other poses' verification rows: without "
              "beyond_data %.2f (median of draws %.2f), with it %.2f (%.2f; %.2f on the %d of %d rows not flagged), as "
              "calibrate chooses %.2f (%.2f; %.2f on %d of %d)\n",
              draws, std::sqrt(sq[0] / rows[0]), median(per_draw[0]), std::sqrt(sq[1] / rows[1]), median(per_draw[1]),
              rows_kept[1] ? std::sqrt(sq_kept[1] / rows_kept[1]) : 0.0, rows_kept[1], rows[1], std::sqrt(sq[2] / rows[2]),
              median(per_draw[2]), rows_kept[2] ? std::sqrt(sq_kept[2] / rows_kept[2]) : 0.0, rows_kept[2], rows[2]);
  // Where the folds judged the extensions, the carried prediction holds: over 30 seeds of 6 draws the RMS on the rows
  // not flagged was 0.41-1.20 kept and 0.51-1.11 as chosen, where there were 10 or more of them (0.62-1.02 and
  // 0.52-1.04 over 16 seeds of 12 draws); the rows farther (beyond the range or deep in its gaps) are said
  // (beyond_checked), not covered. Before the ranges kept their gaps: 0.48-1.48 kept, one draw 2.09x too low with none
  // of its rows flagged.
  for (int w = 1; w < 3; ++w) {
    if (rows_kept[w] < 10) continue;
    const double kept = std::sqrt(sq_kept[w] / rows_kept[w]);
    EXPECT_GT(kept, 0.25) << (w == 1 ? "kept" : "as chosen");
    EXPECT_LT(kept, 1.8) << (w == 1 ? "kept" : "as chosen");
  }
}

// A calibrated robot file compensating targets as the compensation publisher does (the file saved and read back,
// attachRobotFile), judged by where the true robot lands at the commanded joints. The campaign: 300 random
// configurations with joint 2 or 3 on 60 % of its range, three joints with an error each as in the UR5 case (cyclic or
// quadratic); the targets: random configurations of the whole workspace, as the real robot reaches them. Where the
// correction is applied, the landing error against the predicted sigma (the file's kinematic covariance given its
// held columns, and what the extensions may do beyond their data); where the extensions were never judged the target
// is passed through, and what that costs is measured against the extended model applied anyway (the guard off).
TEST(Campaign, ACalibratedRobotFileCompensatesWithinItsPredictedError) {
  std::mt19937_64 rng(test::testSeed());
  const std::vector<RobotModel> robots = test::robotsWithUr5();
  // 12 draws: a draw's actual / predicted runs from 0.1 to 3.1 (560 draws over seeds 101-107), and the RMS of 4
  // draws left [0.5, 2] in 2 of 60 random seeds (8438422067435700231: 0.47; 2032469186469443774: 2.38); of 12, in
  // none of 200,000 resamples of those draws.
  const int want = std::getenv("CELLCAL_DIAGNOSIS_DRAWS") ? std::atoi(std::getenv("CELLCAL_DIAGNOSIS_DRAWS")) : 12;
  double sq_applied = 0, sq_ratio = 0, sq_before = 0, sq_ext = 0, sq_pass = 0;
  int applied = 0, unjudged = 0, other = 0, draws = 0;
  double sq_library = 0;  // actual^2 / predicted^2 where every error is cyclic (the library's form)
  int library = 0;
  std::vector<double> sigma_applied, sigma_marginal;  // predicted sigma where applied; from the marginal covariance
  std::vector<double> draw_ratio;
  for (int trial = 0; trial < 10 * want && draws < want; ++trial) {
    GridCase g;
    if (!drawGridCase(robots[static_cast<size_t>(trial) % robots.size()], rng, &g, true)) continue;
    const CampaignReport r = calibrateCampaign(g.problem());
    if (r.exitCode() != 0) continue;
    ++draws;
    const RobotFile file =
        parseRobotFile(robotFileText(g.file.withParams(r.saved_params), &r.calibration, "test"), "campaign.yaml");
    IdentifiedModel model(calibratedModel(file));
    attachRobotFile(file, model);
    // For the record, the file's marginal covariance of the same kinematic columns (what calibratedModel took before
    // it took them given the held ones): a plain search of the file's columns.
    std::vector<int> at;
    for (int c : model.estimated)
      at.push_back(static_cast<int>(std::find(file.calibration->columns.begin(), file.calibration->columns.end(), c) -
                                    file.calibration->columns.begin()));
    const Eigen::MatrixXd marginal = file.calibration->covariance(at, at);
    KinematicsData kd(g.file);
    // The controller's model: the nominal kinematics with the frames the campaign registered.
    RobotModel controller = g.file;
    const int f0 = controller.baseParam(FrameParam::kX);
    controller.nominal.tail(controller.numParams() - f0) = r.saved_params.tail(controller.numParams() - f0);
    CompensationSettings guarded;
    guarded.max_correction_m = 1;
    guarded.max_correction_rad = 1;
    ASSERT_GT(guarded.max_predicted_sigma_m, 0);
    CompensationSettings off = guarded;
    off.max_predicted_sigma_m = 0;
    auto landing = [&](const Eigen::VectorXd& q) -> Eigen::Vector3d {
      return g.cell->truePose(g.trueJoints(q), 0.0).translation();
    };
    double draw_sq = 0;
    int draw_n = 0, draw_unjudged = 0;
    for (const auto& q0 : g.cell->randomConfigurations(40, rng)) {
      const Pose desired = g.cell->truePose(g.trueJoints(q0), 0.0);
      const CompensationResult c = compensate(controller, model, desired, q0, guarded);
      // Uncorrected: the controller's own joints for the target.
      const IkResult pass = solveInverseKinematics(controller, controller.nominal, desired, q0);
      if (!pass.ok()) continue;  // at a joint limit: the controller does not reach it either
      const double uncorrected2 = (landing(pass.q_rad) - desired.translation()).squaredNorm();
      if (c.outcome == CompensationOutcome::kApplied) {
        const double e2 = (landing(c.q_rad) - desired.translation()).squaredNorm();
        ASSERT_TRUE(std::isfinite(c.predicted_sigma_position_m) && c.predicted_sigma_position_m > 0) << g.what;
        sq_applied += e2;
        sq_before += uncorrected2;
        sq_ratio += e2 / std::pow(c.predicted_sigma_position_m, 2);
        draw_sq += e2 / std::pow(c.predicted_sigma_position_m, 2);
        if (g.library()) sq_library += e2 / std::pow(c.predicted_sigma_position_m, 2), ++library;
        sigma_marginal.push_back(kinematicPositionSigma(g.file, kd, model.params, model.estimated, marginal, c.q_rad));
        sigma_applied.push_back(c.predicted_sigma_position_m);
        ++applied;
        ++draw_n;
      } else if (c.outcome == CompensationOutcome::kNeverJudged) {
        const CompensationResult e = compensate(controller, model, desired, q0, off);
        ASSERT_TRUE(e.applied) << describe(e);
        EXPECT_TRUE(c.corrected_in_tracker.isApprox(desired, 0)) << "passed through";
        sq_ext += (landing(e.q_rad) - desired.translation()).squaredNorm();
        sq_pass += uncorrected2;
        ++unjudged;
        ++draw_unjudged;
      } else {
        ++other;
        std::printf("    %s: %s\n", outcomeName(c.outcome), describe(c).c_str());
      }
    }
    if (draw_n) draw_ratio.push_back(std::sqrt(draw_sq / draw_n));
    std::printf("  %s\n    %d targets corrected (actual / predicted %.2f), %d where the extensions were never judged\n",
                g.what.c_str(), draw_n, draw_n ? std::sqrt(draw_sq / draw_n) : 0.0, draw_unjudged);
  }
  ASSERT_GE(draws, want / 2) << "the campaigns were not deployed";
  auto rms_mm = [](double sq, int n) { return n ? std::sqrt(sq / n) * 1e3 : 0.0; };
  std::printf("  summary: %d draws; %d targets corrected: RMS %.4f mm (uncorrected %.4f mm), actual / predicted RMS %.2f "
              "(median of draws %.2f; %.2f on the %d targets of draws whose errors are all cyclic); %d passed through "
              "where the extensions were never judged: uncorrected %.4f mm, the extended model applied anyway %.4f mm; "
              "%d otherwise; predicted sigma median %.4f mm (from the file's marginal covariance %.4f mm)\n",
              draws, applied, rms_mm(sq_applied, applied), rms_mm(sq_before, applied),
              applied ? std::sqrt(sq_ratio / applied) : 0.0, test::median(draw_ratio),
              library ? std::sqrt(sq_library / library) : 0.0, library, unjudged, rms_mm(sq_pass, unjudged),
              rms_mm(sq_ext, unjudged), other, test::median(sigma_applied) * 1e3, test::median(sigma_marginal) * 1e3);
  ASSERT_GE(applied, 15 * draws) << "the guard refused what the campaign covers";
  // The predicted sigma is the error's size where the correction is applied: the RMS of actual / predicted was
  // 0.92-1.61 over seeds 1-8 of 6 draws and 0.63-1.58 over seeds 17-56 of 4 (the errors outside the library, a
  // cyclic term standing for a quadratic, make the upper ones). From the file's marginal covariance (before
  // calibratedModel took it given the held columns) the predicted sigma would be 6.8-7.0 mm (median per seed, seeds
  // 1-8, printed) against 0.009-0.013 mm, and the ratio about 0.002.
  const double ratio = std::sqrt(sq_ratio / applied);
  EXPECT_LT(ratio, 2.0) << "the predicted sigma understates the error where the correction is applied";
  EXPECT_GT(ratio, 0.5) << "the predicted sigma overstates the error where the correction is applied";
  EXPECT_LT(rms_mm(sq_applied, applied), 0.5 * rms_mm(sq_before, applied));
}

// Where compensation passes a target through because the extensions were never judged there, the remedy is to
// measure there. A random-pose campaign of a joint on part of its range, as above; the robot program is 40 random
// configurations over the workspace, its targets the poses the controller commands there (compensateProgram, the
// controller the nominal kinematics with the campaign's frames). The configurations passed through as unjudged are
// measured, as the campaign's rows were, added to its rows and calibrated again, three ways side by side: each target
// alone; each with 5 configurations within 5 deg of its joints (configurationsAround: `plan cover`'s default); and
// those rows calibrated with a residual map (`calibrate --residual-map`, what `plan cover` says to do with them).
// The same program compensated with each new file: those targets are now corrected, the true robot landing much
// closer than uncorrected, and the program loses none it corrected. Without the map their predicted sigma is printed,
// not judged: where a periodic term stands for an error that grows, the fit does not follow the error at the new edge
// of its data and its posterior does not say so. The map learns what the fit leaves at those rows and its variance
// says what it does not know: with it the predicted sigma holds there (see docs/planning.md for the figures).
TEST(Campaign, MeasuringWhereCompensationPassedThroughBringsThoseTargetsIn) {
  std::mt19937_64 rng(test::testSeed());
  const std::vector<RobotModel> robots = test::robotsWithUr5();
  const int want = std::getenv("CELLCAL_DIAGNOSIS_DRAWS") ? std::atoi(std::getenv("CELLCAL_DIAGNOSIS_DRAWS")) : 6;
  constexpr int kAround = 5;
  const double around_rad = 5 * kPi / 180;
  // [0]: each target alone, [1]: with the configurations around it, [2]: those calibrated with a residual map, [3]:
  // the same with the targets corrected beyond the extensions' data measured too (`plan cover --beyond-data`).
  constexpr int kWays = 4;
  const char* const way_name[kWays] = {"alone", "with 5 around", "with 5 around and the map",
                                       "and those beyond the data too"};
  int draws = 0, before = 0, applied_before = 0, now_applied[kWays] = {}, still_unjudged[kWays] = {},
      now_refused[kWays] = {}, program_applied[kWays] = {};
  double sq_after[kWays] = {}, sq_uncorrected[kWays] = {}, sq_ratio[kWays] = {};
  // The program's targets corrected both with 5 around each and with the map: actual^2 / predicted^2, sums.
  double sq_program_ratio[2] = {0, 0};
  int program_both = 0;
  // With the map, by whether the targets were identification rows [0] or verification rows [1].
  double map_sq[2] = {0, 0};
  int map_n[2] = {0, 0};
  // The targets corrected beyond the extensions' data before measuring, where still corrected: actual^2 / predicted^2
  // before, with the map (ways 2 and 3).
  double beyond_sq[3] = {0, 0, 0};
  int beyond_n = 0;
  // Per draw: actual / predicted RMS at the never-judged targets with the map (way 2), at the targets corrected
  // beyond the data with them measured too (way 3).
  std::vector<double> draw_map, draw_beyond_measured;
  for (int trial = 0; trial < 10 * want && draws < want; ++trial) {
    GridCase g;
    if (!drawGridCase(robots[static_cast<size_t>(trial) % robots.size()], rng, &g, true)) continue;
    const std::vector<Eigen::VectorXd> program = g.cell->randomConfigurations(40, rng);
    CompensationSettings settings;
    settings.max_correction_m = 1;
    settings.max_correction_rad = 1;
    // A campaign's rows calibrated, saved and read back, and the program compensated with the file.
    auto deploy = [&](const MeasurementFile& rows, bool residual_map, RobotModel* controller, ProgramCompensation* pc) {
      GridCase c = g;
      c.campaign_rows = rows;
      CampaignProblem problem = c.problem();
      problem.residual_map = residual_map;
      const CampaignReport r = calibrateCampaign(problem);
      if (r.exitCode() != 0) return false;
      const RobotFile file =
          parseRobotFile(robotFileText(g.file.withParams(r.saved_params), &r.calibration, "test"), "campaign.yaml");
      IdentifiedModel model(calibratedModel(file));
      attachRobotFile(file, model);
      *controller = g.file;
      const int f0 = g.file.baseParam(FrameParam::kX);
      controller->nominal.tail(g.file.numParams() - f0) = r.saved_params.tail(g.file.numParams() - f0);
      *pc = compensateProgram(*controller, model, program, settings);
      return true;
    };
    RobotModel controller0;
    ProgramCompensation pc0;
    if (!deploy(g.campaign_rows, false, &controller0, &pc0)) continue;
    std::vector<int> unjudged;
    for (size_t i = 0; i < program.size(); ++i)
      if (!pc0.results[i].unjudged.empty()) unjudged.push_back(static_cast<int>(i));
    if (unjudged.empty()) continue;  // a draw counts where there is something to measure
    MeasurementFile rows[2] = {g.campaign_rows, g.campaign_rows};
    for (int i : unjudged) {
      const Eigen::VectorXd& q = program[static_cast<size_t>(i)];
      const MeasurementRow at = g.measure(*g.cell, q, rng);
      rows[0].rows.push_back(at);
      rows[1].rows.push_back(at);
      for (const auto& near : configurationsAround(g.file, g.file.nominal, q, kAround, around_rad, std::nullopt, rng))
        rows[1].rows.push_back(g.measure(*g.cell, near, rng));
    }
    // The alternate split identifies even rows: each target and the 5 around it are 6 rows, so the targets are all
    // identification rows or all verification rows, as the campaign's own rows are even or odd in number. Drawn: the
    // map's campaign one row shorter (the targets verify; the map learns them from the rows around).
    const bool targets_verify = std::uniform_real_distribution<double>(0, 1)(rng) < 0.5;
    MeasurementFile map_rows = rows[1];
    if ((g.campaign_rows.rows.size() % 2 == 1) != targets_verify) map_rows.rows.erase(map_rows.rows.begin());
    MeasurementFile beyond_rows = map_rows;
    std::vector<int> beyond;
    for (size_t i = 0; i < program.size(); ++i) {
      if (!pc0.results[i].applied || !pc0.results[i].beyond_data) continue;
      beyond.push_back(static_cast<int>(i));
      beyond_rows.rows.push_back(g.measure(*g.cell, program[i], rng));
      for (const auto& near : configurationsAround(g.file, g.file.nominal, program[i], kAround, around_rad, std::nullopt, rng))
        beyond_rows.rows.push_back(g.measure(*g.cell, near, rng));
    }
    RobotModel controller[kWays];
    ProgramCompensation pc[kWays];
    if (!deploy(rows[0], false, &controller[0], &pc[0]) || !deploy(rows[1], false, &controller[1], &pc[1]) ||
        !deploy(map_rows, true, &controller[2], &pc[2]) || !deploy(beyond_rows, true, &controller[3], &pc[3]))
      continue;
    ++draws;
    before += static_cast<int>(unjudged.size());
    applied_before += pc0.applied;
    KinematicsData kd(g.file);
    auto landing = [&](const Eigen::VectorXd& at) -> Eigen::Vector3d {
      return g.cell->truePose(g.trueJoints(at), 0.0).translation();
    };
    double draw_ratio[kWays] = {};
    for (int w = 0; w < kWays; ++w) {
      program_applied[w] += pc[w].applied;
      double draw_sq = 0;
      int draw_n = 0;
      for (int i : unjudged) {
        const Eigen::VectorXd& q = program[static_cast<size_t>(i)];
        const CompensationResult& c = pc[w].results[static_cast<size_t>(i)];
        if (!c.unjudged.empty()) {
          ++still_unjudged[w];
          continue;
        }
        if (!c.applied) {
          ++now_refused[w];
          std::printf("    %s: %s\n", outcomeName(c.outcome), describe(c).c_str());
          continue;
        }
        // The target as the controller commands it (the new campaign's frames), where the true robot lands.
        const Eigen::Vector3d desired = forwardKinematics(controller[w], kd, controller[w].nominal, q).translation();
        const double e2 = (landing(c.q_rad) - desired).squaredNorm();
        if (w == 2) map_sq[targets_verify] += e2 / std::pow(c.predicted_sigma_position_m, 2), ++map_n[targets_verify];
        ASSERT_TRUE(std::isfinite(c.predicted_sigma_position_m) && c.predicted_sigma_position_m > 0) << g.what;
        sq_after[w] += e2;
        sq_uncorrected[w] += (landing(q) - desired).squaredNorm();
        sq_ratio[w] += e2 / std::pow(c.predicted_sigma_position_m, 2);
        draw_sq += e2 / std::pow(c.predicted_sigma_position_m, 2);
        ++now_applied[w];
        ++draw_n;
      }
      draw_ratio[w] = draw_n ? std::sqrt(draw_sq / draw_n) : 0.0;
    }
    double draw_beyond[3] = {0, 0, 0};
    int draw_beyond_n = 0;
    for (int i : beyond) {
      const auto at = static_cast<size_t>(i);
      if (!pc[2].results[at].applied || !pc[3].results[at].applied) continue;
      const RobotModel* ctl[3] = {&controller0, &controller[2], &controller[3]};
      const CompensationResult* res[3] = {&pc0.results[at], &pc[2].results[at], &pc[3].results[at]};
      for (int w = 0; w < 3; ++w) {
        const Eigen::Vector3d desired = forwardKinematics(*ctl[w], kd, ctl[w]->nominal, program[at]).translation();
        const double r2 = (landing(res[w]->q_rad) - desired).squaredNorm() / std::pow(res[w]->predicted_sigma_position_m, 2);
        beyond_sq[w] += r2;
        draw_beyond[w] += r2;
      }
      ++beyond_n;
      ++draw_beyond_n;
    }
    if (draw_ratio[2] > 0) draw_map.push_back(draw_ratio[2]);
    if (draw_beyond_n > 0) draw_beyond_measured.push_back(std::sqrt(draw_beyond[2] / draw_beyond_n));
    // The whole program, where both of the last two correct: the map may only change what lies near its rows.
    for (size_t i = 0; i < program.size(); ++i) {
      if (!pc[1].results[i].applied || !pc[2].results[i].applied) continue;
      for (int w = 1; w <= 2; ++w) {
        const CompensationResult& c = pc[w].results[i];
        const Eigen::Vector3d desired = forwardKinematics(controller[w], kd, controller[w].nominal, program[i]).translation();
        sq_program_ratio[w - 1] += (landing(c.q_rad) - desired).squaredNorm() / std::pow(c.predicted_sigma_position_m, 2);
      }
      ++program_both;
    }
    std::printf("  %s\n    %zu of 40 targets passed through where the extensions were never judged; measured there and "
                "calibrated again: actual / predicted %.2f alone, %.2f with %d around each, %.2f with the map; the "
                "program's targets corrected %d before, %d, %d, %d and %d after; %zu corrected beyond the data: actual / "
                "predicted %.2f before, %.2f with the map, %.2f measured there too\n", g.what.c_str(), unjudged.size(),
                draw_ratio[0], draw_ratio[1], kAround, draw_ratio[2], pc0.applied, pc[0].applied, pc[1].applied,
                pc[2].applied, pc[3].applied, beyond.size(), std::sqrt(draw_beyond[0] / std::max(1, draw_beyond_n)),
                std::sqrt(draw_beyond[1] / std::max(1, draw_beyond_n)), std::sqrt(draw_beyond[2] / std::max(1, draw_beyond_n)));
  }
  ASSERT_GE(draws, want / 2) << "no draw left targets where the extensions were never judged";
  auto rms_mm = [](double sq, int n) { return n ? std::sqrt(sq / n) * 1e3 : 0.0; };
  double ratio[kWays];
  for (int w = 0; w < kWays; ++w) ratio[w] = now_applied[w] ? std::sqrt(sq_ratio[w] / now_applied[w]) : 0.0;
  std::printf("  summary: %d draws with targets to measure; %d targets passed through where the extensions were never "
              "judged, the program's targets corrected %d; measured there and calibrated again:\n",
              draws, before, applied_before);
  for (int w = 0; w < kWays; ++w)
    std::printf("    %s: %d corrected (RMS %.4f mm, uncorrected %.4f mm, actual / predicted RMS %.2f), %d still never "
                "judged, %d refused otherwise; the program's targets corrected %d\n", way_name[w], now_applied[w],
                rms_mm(sq_after[w], now_applied[w]), rms_mm(sq_uncorrected[w], now_applied[w]), ratio[w],
                still_unjudged[w], now_refused[w], program_applied[w]);
  std::printf("    with the map, actual / predicted RMS where the targets identify %.2f (%d), where they verify %.2f (%d)\n",
              std::sqrt(map_sq[0] / std::max(1, map_n[0])), map_n[0], std::sqrt(map_sq[1] / std::max(1, map_n[1])),
              map_n[1]);
  std::printf("    the %d targets corrected beyond the extensions' data before measuring: actual / predicted RMS %.2f "
              "before, %.2f with the map, %.2f with the map measured there too\n", beyond_n,
              std::sqrt(beyond_sq[0] / std::max(1, beyond_n)), std::sqrt(beyond_sq[1] / std::max(1, beyond_n)),
              std::sqrt(beyond_sq[2] / std::max(1, beyond_n)));
  std::printf("    median of draws: %.2f with the map at the never-judged targets, %.2f at the targets beyond the data "
              "measured too\n", test::median(draw_map), test::median(draw_beyond_measured));
  std::printf("    the program's %d targets corrected with 5 around and with the map: actual / predicted RMS %.2f and "
              "%.2f\n", program_both, std::sqrt(sq_program_ratio[0] / std::max(1, program_both)),
              std::sqrt(sq_program_ratio[1] / std::max(1, program_both)));
  ASSERT_GE(before, 5) << "too few targets passed through to judge the remedy";
  for (int w = 0; w < kWays; ++w) {
    EXPECT_GE(now_applied[w], before * 3 / 4) << way_name[w] << ": measuring where the targets were passed through "
                                                 "did not bring them in";
    EXPECT_GE(program_applied[w], applied_before) << way_name[w];
    EXPECT_GT(ratio[w], 0.5) << way_name[w] << ": the predicted sigma overstates the error at the targets brought in";
    EXPECT_LT(rms_mm(sq_after[w], now_applied[w]), 0.5 * rms_mm(sq_uncorrected[w], now_applied[w])) << way_name[w];
  }
  // With the map the predicted sigma holds where the targets were measured, in all but a few draws: over seeds 1-60 of
  // 6 draws, 8 of 360 draws more than 2x too low there (77 without the map), the median of a seed's draws 0.67-1.31
  // (0.76-2.98 without). The tail: targets that verify, where the map did not reach them from the rows around
  // (12.5x once, seed 15). Judged by the median of the draws, not their pooled RMS, which one such draw makes.
  EXPECT_LT(test::median(draw_map), 1.75) << "with the map, the predicted sigma understates the error at the targets "
                                             "measured";
  // The targets corrected beyond the extensions' data within the judged distance (`plan cover --beyond-data`):
  // measured too, their pooled actual / predicted 0.61-1.42 per seed (over 1.5 at none of 60; 1 of 356 draws over 2x),
  // against 0.44-2.79 before measuring (over 1.5 at 6; 36 draws over 2x).
  ASSERT_GE(beyond_n, 10) << "the draws do not make targets beyond the data";
  EXPECT_LT(std::sqrt(beyond_sq[2] / beyond_n), 1.75) << "measured there too, the predicted sigma understates the "
                                                         "error at the targets corrected beyond the data";
}

}  // namespace
}  // namespace cellcal
