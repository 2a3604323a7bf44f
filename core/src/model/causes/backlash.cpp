// backlash: dq_j = e_0 * s_j / 2 with s_j in [-1, 1] the play state of joint j (|e_0|: the width, rad): +-1 after the
// joint moved more than the width in the + / - direction; a smaller move crosses the gap only partly,
// s_j <- clamp(s_j + 2 step / width, -1, 1) (playState in model_extension.hpp). s_j depends on the width, so the
// basis is evaluated at a width (fitExtended iterates it with the fit); width 0 is the direction the joint last moved
// (Drivers::motion_direction). A row whose joint has not moved since the data began has an unknown play state.
#include "cause_support.hpp"

namespace cellcal {
namespace {

class Backlash final : public CauseModel {
 public:
  Backlash() : CauseModel({Cause::kBacklash, "backlash", Subject::kJoint, Driver::kPath}) {}

  int numParams(const RobotModel&, int) const override { return 1; }
  std::vector<std::string> paramNames(const RobotModel&, int joint) const override {
    return {causes::jointPrefix(joint) + "backlash_width_rad"};
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    B(causes::thetaRow(at.model, at.ext.joint), 0) = 0.5 * playState(at.drivers, at.ext.joint, at.backlash_width_rad);
  }

  std::string signatureXLabel(const RobotModel&, int joint, const std::string&) const override {
    return "direction joint " + std::to_string(joint + 1) + " last moved (-1 / +1)";
  }
  // The direction, spread by +-0.15 (golden-ratio steps over the rows) so the two clusters show their rows.
  double signatureX(const SignatureRow& at) const override {
    const double spread = std::fmod(0.6180339887 * static_cast<double>(at.row), 1.0) - 0.5;
    return (at.drivers.motion_direction.size() > at.joint ? at.drivers.motion_direction[at.joint] : 0.0) + 0.3 * spread;
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(backlash, Backlash)

}  // namespace cellcal
