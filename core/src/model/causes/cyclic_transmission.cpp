// cyclic_transmission: dq_j = e_0 sin q_j + e_1 cos q_j + e_2 sin 2q_j + e_3 cos 2q_j (the once- and twice-per-turn
// error of a gear train or an eccentric encoder).
#include "cause_support.hpp"

namespace cellcal {
namespace {

class CyclicTransmission final : public CauseModel {
 public:
  CyclicTransmission() : CauseModel({Cause::kCyclicTransmission, "cyclic_transmission", Subject::kJoint, Driver::kJointAngle}) {}

  int numParams(const RobotModel&, int) const override { return 4; }
  std::vector<std::string> paramNames(const RobotModel&, int joint) const override {
    const std::string j = causes::jointPrefix(joint);
    return {j + "sin1_rad", j + "cos1_rad", j + "sin2_rad", j + "cos2_rad"};
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    const int th = causes::thetaRow(at.model, at.ext.joint);
    const double q = at.q_rad[at.ext.joint];
    B(th, 0) = std::sin(q);
    B(th, 1) = std::cos(q);
    B(th, 2) = std::sin(2 * q);
    B(th, 3) = std::cos(2 * q);
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(cyclicTransmission, CyclicTransmission)

}  // namespace cellcal
