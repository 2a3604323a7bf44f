// Conversions between the wire types and core (components/common/convert): what the engine publishes is what the
// compensation publisher rebuilds. Its own TU: the generated TypeObject header (test_msgs.cpp) opens Fast DDS's types
// namespace, whose operator templates make Eigen's enum comparisons ambiguous.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "cdr_round_trip.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal_msgsPubSubTypes.h"

namespace {

using cellcal::test::roundTrip;

// The shipped cell's robot, for a snapshot to convert.
struct Convert : ::testing::Test {
  cellcal::CellConfig cell = cellcal::loadCellConfig(std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml");
  cellcal::CellRobot& robot = cell.robots[0];
  const cellcal::RobotModel& m = robot.model;
};

// The estimate's covariance crosses the wire as stddevs and correlations: a random covariance over estimated
// parameters listed in any order comes back as the kinematic block, in index order, to rounding.
TEST_F(Convert, CalibrationStateCarriesTheCovariance) {
  cellcal::CalibrationSnapshot s;
  s.version = 2;
  s.params = m.nominal;
  s.estimated = {7, 2, 11, 0, 5};  // not in index order
  s.extensions = {{cellcal::Cause::kJointCompliance, 1}};
  s.extension_params = Eigen::VectorXd::Zero(cellcal::numExtensionParams(m, s.extensions));
  s.estimated_extension = {1, 0};
  const Eigen::MatrixXd A = Eigen::MatrixXd::Random(7, 7);
  s.covariance = 1e-8 * (A * A.transpose() + 0.1 * Eigen::MatrixXd::Identity(7, 7));
  const auto wire = roundTrip<cellcal::msg::CalibrationStatePubSubType>(cellcal::components::toCalibrationState(robot, s, 1, 1));
  EXPECT_EQ(wire.parameter_correlations().size(), 7u * 6u / 2u);
  std::string error;
  const auto back = cellcal::components::fromCalibrationState(m, wire, &error);
  ASSERT_TRUE(back) << error;
  ASSERT_EQ(back->estimated, (std::vector<int>{0, 2, 5, 7, 11}));
  for (size_t a = 0; a < 5; ++a)
    for (size_t b = 0; b < 5; ++b) {
      const auto ia = std::find(s.estimated.begin(), s.estimated.end(), back->estimated[a]) - s.estimated.begin();
      const auto ib = std::find(s.estimated.begin(), s.estimated.end(), back->estimated[b]) - s.estimated.begin();
      EXPECT_NEAR(back->covariance(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)), s.covariance(ia, ib),
                  1e-14 * s.covariance.norm());
    }
  auto bad = wire;
  bad.parameter_correlations().pop_back();
  EXPECT_FALSE(cellcal::components::fromCalibrationState(m, bad, &error));
  EXPECT_NE(error.find("parameter_correlations: 20 values, expected 21 for 7 parameters with a stddev"), std::string::npos)
      << error;
}

// The engine fills one sample per robot again for every publish: whatever the sample held before (another robot's
// state, other extensions, more correlations), it serializes to the bytes of a fresh toCalibrationState.
TEST_F(Convert, AReusedCalibrationStateSampleIsAFreshOne) {
  auto bytes = [](cellcal::msg::CalibrationState& m) {
    cellcal::msg::CalibrationStatePubSubType type;
    eprosima::fastrtps::rtps::SerializedPayload_t payload(type.getSerializedSizeProvider(&m)());
    EXPECT_TRUE(type.serialize(&m, &payload));
    return std::vector<unsigned char>(payload.data, payload.data + payload.length);
  };
  auto snapshot = [&](std::vector<cellcal::Extension> ext, int estimated) {
    cellcal::CalibrationSnapshot s;
    s.version = static_cast<std::uint64_t>(estimated);
    s.params = m.nominal + 1e-4 * Eigen::VectorXd::Random(m.numParams());
    for (int i = 0; i < estimated; ++i) s.estimated.push_back(i);
    s.extensions = std::move(ext);
    s.extension_params = 1e-5 * Eigen::VectorXd::Random(cellcal::numExtensionParams(m, s.extensions));
    for (int e = 0; e < s.extension_params.size(); e += 2) s.estimated_extension.push_back(e);
    const auto n = static_cast<Eigen::Index>(s.estimated.size() + s.estimated_extension.size());
    const Eigen::MatrixXd A = Eigen::MatrixXd::Random(n, n);
    s.covariance = 1e-8 * (A * A.transpose() + 0.1 * Eigen::MatrixXd::Identity(n, n));
    return s;
  };
  cellcal::CellRobot other = robot;
  other.robot_id = "another_robot";
  const std::vector<std::pair<const cellcal::CellRobot*, cellcal::CalibrationSnapshot>> sequence = {
      {&robot, snapshot({{cellcal::Cause::kCyclicTransmission, 2}}, 12)},
      {&robot, snapshot({{cellcal::Cause::kCyclicTransmission, 2}}, 5)},  // fewer correlations
      {&robot, snapshot({}, 20)},                                          // extensions dropped
      {&other, snapshot({}, 20)},                                          // another robot, the same names
      {&robot, snapshot({{cellcal::Cause::kJointCompliance, 1}, {cellcal::Cause::kCyclicTransmission, 3}}, 8)},
      {&robot, snapshot({{cellcal::Cause::kCyclicTransmission, 3}, {cellcal::Cause::kJointCompliance, 1}}, 8)},
  };
  cellcal::msg::CalibrationState reused;
  std::uint64_t seq = 0;
  for (const auto& [r, s] : sequence) {
    ++seq;
    cellcal::components::fillCalibrationState(*r, s, 7, seq, reused);
    auto fresh = cellcal::components::toCalibrationState(*r, s, 7, seq);
    EXPECT_EQ(bytes(reused), bytes(fresh)) << "step " << seq;
  }
}

TEST_F(Convert, CalibrationStateCarriesModelExtensions) {
  // The engine's snapshot with extensions -> wire -> what the compensation publisher rebuilds: the same model.
  cellcal::CalibrationSnapshot s;
  s.version = 3;
  s.params = m.nominal + 1e-4 * Eigen::VectorXd::Random(m.numParams());
  for (int i = 0; i < 10; ++i) s.estimated.push_back(i);
  s.extensions = {{cellcal::Cause::kCyclicTransmission, 2}, {cellcal::Cause::kJointCompliance, 1}};
  const int nx = cellcal::numExtensionParams(m, s.extensions);
  s.extension_params = 1e-5 * Eigen::VectorXd::Random(nx);
  s.estimated_extension = {0, 1, 2, 3, 5};
  s.covariance = Eigen::VectorXd::LinSpaced(15, 1e-8, 15e-8).asDiagonal();
  const auto wire = roundTrip<cellcal::msg::CalibrationStatePubSubType>(cellcal::components::toCalibrationState(robot, s, 1, 1));
  ASSERT_EQ(wire.model_extensions().size(), 2u);
  EXPECT_EQ(wire.model_extensions()[0].to_string(), "cyclic_transmission:3");
  EXPECT_EQ(wire.parameter_names().size(), static_cast<size_t>(m.numParams() + nx));
  EXPECT_EQ(wire.parameter_names()[m.numParams()].to_string(), "joint3.sin1_rad");
  EXPECT_NEAR(wire.parameter_stddevs()[m.numParams() + 5], std::sqrt(15e-8), 1e-15);  // estimated_extension[4] = 5
  EXPECT_EQ(wire.parameter_stddevs()[m.numParams() + 4], 0.0);                          // not estimated
  std::string error;
  const auto back = cellcal::components::fromCalibrationState(m, wire, &error);
  ASSERT_TRUE(back) << error;
  EXPECT_EQ(back->params, s.params);
  EXPECT_EQ(back->extension_params, s.extension_params);
  ASSERT_EQ(back->extensions.size(), 2u);
  EXPECT_EQ(back->extensions[1].cause, cellcal::Cause::kJointCompliance);
  EXPECT_EQ(back->extensions[1].joint, 1);
  // A parameter of a named extension left out is an error, not "no effect".
  auto cut = wire;
  cut.parameter_names().pop_back();
  cut.parameter_values().pop_back();
  EXPECT_FALSE(cellcal::components::fromCalibrationState(m, cut, &error));
  EXPECT_NE(error.find("extension parameter 'joint2.compliance_link6_moment_z_rad_per_Nm_kg_m' missing"), std::string::npos) << error;
  auto bad = wire;
  bad.model_extensions()[0] = "thermal_drift";
  EXPECT_FALSE(cellcal::components::fromCalibrationState(m, bad, &error));
  EXPECT_NE(error.find("model_extensions: 'thermal_drift' does not apply"), std::string::npos) << error;
}

// A proposal crosses the wire row-major with its joint count; what does not fit the robot is refused, named.
TEST_F(Convert, PoseRequestCarriesTheConfigurationsInOrder) {
  cellcal::PoseProposal p;
  p.version = 7;
  p.predicted_sigma_now_m = 3e-5;
  p.predicted_sigma_after_m = 2e-5;
  for (int k = 0; k < 4; ++k) p.q_rad.push_back(Eigen::VectorXd::LinSpaced(m.numJoints(), 0.1 * k, 0.1 * k + 1));
  const cellcal::msg::PoseRequest w = roundTrip<cellcal::msg::PoseRequestPubSubType>(
      cellcal::components::toPoseRequest("tx60", p, 278, 123, 5));
  EXPECT_EQ(w.robot_id(), "tx60");
  EXPECT_EQ(w.calibration_version(), 7u);
  EXPECT_EQ(w.candidates(), 278u);
  EXPECT_EQ(w.predicted_sigma_after_m(), 2e-5);
  std::string error;
  const auto back = cellcal::components::fromPoseRequest(w, m.numJoints(), &error);
  ASSERT_TRUE(back) << error;
  ASSERT_EQ(back->size(), 4u);
  for (size_t k = 0; k < 4; ++k) EXPECT_EQ((*back)[k], p.q_rad[k]);
  EXPECT_FALSE(cellcal::components::fromPoseRequest(w, m.numJoints() + 1, &error));
  EXPECT_NE(error.find("pose_request of tx60 #5: 6 joints per configuration for a robot of 7"), std::string::npos) << error;
  cellcal::msg::PoseRequest bad = w;
  bad.configurations_rad().pop_back();
  EXPECT_FALSE(cellcal::components::fromPoseRequest(bad, m.numJoints(), &error));
  EXPECT_NE(error.find("are not whole configurations"), std::string::npos) << error;
  bad = w;
  bad.configurations_rad()[8] = std::nan("");
  EXPECT_FALSE(cellcal::components::fromPoseRequest(bad, m.numJoints(), &error));
  EXPECT_NE(error.find("configuration 1 is not finite"), std::string::npos) << error;
  // More than the IDL's 1024 values: the most informative kept, whole configurations only.
  p.q_rad.assign(200, Eigen::VectorXd::Zero(m.numJoints()));
  EXPECT_EQ(cellcal::components::toPoseRequest("tx60", p, 1, 1, 1).configurations_rad().size(), 1020u);
}

// The wire's compensation outcome starts with core's, in its order, each with core's name; the publisher's own follow,
// and every code has a name of its own. A CompensatedTarget carries it through CDR.
TEST(CompensationOutcome, TheWiresCodesAreCoresThenThePublishersEachNamed) {
  std::vector<std::string> names;
  for (int k = 0; k <= static_cast<int>(cellcal::msg::OUTCOME_NO_GOOD_CALIBRATION); ++k) {
    const auto o = static_cast<cellcal::msg::CompensationOutcome>(k);
    const std::string name = cellcal::components::outcomeText(o);
    if (k < cellcal::kNumCompensationOutcomes) {
      EXPECT_EQ(name, cellcal::outcomeName(static_cast<cellcal::CompensationOutcome>(k)));
    }
    EXPECT_NE(name, "?") << k;
    EXPECT_EQ(std::count(names.begin(), names.end(), name), 0) << name;
    names.push_back(name);
  }
  EXPECT_EQ(names[cellcal::msg::OUTCOME_NEVER_JUDGED], "never_judged");
  EXPECT_EQ(names[cellcal::msg::OUTCOME_NO_GOOD_CALIBRATION], "no_good_calibration");
  cellcal::msg::CompensatedTarget t;
  t.outcome(cellcal::msg::OUTCOME_NEVER_JUDGED);
  t.beyond_data(true);
  t.older_calibration(true);
  const cellcal::msg::CompensatedTarget back = roundTrip<cellcal::msg::CompensatedTargetPubSubType>(t);
  EXPECT_EQ(back.outcome(), cellcal::msg::OUTCOME_NEVER_JUDGED);
  EXPECT_TRUE(back.beyond_data());
  EXPECT_TRUE(back.older_calibration());
}

}  // namespace
