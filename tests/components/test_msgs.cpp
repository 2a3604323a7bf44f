// The generated topic types: every type survives a CDR round trip, keyed types hash their key, and the type names and
// TypeObjects that recorders and other vendors see are the ones documented.
#include <gtest/gtest.h>

#include <fastrtps/rtps/common/InstanceHandle.h>

#include "cdr_round_trip.hpp"
#include "cellcal_msgsPubSubTypes.h"
#include "cellcal_msgsTypeObject.h"

namespace {

using eprosima::fastrtps::rtps::InstanceHandle_t;
using cellcal::test::roundTrip;

template <typename PubSubType, typename T>
InstanceHandle_t keyOf(const T& sample) {
  PubSubType type;
  InstanceHandle_t h;
  EXPECT_TRUE(type.getKey(const_cast<T*>(&sample), &h, false));
  return h;
}

TEST(Msgs, JointStateRoundTripAndKey) {
  cellcal::msg::JointState a;
  a.robot_id("tx60_left");
  a.source_stamp_ns(1700000000123456789ULL);
  a.sequence_number(42);
  a.position_rad({0.1, -0.2, 0.3, -0.4, 0.5, -0.6});
  a.settled(true);
  const auto b = roundTrip<cellcal::msg::JointStatePubSubType>(a);
  EXPECT_EQ(a, b);
  EXPECT_EQ(b.position_rad().size(), 6u);
  cellcal::msg::JointState other = a;
  other.sequence_number(43);
  other.position_rad({0.0});
  EXPECT_EQ(keyOf<cellcal::msg::JointStatePubSubType>(a), keyOf<cellcal::msg::JointStatePubSubType>(other));
  other.robot_id("tx60_right");
  EXPECT_NE(keyOf<cellcal::msg::JointStatePubSubType>(a), keyOf<cellcal::msg::JointStatePubSubType>(other));
  EXPECT_TRUE(cellcal::msg::JointStatePubSubType().m_isGetKeyDefined);
}

TEST(Msgs, TrackerPoseRoundTrip) {
  cellcal::msg::TrackerPose a;
  a.target_id("smr1");
  a.position_m({2.1, 0.4, -0.3});
  a.orientation_xyzw({0.0, 0.0, 0.38268343236508984, 0.9238795325112867});
  a.has_orientation(true);
  a.covariance()[0] = 1e-10;
  a.covariance()[35] = 7.6e-9;
  a.valid(true);
  EXPECT_EQ(a, (roundTrip<cellcal::msg::TrackerPosePubSubType>(a)));
}

TEST(Msgs, CalibrationStateCarriesNamedParameters) {
  cellcal::msg::CalibrationState a;
  a.robot_id("tx60_left");
  a.version(7);
  a.mode(cellcal::msg::MODE_CONTINUOUS);
  a.health(cellcal::msg::HEALTH_OK);
  a.poses_used(65);
  a.parameter_names().push_back("joint2.a_m");
  a.parameter_values().push_back(0.29021);
  a.parameter_stddevs().push_back(3e-6);
  const auto b = roundTrip<cellcal::msg::CalibrationStatePubSubType>(a);
  EXPECT_EQ(a, b);
  ASSERT_EQ(b.parameter_names().size(), 1u);
  EXPECT_EQ(b.parameter_names()[0].to_string(), "joint2.a_m");
  EXPECT_EQ(b.parameter_values()[0], 0.29021);
}

TEST(Msgs, TargetCompensationAndDiagnosticsRoundTrip) {
  cellcal::msg::TargetPose t;
  t.robot_id("r");
  t.position_m({0.5, 0.1, 0.4});
  t.orientation_xyzw({0, 0, 0, 1});
  EXPECT_EQ(t, (roundTrip<cellcal::msg::TargetPosePubSubType>(t)));
  cellcal::msg::CompensatedTarget c;
  c.robot_id("r");
  c.target_sequence(9);
  c.calibration_version(3);
  c.joint_position_rad({0.1, 0.2, 0.3, 0.4, 0.5, 0.6});
  c.applied(false);
  c.reason("no calibration loaded");
  EXPECT_EQ(c, (roundTrip<cellcal::msg::CompensatedTargetPubSubType>(c)));
  // The words travel whole, however long (a reason naming an unjudged range runs past 256 characters), the operator's
  // note in its own field.
  c.reason(std::string(1000, 'r'));
  c.note(std::string(600, 'n'));
  c.outcome(cellcal::msg::OUTCOME_NEVER_JUDGED);
  EXPECT_EQ(c, (roundTrip<cellcal::msg::CompensatedTargetPubSubType>(c)));
  cellcal::msg::CalibrationDiagnostics d;
  d.robot_id("r");
  d.rejection_reasons().push_back("robot_moving");
  d.rejection_counts().push_back(12);
  d.drift_alarm(true);
  EXPECT_EQ(d, (roundTrip<cellcal::msg::CalibrationDiagnosticsPubSubType>(d)));
}

TEST(Msgs, TypeNamesAndTypeObjects) {
  EXPECT_STREQ(cellcal::msg::JointStatePubSubType().getName(), "cellcal::msg::JointState");
  EXPECT_STREQ(cellcal::msg::CalibrationStatePubSubType().getName(), "cellcal::msg::CalibrationState");
  EXPECT_STREQ(cellcal::msg::CompensatedTargetPubSubType().getName(), "cellcal::msg::CompensatedTarget");
  registercellcal_msgsTypes();
  EXPECT_NE(cellcal::msg::GetJointStateIdentifier(true), nullptr);
  EXPECT_NE(cellcal::msg::GetCalibrationStateIdentifier(true), nullptr);
}

}  // namespace
