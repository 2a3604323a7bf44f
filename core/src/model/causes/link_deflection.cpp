// link_deflection: link j (the segment between the axes of joints j and j+1, 1-based; one of 200 mm or more that
// gravity loads across) bends as a beam under the gravity across it, g_perp = the part of gravity (in g) perpendicular
// to the link, the elastostatic model of elasto-geometric calibration: its far end moves by e_0 g_perp (e_0: the sag
// of the link held horizontal, m) and turns by e_1 about u x g_perp (u: the link's direction; e_1: the slope at its
// end when horizontal, rad). The load of the links beyond adds a moment that depends on their pose: that part acts as
// joint_compliance of joint j+1. A Cartesian motion, not a joint error: B is the minimum-norm parameter change that
// moves the target by that twist (first order; J B e = the twist).
#include <Eigen/Cholesky>
#include <algorithm>
#include <random>

#include "cause_support.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {
namespace {

class LinkDeflection final : public CauseModel {
 public:
  LinkDeflection() : CauseModel({Cause::kLinkDeflection, "link_deflection", Subject::kLink, Driver::kGravity}) {}

  std::string whyNot(const RobotModel& model, int joint, bool has_thermal) const override {
    const std::string l = std::to_string(joint + 1);
    return CauseModel::whyNot(model, joint, has_thermal) + " (link " + l + ", between the axes of joints " + l +
           " and " + std::to_string(joint + 2) + ", is shorter than 200 mm or never held across gravity)";
  }
  int numParams(const RobotModel&, int) const override { return 2; }
  std::vector<std::string> paramNames(const RobotModel&, int joint) const override {
    const std::string l = "link" + std::to_string(joint + 1) + ".";
    return {l + "sag_m", l + "tip_slope_rad"};
  }
  void basis(const BasisPoint& at, Eigen::Ref<Eigen::MatrixXd> B) const override {
    // The twist the bending gives the target (translation, rotation; tracker frame), then the minimum-norm parameter
    // change with that first-order effect: B = J^T (J J^T)^-1 G.
    const RobotModel& model = at.model;
    const std::vector<Pose> F = chainFrames(model, at.params, at.q_rad);
    const causes::LinkLoad l = causes::linkLoad(model, F, at.ext.joint);
    const Eigen::Vector3d target = F.back().translation();
    Eigen::Matrix<double, 6, 2> G;
    const Eigen::Vector3d w = l.direction.cross(l.across);
    G.col(0) << l.across, Eigen::Vector3d::Zero();
    G.col(1) << w.cross(target - l.far_end), w;
    KinematicsData data(model);
    forwardKinematics(model, data, at.params, at.q_rad);
    Eigen::MatrixXd J(6, model.numParams());
    computePoseJacobian(model, data, J);
    B = J.transpose() * (J * J.transpose()).ldlt().solve(G);
  }

  std::string label(const Extension& ext) const override {
    return std::string(name()) + " link " + std::to_string(ext.joint + 1);
  }
  std::string signatureXLabel(const RobotModel&, int joint, const std::string&) const override {
    return "gravity across link " + std::to_string(joint + 1) + " (g)";
  }
  std::string signatureYLabel(int joint) const override {
    return "position error along the gravity across link " + std::to_string(joint + 1) + " (mm)";
  }
  double signatureX(const SignatureRow& at) const override { return across(at).norm(); }
  double rangeValue(const RobotModel& model, const Eigen::VectorXd& params, const Extension& ext,
                    const Eigen::VectorXd& q_rad, const Drivers&) const override {
    return causes::linkLoad(model, chainFrames(model, params, q_rad), ext.joint).across.norm();
  }
  std::string rangeLabel(const Extension& ext, const std::string&) const override {
    return "gravity across link " + std::to_string(ext.joint + 1) + " (g)";
  }
  SignatureAxis signatureAxis(const SignatureRow& at) const override {
    const Eigen::Vector3d a = across(at);
    SignatureAxis axis;
    axis.direction = a / std::max(a.norm(), 1e-12);
    axis.scale = 1e3;
    axis.unit = true;
    return axis;
  }

 protected:
  // A link of beam length that gravity can load across: over configurations spread through the limits, the gravity
  // across it reaches 0.3 g.
  bool appliesTo(const RobotModel& model, int j, bool) const override {
    if (j >= model.numJoints() - 1 || linkLength(model, model.nominal, j) < causes::kMinBeamLengthM) return false;
    std::mt19937_64 rng(20261128);
    for (int s = 0; s < 64; ++s) {
      Eigen::VectorXd q(model.numJoints());
      for (int k = 0; k < model.numJoints(); ++k)
        q[k] = std::uniform_real_distribution<double>(std::max(model.limits[k].lower_rad, -kPi),
                                                      std::min(model.limits[k].upper_rad, kPi))(rng);
      if (causes::linkLoad(model, chainFrames(model, model.nominal, q), j).across.norm() > 0.3) return true;
    }
    return false;
  }

 private:
  static Eigen::Vector3d across(const SignatureRow& at) {
    return causes::linkLoad(at.model, chainFrames(at.model, at.params, at.q_rad), at.joint).across;
  }
};

}  // namespace

CELLCAL_DEFINE_CAUSE(linkDeflection, LinkDeflection)

}  // namespace cellcal
