// joint_compliance: dq_j = compliance * tau_j(q), the gravity torque on joint j. With link masses in the robot file,
// one parameter (rad per N m) times the torque of those masses. Without, the gravity regressor of the links beyond
// joint j: per link i, its mass and first moment (m, m c) in frame i times the compliance, 4 parameters per link (the
// data decide which combinations are identifiable). Applies to a joint gravity loads (not a vertical first axis).
#include "cause_support.hpp"

namespace cellcal {
namespace {

class JointCompliance final : public CauseModel {
 public:
  JointCompliance() : CauseModel({Cause::kJointCompliance, "joint_compliance", Subject::kJoint, Driver::kGravity}) {}

  std::string whyNot(const RobotModel& model, int joint, bool has_thermal) const override {
    return CauseModel::whyNot(model, joint, has_thermal) + " (gravity does not load that joint)";
  }
  int numParams(const RobotModel& model, int joint) const override {
    return model.links.empty() ? 4 * (model.numJoints() - joint) : 1;
  }
  std::vector<std::string> paramNames(const RobotModel& model, int joint) const override {
    const std::string j = causes::jointPrefix(joint);
    if (!model.links.empty()) return {j + "compliance_rad_per_Nm"};
    std::vector<std::string> out;
    for (int i = joint + 1; i <= model.numJoints(); ++i) {
      const std::string l = j + "compliance_link" + std::to_string(i);
      out.push_back(l + "_mass_rad_per_Nm_kg");
      for (const char* a : {"x", "y", "z"}) out.push_back(l + "_moment_" + a + "_rad_per_Nm_kg_m");
    }
    return out;
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    const RobotModel& model = at.model;
    const int j = at.ext.joint, th = causes::thetaRow(model, j);
    if (!model.links.empty()) {
      B(th, 0) = gravityTorques(model, at.params, at.q_rad)[j];
      return;
    }
    // Gravity regressor of the links beyond joint j: a mass m with centre l in frame i loads joint j with
    // m * torque(origin of frame i) + (m l) . R_i^T (g x z_j): linear in (m, m l), four parameters per link.
    const std::vector<Pose> F = chainFrames(model, at.params, at.q_rad);
    const Eigen::Vector3d g = causes::gravityInTracker(model, F);
    const Eigen::Vector3d gxz = g.cross(F[j].linear().col(2));
    for (int i = j + 1, c = 0; i <= model.numJoints(); ++i, c += 4) {
      B(th, c) = causes::unitTorque(F, j, F[i].translation(), g);
      B.block<1, 3>(th, c + 1) = (F[i].linear().transpose() * gxz).transpose();
    }
  }

  std::string signatureXLabel(const RobotModel& model, int joint, const std::string&) const override {
    const std::string jn = std::to_string(joint + 1);
    return model.links.empty() ? "gravity torque of 1 kg at the target on joint " + jn + " (N m/kg)"
                               : "gravity torque on joint " + jn + " (N m)";
  }
  double signatureX(const SignatureRow& at) const override {
    return complianceDriver(at.model, at.params, at.q_rad, at.joint);
  }

 protected:
  bool appliesTo(const RobotModel& model, int joint, bool) const override {
    return loadedByGravity(model, joint) && numParams(model, joint) > 0;
  }

 private:
  // Every joint but a first one whose axis is along gravity.
  static bool loadedByGravity(const RobotModel& model, int j) {
    if (j > 0) return true;
    const std::vector<Pose> F = chainFrames(model, model.nominal, Eigen::VectorXd::Zero(model.numJoints()));
    const Eigen::Vector3d z = F[0].linear().col(2), g = causes::gravityInTracker(model, F);
    return z.cross(g).norm() > 1e-6 * g.norm();
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(jointCompliance, JointCompliance)

}  // namespace cellcal
