// Calibrated robot files (robot_file.hpp): what is saved is what is loaded, on robots, parameter errors, extensions
// and covariances drawn at random; a damaged calibration section is refused with its line and field.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/model/cause.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

RobotCalibration randomCalibration(const RobotModel& m, std::mt19937_64& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  RobotCalibration c;
  if (u(rng) < 0.7) {
    const int j = 1 + static_cast<int>(2 * u(rng));
    c.extensions.push_back(Extension{u(rng) < 0.5 ? Cause::kJointCompliance : Cause::kCyclicTransmission, j});
  }
  if (u(rng) < 0.3) c.extensions.push_back(Extension{Cause::kThermalDrift, -1, 0.5 + 3 * u(rng)});
  if (u(rng) < 0.3) c.extensions.push_back(Extension{Cause::kLinkDeflection, 1});  // a beam on both robots
  const int k = numExtensionParams(m, c.extensions);
  c.extension_params = Eigen::VectorXd::NullaryExpr(k, [&] { return 1e-6 * g(rng); });
  c.columns = m.canonicalParams();
  for (int e = 0; e < k; ++e) c.columns.push_back(m.numParams() + e);
  const auto n = static_cast<Eigen::Index>(c.columns.size());
  const Eigen::MatrixXd A = Eigen::MatrixXd::NullaryExpr(n, n, [&] { return 1e-5 * g(rng); });
  c.covariance = A * A.transpose() + 1e-12 * Eigen::MatrixXd::Identity(n, n);
  for (Eigen::Index i = 0; i < n; ++i) c.estimated.push_back(u(rng) < 0.8);
  c.variance_factor_position = 0.5 + 100 * u(rng);
  c.provenance = {{"date_utc", "2026-11-28T21:50:00Z"}, {"data_file", "dir with space/m \"1\".csv"}, {"rows", "120"}};
  if (!c.extensions.empty() && u(rng) < 0.7)  // the campaign's geometric calibration beside the extended model
    c.geometric_params = m.nominal + Eigen::VectorXd::NullaryExpr(m.numParams(), [&] { return 1e-3 * g(rng); });
  for (const auto& e : c.extensions)  // what the extensions may do beyond the campaign's joint ranges
    if (e.joint >= 0 && u(rng) < 0.7) {
      BeyondRange b;
      b.joint = e.joint;
      b.lower_rad = -3 * u(rng);
      b.upper_rad = b.lower_rad + 3 * u(rng);
      b.sigma_at_1_rad = 1e-3 * u(rng);
      b.growth = static_cast<int>(3 * u(rng)) % 3;
      b.checked_rad = 0.5 * u(rng);
      // Stretches inside the range its data never reached (0-3 of them).
      std::vector<double> ends;
      for (int k = static_cast<int>(7 * u(rng)) % 7; k > 0; --k) ends.push_back(b.lower_rad + (b.upper_rad - b.lower_rad) * u(rng));
      std::sort(ends.begin(), ends.end());
      for (size_t k = 0; k + 1 < ends.size(); k += 2)
        if (ends[k] < ends[k + 1]) b.gaps_rad.emplace_back(ends[k], ends[k + 1]);
      c.beyond_data.push_back(b);
    }
  for (const auto& e : c.extensions)  // and beyond the ranges of the drivers of the others
    if (causeModel(e.cause).regionJoint(e) < 0 && u(rng) < 0.7) {
      DriverRange d;
      d.extension = e;
      d.label = causeModel(e.cause).rangeLabel(e, u(rng) < 0.5 ? "temperature_c" : "stamp_s");
      d.lower = 2 * u(rng) - 1;
      d.upper = d.lower + u(rng);
      d.sigma_at_1_m = 1e-3 * u(rng);
      d.growth = static_cast<int>(3 * u(rng)) % 3;
      d.checked_below = u(rng) < 0.2 ? 0 : 0.5 * u(rng);
      d.checked_above = 0.5 * u(rng);
      c.beyond_drivers.push_back(d);
    }
  return c;
}

TEST(RobotFile, SavedAndLoadedPredictIdentically) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  const std::string dir = ::testing::TempDir();
  double worst_m = 0, worst_cov = 0;
  for (int d = 0; d < 40; ++d) {
    const RobotModel file = test::robot(d % 2 ? "ur10" : "staubli_tx60");
    Eigen::VectorXd p = file.nominal;
    for (int i : file.canonicalParams()) p[i] += (file.isLength(i) ? 1e-3 : 1e-3) * g(rng);
    p.segment(file.baseParam(FrameParam::kX), 3) += Eigen::Vector3d::Random() * 3;
    const RobotModel calibrated = file.withParams(p);
    const RobotCalibration cal = randomCalibration(calibrated, rng);
    const std::string path = dir + "/calibrated_" + std::to_string(d) + ".yaml";
    saveRobotFile(path, calibrated, &cal, "a test\nof two lines");
    const RobotFile back = loadRobotFile(path);
    ASSERT_TRUE(back.calibration.has_value());
    const RobotCalibration& c2 = *back.calibration;
    EXPECT_EQ(back.model.name, calibrated.name);
    ASSERT_EQ(c2.extensions.size(), cal.extensions.size());
    for (size_t e = 0; e < cal.extensions.size(); ++e) {
      EXPECT_EQ(c2.extensions[e].cause, cal.extensions[e].cause);
      EXPECT_EQ(c2.extensions[e].joint, cal.extensions[e].joint);
      EXPECT_EQ(c2.extensions[e].time_constant_h, cal.extensions[e].time_constant_h);
    }
    EXPECT_EQ(c2.extension_params, cal.extension_params);
    EXPECT_EQ(c2.columns, cal.columns);
    EXPECT_EQ(c2.estimated, cal.estimated);
    EXPECT_EQ(c2.provenance, cal.provenance);
    EXPECT_EQ(c2.variance_factor_position, cal.variance_factor_position);
    ASSERT_EQ(c2.geometric_params.size(), cal.geometric_params.size());
    for (Eigen::Index i = 0; i < cal.geometric_params.size(); ++i)
      EXPECT_NEAR(c2.geometric_params[i], cal.geometric_params[i], 1e-12 * (1 + std::abs(cal.geometric_params[i]))) << i;
    ASSERT_EQ(c2.beyond_data.size(), cal.beyond_data.size());
    for (size_t i = 0; i < cal.beyond_data.size(); ++i) {
      const BeyondRange &x = cal.beyond_data[i], &y = c2.beyond_data[i];
      EXPECT_EQ(y.joint, x.joint);
      EXPECT_EQ(y.growth, x.growth);
      for (double q = -4; q < 4; q += 0.37) EXPECT_NEAR(y.sigmaRad(q), x.sigmaRad(q), 1e-12 * (1 + x.sigmaRad(q))) << q;
      EXPECT_NEAR(y.checked_rad, x.checked_rad, 1e-12);
      ASSERT_EQ(y.gaps_rad.size(), x.gaps_rad.size());
      for (size_t k = 0; k < x.gaps_rad.size(); ++k) {
        EXPECT_NEAR(y.gaps_rad[k].first, x.gaps_rad[k].first, 1e-12);
        EXPECT_NEAR(y.gaps_rad[k].second, x.gaps_rad[k].second, 1e-12);
      }
    }
    ASSERT_EQ(c2.beyond_drivers.size(), cal.beyond_drivers.size());
    for (size_t i = 0; i < cal.beyond_drivers.size(); ++i) {
      const DriverRange &x = cal.beyond_drivers[i], &y = c2.beyond_drivers[i];
      EXPECT_EQ(extensionSpec(y.extension), extensionSpec(x.extension));
      EXPECT_EQ(y.extension.time_constant_h, x.extension.time_constant_h);  // the calibration's extension's
      EXPECT_EQ(y.label, x.label);
      EXPECT_EQ(y.growth, x.growth);
      for (double v = -2; v < 3; v += 0.037) {
        EXPECT_NEAR(y.sigmaM(v), x.sigmaM(v), 1e-12 * (1 + x.sigmaM(v))) << v;
        EXPECT_EQ(y.judged(v), x.judged(v)) << v;
      }
    }
    worst_cov = std::max(worst_cov, (c2.covariance - cal.covariance).cwiseAbs().maxCoeff() / cal.covariance.cwiseAbs().maxCoeff());
    // Predictions (with the extensions) at random configurations.
    KinematicsData a(calibrated), b(back.model);
    std::mt19937_64 qr(rng());
    for (int t = 0; t < 50; ++t) {
      Eigen::VectorXd q(calibrated.numJoints());
      for (int j = 0; j < q.size(); ++j)
        q[j] = std::uniform_real_distribution<double>(calibrated.limits[j].lower_rad, calibrated.limits[j].upper_rad)(qr);
      Drivers dr;
      dr.thermal = 3.0;
      const Eigen::VectorXd pa = extendedParams(calibrated, calibrated.nominal, cal.extensions, cal.extension_params, q, dr);
      const Eigen::VectorXd pb = extendedParams(back.model, back.model.nominal, c2.extensions, c2.extension_params, q, dr);
      const Pose A = forwardKinematics(calibrated, a, pa, q), B = forwardKinematics(back.model, b, pb, q);
      worst_m = std::max(worst_m, (A.translation() - B.translation()).norm());
      worst_m = std::max(worst_m, 1.0 * (A.linear() - B.linear()).norm());
    }
  }
  std::printf("worst prediction difference %.3g m, covariance %.3g relative\n", worst_m, worst_cov);
  EXPECT_LT(worst_m, 1e-12);
  EXPECT_LT(worst_cov, 1e-12);
}

// `good` with its first `from` replaced by `to` is refused, the message naming `what` after the file's name.
// Each edit of `good` (replace `from` by `to`) refused, naming `what`.
struct Edit {
  std::string from, to, what;
};
void expectRefused(const std::string& good, const std::string& from, const std::string& to, const std::string& what);
void expectEachRefused(const std::string& good, const std::vector<Edit>& edits) {
  for (const auto& e : edits) expectRefused(good, e.from, e.to, e.what);
}

void expectRefused(const std::string& good, const std::string& from, const std::string& to, const std::string& what) {
  std::string text = good;
  const auto at = text.find(from);
  ASSERT_NE(at, std::string::npos) << from;
  text.replace(at, from.size(), to);
  try {
    parseRobotFile(text, "<bad>");
    ADD_FAILURE() << "accepted: " << to;
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what() << "\n(edit: " << from << " -> " << to << ")";
    EXPECT_EQ(std::string(e.what()).rfind("<bad>:", 0), 0u) << e.what();
  }
}

// calibratedModel(file): the file's kinematics and extensions, and the covariance of the columns the calibration
// estimated (in any order in the file) given the others, checked entry by entry against a plain search of the file's
// columns by name and the plain reference of Gaussian conditioning: the inverse of the information matrix's block.
TEST(RobotFile, ItsCalibratedModelIsTheEstimatedColumnsOfTheFile) {
  std::mt19937_64 rng(test::testSeed());
  for (int d = 0; d < 20; ++d) {
    const RobotModel m = test::robot(d % 2 ? "ur10" : "staubli_tx60");
    RobotFile file{m, randomCalibration(m, rng), {}};
    RobotCalibration& cal = *file.calibration;
    // The file's columns in a random order, the covariance permuted with them.
    std::vector<Eigen::Index> perm(cal.columns.size());
    for (size_t k = 0; k < perm.size(); ++k) perm[k] = static_cast<Eigen::Index>(k);
    std::shuffle(perm.begin(), perm.end(), rng);
    std::vector<int> columns;
    std::vector<bool> estimated;
    for (Eigen::Index k : perm) {
      columns.push_back(cal.columns[static_cast<size_t>(k)]);
      estimated.push_back(cal.estimated[static_cast<size_t>(k)]);
    }
    const Eigen::MatrixXd cov = cal.covariance(perm, perm);
    cal.columns = columns, cal.estimated = estimated, cal.covariance = cov;
    const CalibratedModel c = calibratedModel(file);
    std::string why;
    ASSERT_TRUE(c.IsValid(m, &why)) << why;
    EXPECT_EQ(c.params, m.nominal);
    EXPECT_EQ(c.extension_params, cal.extension_params);
    ASSERT_EQ(c.extensions.size(), cal.extensions.size());
    int flagged = 0;
    for (bool e : cal.estimated) flagged += e;
    ASSERT_EQ(c.numEstimated(), flagged);
    auto fileIndex = [&](const std::string& name) {
      for (size_t k = 0; k < cal.columns.size(); ++k)
        if (cal.columnName(m, cal.columns[k]) == name) return static_cast<Eigen::Index>(k);
      return Eigen::Index(-1);
    };
    std::vector<Eigen::Index> at;  // each of c's columns' place in the file
    for (int a = 0; a < c.numEstimated(); ++a) {
      const Eigen::Index fa = fileIndex(c.columnName(m, a));
      ASSERT_GE(fa, 0) << c.columnName(m, a);
      EXPECT_TRUE(cal.estimated[static_cast<size_t>(fa)]) << c.columnName(m, a);
      at.push_back(fa);
    }
    const Eigen::MatrixXd info = cal.covariance.inverse();
    const Eigen::MatrixXd given = Eigen::MatrixXd(info(at, at)).inverse();
    const double scale = given.cwiseAbs().maxCoeff();
    for (int a = 0; a < c.numEstimated(); ++a)
      for (int b = 0; b < c.numEstimated(); ++b)
        EXPECT_NEAR(c.covariance(a, b), given(a, b), 1e-6 * scale) << c.columnName(m, a) << ", " << c.columnName(m, b);
    // Given the others it is no wider than the file's marginal.
    for (int a = 0; a < c.numEstimated(); ++a) EXPECT_LE(c.covariance(a, a), cal.covariance(at[static_cast<size_t>(a)], at[static_cast<size_t>(a)]) * (1 + 1e-9));
  }
  const CalibratedModel plain = calibratedModel(RobotFile{test::robot("ur10"), std::nullopt, {}});
  EXPECT_TRUE(plain.extensions.empty() && plain.estimated.empty() && !plain.hasCovariance());
}

TEST(RobotFile, APlainRobotFileHasNoCalibration) {
  const RobotFile f = loadRobotFile(std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml");
  EXPECT_FALSE(f.calibration.has_value());
  EXPECT_EQ(f.model.links.size(), 6u);  // UR's published masses
}

TEST(RobotFile, ADamagedCalibrationSectionIsNamed) {
  const RobotModel m = test::robot("ur10");
  std::mt19937_64 rng(7);
  RobotCalibration cal = randomCalibration(m, rng);
  cal.extensions = {Extension{Cause::kJointCompliance, 1}};
  cal.extension_params = Eigen::VectorXd::Constant(numExtensionParams(m, cal.extensions), 1e-6);
  cal.columns = {0, 1};
  cal.estimated = {true, false};
  cal.covariance = Eigen::Matrix2d::Identity() * 1e-8;
  cal.geometric_params.resize(0);  // given below
  cal.beyond_data.clear();
  cal.beyond_drivers.clear();
  const std::string good = robotFileText(m, &cal, "");
  EXPECT_NO_THROW(parseRobotFile(good, "<good>"));
  expectEachRefused(good, {{"joint_compliance:2", "joint_compliance:9", "calibration.extensions[0].spec"},
                           {"name: joint1.theta_offset_deg", "name: joint1.theta_offset_rad", "calibration.parameters[0].name"},
                           {"- [1, 0]", "- [1, 2]", "calibration.correlation[0]"},
                           {"estimated: true", "estimated: maybe", "calibration.parameters[0].estimated"},
                           {"variance_factor_position:", "variance_factorposition:", "unknown key"}});
  // The geometric calibration beside it: every parameter, by name, in order.
  cal.geometric_params = m.nominal;
  const std::string with = robotFileText(m, &cal, "");
  EXPECT_NO_THROW(parseRobotFile(with, "<good>"));
  expectRefused(with, "geometric_parameters:\n    - { name: joint1.theta_offset_deg", "geometric_parameters:\n    - { name: joint1.d_mm",
                "calibration.geometric_parameters[0].name");
  expectRefused(with, "    - { name: tool.yaw_deg, value: 0 }\n", "", "calibration.geometric_parameters: expected one");
  // What the extensions may do beyond the campaign's joint ranges: a joint of the robot, a growth of 0-2, a range.
  BeyondRange b;
  b.joint = 1;
  b.lower_rad = -1;
  b.upper_rad = 0.5;
  b.sigma_at_1_rad = 1e-3;
  b.growth = 1;
  b.gaps_rad = {{-0.75, -0.5}, {0, 0.25}};
  cal.beyond_data = {b};
  const std::string beyond = robotFileText(m, &cal, "");
  ASSERT_NE(beyond.find("gaps_deg: [[-42.97183463481174, -28.64788975654116], [0, 14.32394487827058]]"), std::string::npos)
      << beyond;
  EXPECT_NO_THROW(parseRobotFile(beyond, "<good>"));
  // Gaps: each [lower, upper] with lower below upper, in order, apart, inside the range.
  for (const auto& [from, to] : std::vector<std::pair<std::string, std::string>>{
           {"{ joint: 2,", "{ joint: 9,"}, {"growth: 1,", "growth: 3,"}, {"growth: 1,", "growth: 1.5,"},
           {"lower_deg: -57", "lower_deg: 57"}, {"sigma_at_1_rad_deg: ", "sigma_at_1_rad_deg: -"},
           {"[[-42.97183463481174, -28.64788975654116]", "[[-28.64788975654116, -42.97183463481174]"},
           {"[0, 14.32394487827058]", "[-30, 14.32394487827058]"}, {"[0, 14.32394487827058]", "[0, 40]"},
           {"[0, 14.32394487827058]", "[0]"}, {"gaps_deg: [[", "gaps_deg: 3, x: [["}, {"[[-42.97183463481174", "[[-60"}})
    expectRefused(beyond, from, to, "calibration.beyond_data[0]");
  // And beyond an extension driver's range: one of the calibration's extensions that a driver bounds, a growth of 0-2,
  // a range, distances judged of 0 or more.
  cal.extensions = {Extension{Cause::kJointCompliance, 1}, Extension{Cause::kLinkDeflection, 1}};
  cal.extension_params = Eigen::VectorXd::Constant(numExtensionParams(m, cal.extensions), 1e-6);
  DriverRange d;
  d.extension = cal.extensions[1];
  d.label = "gravity across link 2 (g)";
  d.lower = 0.25;
  d.upper = 0.75;
  d.sigma_at_1_m = 2e-4;
  d.growth = 1;
  d.checked_below = 0.125;
  d.checked_above = 0.0625;
  cal.beyond_drivers = {d};
  const std::string driver = robotFileText(m, &cal, "");
  const RobotFile read = parseRobotFile(driver, "<good>");
  ASSERT_EQ(read.calibration->beyond_drivers.size(), 1u);
  EXPECT_EQ(read.calibration->beyond_drivers[0].checked_above, 0.0625);
  for (const auto& [from, to] : std::vector<std::pair<std::string, std::string>>{
           {"{ extension: link_deflection:2,", "{ extension: link_deflection:3,"},
           {"{ extension: link_deflection:2,", "{ extension: joint_compliance:2,"},
           {"growth: 1, checked_below", "growth: 3, checked_below"}, {"lower: 0.25", "lower: 0.95"},
           {"sigma_at_1_mm: ", "sigma_at_1_mm: -"}, {"checked_above: ", "checked_above: -"},
           {", checked_above: 0.0625", ""}, {"upper: 0.75", "upper: 0.75, uper: 1"}})
    expectRefused(driver, from, to, "calibration.beyond_drivers[0]");
}

// A residual map (calibrate --residual-map) in the calibration section: rows and kernel drawn at random, saved and
// loaded, predict the same corrections, sigmas and distances; damaged map entries are named.
TEST(RobotFile, AResidualMapIsSavedAndLoadedAndDamageNamed) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (const char* name : {"ur10", "staubli_tx60"}) {
    const RobotModel m = test::robot(name);
    RobotCalibration cal = randomCalibration(m, rng);
    const int joints = m.numJoints(), rows = 20 + static_cast<int>(rng() % 60);
    std::vector<Eigen::VectorXd> q;
    std::vector<Eigen::Vector3d> y;
    for (int i = 0; i < rows; ++i) {
      q.push_back(Eigen::VectorXd::NullaryExpr(joints, [&] { return 2.0 * u(rng); }));
      y.emplace_back(3e-4 * u(rng), 3e-4 * u(rng), 3e-4 * u(rng));
    }
    ResidualMapKernel k;
    k.length_rad = Eigen::VectorXd::NullaryExpr(joints, [&] { return 0.2 + 2.0 * (1 + u(rng)); });
    k.signal_m = 2e-4 * (1.5 + u(rng));
    k.noise_m = 3e-5 * (1.5 + u(rng));
    k.max_distance = 1.0 + u(rng) * 0.5;
    cal.residual_map = conditionResidualMap(q, y, k);
    const std::string text = robotFileText(m, &cal, "");
    const RobotFile back = parseRobotFile(text, "<saved>");
    ASSERT_TRUE(back.calibration && back.calibration->residual_map);
    const ResidualMap& a = *cal.residual_map;
    const ResidualMap& b = *back.calibration->residual_map;
    ASSERT_EQ(b.rows(), a.rows());
    for (int t = 0; t < 50; ++t) {
      const Eigen::VectorXd x = t < 10 ? q[static_cast<size_t>(t)] : Eigen::VectorXd::NullaryExpr(joints, [&] { return 2.0 * u(rng); });
      const auto pa = a.predict(x, true), pb = b.predict(x, true);
      EXPECT_EQ(pa.applies, pb.applies);
      EXPECT_NEAR(pa.distance, pb.distance, 1e-12 * (1 + pa.distance));
      EXPECT_LT((pa.correction_m - pb.correction_m).norm(), 1e-12 + 1e-9 * pa.correction_m.norm());
      EXPECT_NEAR(pa.sigma_m, pb.sigma_m, 1e-9 * k.signal_m);
    }
    expectRefused(text, "length_scales_deg: [", "length_scales_deg: [1, ", "calibration.residual_map.length_scales_deg: expected");
    expectRefused(text, "signal_mm: ", "signal_mm: -", "the signal sigma must be finite and > 0");
    expectRefused(text, "      - [", "      - [1, ", "calibration.residual_map.rows[0]: expected");
    expectRefused(text, "max_distance:", "reach:", "calibration.residual_map.reach: unknown key");
  }
}

}  // namespace
}  // namespace cellcal
