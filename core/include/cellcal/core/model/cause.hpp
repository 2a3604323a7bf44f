// One physical cause of error a geometric model does not have, as the library knows it: what an extension of it acts
// on and reads, its parameters and their names, its basis B (model_extension.hpp), the label and figure diagnose gives
// it. Each cause is one file of core/src/model/causes/ and one line of cause_list.hpp; model_extension.hpp's free
// functions, diagnose and the shared suite (tests/core/model/test_causes.cpp: names, applicability, and every basis
// column's pose derivative against finite differences and ceres::Jet) reach a cause only through this interface.
//
// Contract of every implementation: numParams(model, joint) == paramNames(model, joint).size() wherever applicable();
// basis() writes only the rows of the kinematic parameters the cause perturbs and is deterministic; the sizes of its
// parameters are SI (rad, m, per unit of the thermal driver) and named with their unit.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/model/model_extension.hpp"

namespace cellcal {

// Where B of one observation is evaluated (extensionBasis's arguments).
struct BasisPoint {
  const RobotModel& model;
  const Eigen::VectorXd& params;    // kinematic parameters: the geometry of gravity and of the lengths
  const Extension& ext;
  const Eigen::VectorXd& q_rad;
  const Drivers& drivers;
  double backlash_width_rad = 0.0;  // the width a play state is evaluated at (0: the last direction of motion)
};

// One row of diagnose's signature figure of a cause (causeSignature in diagnosis.hpp): x is the cause's driver at the
// row, y the row's position residual read along `direction`: y = direction . r / |direction|^2 * scale, or
// direction . r * scale when `unit` (direction has unit length already).
struct SignatureRow {
  const RobotModel& model;
  const Eigen::VectorXd& params;  // the geometric fit
  const Eigen::VectorXd& q_rad;
  const Drivers& drivers;
  int joint;                      // Extension::joint
  size_t row;                     // index of the row (for a spread that keeps discrete drivers apart)
  const Eigen::MatrixXd& J;       // pose Jacobian (6 x numParams) at (params, q_rad)
};
struct SignatureAxis {
  Eigen::Vector3d direction = Eigen::Vector3d::Zero();
  double scale = 1.0;
  bool unit = false;
};

class CauseModel {
 public:
  // What Extension::joint names.
  enum class Subject {
    kJoint,           // a joint, required: "backlash:3"
    kLink,            // a link, required (link j: between the axes of joints j and j+1): "link_deflection:2"
    kJointOrLengths,  // a joint, or none (-1): the link lengths alone. "thermal_drift", "thermal_drift:2"
    kBase,            // none: the base frame. "frame_drift"
  };
  // What the basis reads besides the joint angles: what the data must bring for the cause to apply.
  enum class Driver {
    kJointAngle,  // q alone
    kGravity,     // the gravity load at q; the robot file's masses when it has them
    kThermal,     // Drivers::thermal (temperature, or time with a warm-up fitExtended fits)
    kPath,        // the path to the pose (Drivers::recent_steps_rad, motion_direction): a play state
  };

  // What the library says of a cause before any robot: its value, written name, subject and driver, and whether
  // diagnose tries it (frame_drift: no, it is the alternative a drift is tested against).
  struct Traits {
    Cause id;
    const char* name;  // as written in files and on the command line: "joint_compliance"
    Subject subject;
    Driver driver;
    bool diagnosed = true;
  };
  explicit CauseModel(const Traits& traits) : traits_(traits) {}
  virtual ~CauseModel() = default;
  Cause id() const { return traits_.id; }
  const char* name() const { return traits_.name; }
  Subject subject() const { return traits_.subject; }
  Driver driver() const { return traits_.driver; }
  bool diagnosed() const { return traits_.diagnosed; }  // in extensionCauses()

  // Whether an extension on `joint` applies to `model` with these data (a thermal driver or not); Subject and the
  // driver are checked here, a cause adds its own conditions in appliesTo(). whyNot: appended to "does not apply to
  // <robot>" when it does not.
  bool applicable(const RobotModel& model, int joint, bool has_thermal) const;
  virtual std::string whyNot(const RobotModel& model, int joint, bool has_thermal) const;

  virtual int numParams(const RobotModel& model, int joint) const = 0;
  virtual std::vector<std::string> paramNames(const RobotModel& model, int joint) const = 0;
  // B of one observation; B is model.numParams() x numParams(model, joint) and zero on entry.
  virtual void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const = 0;

  // Whether `mine` and `other` cannot be in one model (they share parameters). Default: same cause and joint.
  virtual bool conflicts(const Extension& mine, const Extension& other) const;
  // diagnose's label: "backlash joint 3".
  virtual std::string label(const Extension& ext) const;
  // The joint whose angle bounds the regions diagnose judges the cause on beyond its data; -1: halves of the
  // workspace. Default: the joint of a kJoint cause.
  virtual int regionJoint(const Extension& ext) const;
  // For an extension with no regionJoint (-1): the quantity whose range over a campaign bounds where it was fitted,
  // its value at a configuration (rangeValue) and its name with its unit (rangeLabel; thermal_source as
  // DiagnosisData's). Beyond that range its form was never put to the test (extensionTransfer judges it there on
  // folds, compensation refuses farther). Default: the thermal driver the extension sees (thermalDriverValue) for a
  // kThermal cause; NaN for the others (a joint's angle bounds them, or nothing does).
  virtual double rangeValue(const RobotModel& model, const Eigen::VectorXd& params, const Extension& ext,
                            const Eigen::VectorXd& q_rad, const Drivers& drivers) const;
  virtual std::string rangeLabel(const Extension& ext, const std::string& thermal_source) const;

  // diagnose's signature figure (see SignatureRow). Default x: the joint's angle (deg) for kJointAngle, the thermal
  // driver for kThermal; a cause with another driver says its own.
  virtual std::string signatureXLabel(const RobotModel& model, int joint, const std::string& thermal_source) const;
  virtual double signatureX(const SignatureRow& at) const;
  // Default: the apparent error of the joint's zero (deg), or of the lengths' scale (um/m) without a joint.
  virtual std::string signatureYLabel(int joint) const;
  virtual SignatureAxis signatureAxis(const SignatureRow& at) const;

 protected:
  virtual bool appliesTo(const RobotModel&, int /*joint*/, bool /*has_thermal*/) const { return true; }

 private:
  Traits traits_;
};

// The registry: every cause of cause_list.hpp, in its order. causeModel throws std::invalid_argument for kNone.
const std::vector<const CauseModel*>& causeModels();
const CauseModel& causeModel(Cause cause);

// Each cause's file defines its accessor (one per line of cause_list.hpp), with CELLCAL_DEFINE_CAUSE(stem, Class).
#define CELLCAL_DECLARE_CAUSE(enumerator, stem) const CauseModel& stem##Cause();
CELLCAL_CAUSES(CELLCAL_DECLARE_CAUSE)
#undef CELLCAL_DECLARE_CAUSE
#define CELLCAL_DEFINE_CAUSE(stem, Class) \
  const CauseModel& stem##Cause() {       \
    static const Class instance;          \
    return instance;                      \
  }

}  // namespace cellcal
