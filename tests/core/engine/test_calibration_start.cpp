// calibrationStart (core/engine/calibration_start.hpp): the engine's starting estimate and prior from a calibrated
// robot file, against a plain reference written here: the covered state entries' covariance given every other column
// of the file (Schur complement with an explicit inverse), the uncalibrated prior elsewhere, each variance capped at
// the prior's; extension values taken by name. Random robots, files (columns in any order, covariances, extensions)
// and cell extensions.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "cellcal/core/engine/calibration_start.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

TEST(CalibrationStart, ThePriorIsTheFilesCovarianceGivenWhatTheEngineDoesNotEstimate) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int capped_seen = 0, uncovered_seen = 0;
  for (int d = 0; d < 16; ++d) {
    const RobotModel nominal = test::robot(d % 2 ? "ur10" : "staubli_tx60");
    RobotFile file{nominal, RobotCalibration{}, {}};
    for (int i : nominal.canonicalParams()) file.model.nominal[i] += 1e-4 * g(rng);
    RobotCalibration& cal = *file.calibration;
    // The file's extensions and the cell's: each of two candidates in one, the other or both.
    const Extension a{Cause::kCyclicTransmission, 1}, b{Cause::kJointScale, 2};
    std::vector<Extension> cell_exts;
    for (const Extension& e : {a, b}) {
      const int where = static_cast<int>(3 * u(rng));  // 0 file, 1 cell, 2 both
      if (where != 1) cal.extensions.push_back(e);
      if (where != 0) cell_exts.push_back(e);
    }
    const int k = numExtensionParams(nominal, cal.extensions);
    cal.extension_params = Eigen::VectorXd::NullaryExpr(k, [&] { return 1e-4 * g(rng); });
    // Columns: most kinematic parameters and the extension ones, in a random order.
    for (int i : nominal.canonicalParams())
      if (u(rng) < 0.9) cal.columns.push_back(i);
    for (int e = 0; e < k; ++e) cal.columns.push_back(nominal.numParams() + e);
    std::shuffle(cal.columns.begin(), cal.columns.end(), rng);
    const auto nc = static_cast<Eigen::Index>(cal.columns.size());
    const Eigen::MatrixXd A = Eigen::MatrixXd::NullaryExpr(nc, nc, [&] { return (u(rng) < 0.5 ? 1e-3 : 1e-6) * g(rng); });
    cal.covariance = A * A.transpose() + 1e-14 * Eigen::MatrixXd::Identity(nc, nc);
    cal.estimated.assign(cal.columns.size(), true);
    const double prior_length_m = 1e-3, prior_angle_rad = degToRad(0.1);
    const CalibrationStart s =
        calibrationStart(nominal, file, cell_exts, prior_length_m, prior_angle_rad, MeasurementKind::kPose6D);
    const CalibratedModel& c = s.model;
    std::string why;
    ASSERT_TRUE(c.IsValid(nominal, &why)) << why;
    EXPECT_EQ(c.params, file.model.nominal);
    ASSERT_EQ(s.prior_sd.size(), c.numEstimated());
    // Extension values by name: the file's where it has them, else zero.
    const std::vector<std::string> names = extensionParamNames(nominal, cell_exts),
                                   file_names = extensionParamNames(nominal, cal.extensions);
    for (size_t e = 0; e < names.size(); ++e) {
      const auto it = std::find(file_names.begin(), file_names.end(), names[e]);
      EXPECT_EQ(c.extension_params[static_cast<Eigen::Index>(e)],
                it == file_names.end() ? 0.0 : cal.extension_params[it - file_names.begin()])
          << names[e];
    }
    // The reference: state entry -> file column by name; S covered, O every other file column.
    std::vector<Eigen::Index> S, fS, uncovered;
    for (int col = 0; col < c.numEstimated(); ++col) {
      const std::string name = c.columnName(nominal, col);
      Eigen::Index f = -1;
      for (Eigen::Index j = 0; j < nc; ++j)
        if (cal.columnName(nominal, cal.columns[static_cast<size_t>(j)]) == name) f = j;
      if (f < 0) {
        uncovered.push_back(col);
      } else {
        S.push_back(col);
        fS.push_back(f);
      }
    }
    std::vector<Eigen::Index> fO;
    for (Eigen::Index j = 0; j < nc; ++j)
      if (std::find(fS.begin(), fS.end(), j) == fS.end()) fO.push_back(j);
    EXPECT_EQ(s.covered, static_cast<int>(S.size()));
    const Eigen::MatrixXd Sss = cal.covariance(fS, fS), Sso = cal.covariance(fS, fO), Soo = cal.covariance(fO, fO);
    Eigen::MatrixXd ref = fO.empty() ? Sss : Eigen::MatrixXd(Sss - Sso * Soo.inverse() * Sso.transpose());
    Eigen::MatrixXd full = s.prior_sd.array().square().matrix().asDiagonal();
    for (size_t x = 0; x < S.size(); ++x)
      for (size_t y = 0; y < S.size(); ++y) full(S[x], S[y]) = ref(static_cast<Eigen::Index>(x), static_cast<Eigen::Index>(y));
    int capped = 0;
    for (Eigen::Index i = 0; i < full.rows(); ++i)
      if (full(i, i) > s.prior_sd[i] * s.prior_sd[i]) {
        const double f = s.prior_sd[i] / std::sqrt(full(i, i));
        full.row(i) *= f;
        full.col(i) *= f;
        ++capped;
      }
    EXPECT_EQ(s.capped, capped);
    const double scale = full.diagonal().maxCoeff();
    EXPECT_LT((c.covariance - full).cwiseAbs().maxCoeff(), 1e-6 * scale) << "draw " << d;
    capped_seen += capped > 0;
    uncovered_seen += !uncovered.empty();
  }
  EXPECT_GT(capped_seen, 0) << "no draw capped a variance";
  EXPECT_GT(uncovered_seen, 0) << "no draw left a state entry to its prior";
}

}  // namespace
}  // namespace cellcal
