// thermal_drift: every a and d grows by e_0 * s * value and joint j's zero by e_1 * s, with s the thermal driver
// (temperature minus its reference, K). Without a thermometer, time drives it as a first-order warm-up:
// s = tau (1 - exp(-t / tau)) with t the hours since the first row and tau the time constant
// (Extension::time_constant_h, fitted by fitExtended; infinite: s = t, a straight line). joint = -1: the lengths only
// (one parameter), when no joint zero drifts measurably. Two thermal drifts share the lengths: one per model.
#include "cause_support.hpp"

namespace cellcal {
namespace {

class ThermalDrift final : public CauseModel {
 public:
  ThermalDrift() : CauseModel({Cause::kThermalDrift, "thermal_drift", Subject::kJointOrLengths, Driver::kThermal}) {}

  int numParams(const RobotModel&, int joint) const override { return joint < 0 ? 1 : 2; }
  std::vector<std::string> paramNames(const RobotModel&, int joint) const override {
    if (joint < 0) return {"lengths.expansion_per_unit"};
    return {"lengths.expansion_per_unit", causes::jointPrefix(joint) + "zero_drift_rad_per_unit"};
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    const double s = thermalDriverValue(at.ext, at.drivers);
    // Column 0: every length grows with itself; column 1: joint j's zero.
    for (int i = 0; i < at.model.numJoints(); ++i)
      for (JointParam p : {JointParam::kA, JointParam::kD}) {
        const int idx = at.model.jointParam(i, p);
        B(idx, 0) = s * at.params[idx];
      }
    if (at.ext.joint >= 0) B(causes::thetaRow(at.model, at.ext.joint), 1) = s;
  }

  bool conflicts(const Extension& mine, const Extension& other) const override {
    return other.cause == mine.cause;  // they share the lengths
  }
  std::string label(const Extension& ext) const override {
    return std::string(name()) + (ext.joint < 0 ? " (lengths)" : " joint " + std::to_string(ext.joint + 1)) +
           causes::warmUpSuffix(ext);
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(thermalDrift, ThermalDrift)

}  // namespace cellcal
