// joint_scale: dq_j = e_0 q_j (a transmission-ratio error).
#include "cause_support.hpp"

namespace cellcal {
namespace {

class JointScale final : public CauseModel {
 public:
  JointScale() : CauseModel({Cause::kJointScale, "joint_scale", Subject::kJoint, Driver::kJointAngle}) {}

  int numParams(const RobotModel&, int) const override { return 1; }
  std::vector<std::string> paramNames(const RobotModel&, int joint) const override {
    return {causes::jointPrefix(joint) + "scale_ratio"};
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    B(causes::thetaRow(at.model, at.ext.joint), 0) = at.q_rad[at.ext.joint];
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(jointScale, JointScale)

}  // namespace cellcal
