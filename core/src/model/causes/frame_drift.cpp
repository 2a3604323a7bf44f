// frame_drift: not the robot's error: the base frame (the robot in the tracker's frame) moves with the thermal driver
// of thermal_drift, each of base x, y, z, roll, pitch, yaw by e_k * s (6 parameters; a tracker or a robot base that
// creeps). Never chosen by diagnose (not diagnosed()): it is the alternative each drift diagnose names is tested
// against (DriftCheck in diagnosis.hpp); a user may fit it by name.
#include "cause_support.hpp"

namespace cellcal {
namespace {

class FrameDrift final : public CauseModel {
 public:
  FrameDrift() : CauseModel({Cause::kFrameDrift, "frame_drift", Subject::kBase, Driver::kThermal, false}) {}

  int numParams(const RobotModel&, int) const override { return 6; }
  std::vector<std::string> paramNames(const RobotModel&, int) const override {
    return {"base.drift_x_m_per_unit",      "base.drift_y_m_per_unit",       "base.drift_z_m_per_unit",
            "base.drift_roll_rad_per_unit", "base.drift_pitch_rad_per_unit", "base.drift_yaw_rad_per_unit"};
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    const double s = thermalDriverValue(at.ext, at.drivers);
    for (int p = 0; p < 6; ++p) B(at.model.baseParam(static_cast<FrameParam>(p)), p) = s;
  }

  std::string label(const Extension& ext) const override {
    return std::string(name()) + " (base)" + causes::warmUpSuffix(ext);
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(frameDrift, FrameDrift)

}  // namespace cellcal
