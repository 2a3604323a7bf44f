// The registry of causes (cause_list.hpp) and what every cause has in common (the defaults of CauseModel).
#include <cmath>
#include <limits>
#include <stdexcept>

#include "cause_support.hpp"

namespace cellcal {

const std::vector<const CauseModel*>& causeModels() {
#define CELLCAL_REGISTER_CAUSE(enumerator, stem) &stem##Cause(),
  static const std::vector<const CauseModel*> all = {CELLCAL_CAUSES(CELLCAL_REGISTER_CAUSE)};
#undef CELLCAL_REGISTER_CAUSE
  return all;
}

const CauseModel& causeModel(Cause cause) {
  for (const CauseModel* c : causeModels())
    if (c->id() == cause) return *c;
  throw std::invalid_argument("causeModel: no cause registered for this value (kNone is not a cause)");
}

bool CauseModel::applicable(const RobotModel& model, int joint, bool has_thermal) const {
  const int n = model.numJoints();
  switch (subject()) {
    case Subject::kBase:
      if (joint != -1) return false;
      break;
    case Subject::kJointOrLengths:
      if (joint < -1 || joint >= n) return false;
      break;
    case Subject::kJoint:
    case Subject::kLink:
      if (joint < 0 || joint >= n) return false;
      break;
  }
  if (driver() == Driver::kThermal && !has_thermal) return false;
  return appliesTo(model, joint, has_thermal);
}

std::string CauseModel::whyNot(const RobotModel&, int, bool has_thermal) const {
  return driver() == Driver::kThermal && !has_thermal ? " without a temperature or time driver" : "";
}

bool CauseModel::conflicts(const Extension& mine, const Extension& other) const {
  return mine.cause == other.cause && mine.joint == other.joint;
}

std::string CauseModel::label(const Extension& ext) const {
  std::string s = name();
  if (ext.joint >= 0) s += " joint " + std::to_string(ext.joint + 1);
  return s;
}

int CauseModel::regionJoint(const Extension& ext) const {
  return subject() == Subject::kJoint && ext.joint >= 0 ? ext.joint : -1;
}

double CauseModel::rangeValue(const RobotModel&, const Eigen::VectorXd&, const Extension& ext, const Eigen::VectorXd&,
                              const Drivers& drivers) const {
  return driver() == Driver::kThermal ? thermalDriverValue(ext, drivers) : std::numeric_limits<double>::quiet_NaN();
}

std::string CauseModel::rangeLabel(const Extension& ext, const std::string& thermal_source) const {
  if (driver() != Driver::kThermal) return "";
  if (thermal_source == "temperature_c") return causes::thermalLabel(thermal_source);
  return ext.time_constant_h > 0 && std::isfinite(ext.time_constant_h) ? "warm-up since the first row (h)"
                                                                        : causes::thermalLabel(thermal_source);
}

std::string CauseModel::signatureXLabel(const RobotModel&, int joint, const std::string& thermal_source) const {
  if (driver() == Driver::kThermal) return causes::thermalLabel(thermal_source);
  if (driver() == Driver::kJointAngle) return "q" + std::to_string(joint + 1) + " (deg)";
  throw std::logic_error(std::string(name()) + ": a cause on this driver says its signature's x");
}

double CauseModel::signatureX(const SignatureRow& at) const {
  if (driver() == Driver::kThermal) return at.drivers.thermal;
  if (driver() == Driver::kJointAngle) return at.q_rad[at.joint] * 180.0 / kPi;
  throw std::logic_error(std::string(name()) + ": a cause on this driver says its signature's x");
}

std::string CauseModel::signatureYLabel(int joint) const {
  return joint >= 0 ? "apparent joint " + std::to_string(joint + 1) + " error (deg)"
                    : "apparent growth of the lengths (um/m)";
}

SignatureAxis CauseModel::signatureAxis(const SignatureRow& at) const {
  SignatureAxis a;
  if (at.joint >= 0) {
    a.direction = at.J.block<3, 1>(0, causes::thetaRow(at.model, at.joint));
    a.scale = 180.0 / kPi;
    return a;
  }
  for (int k = 0; k < at.model.numJoints(); ++k)
    for (JointParam p : {JointParam::kA, JointParam::kD}) {
      const int idx = at.model.jointParam(k, p);
      a.direction += at.J.block<3, 1>(0, idx) * at.params[idx];
    }
  a.scale = 1e6;
  return a;
}

}  // namespace cellcal
