// Immutable description of a serial robot in the tracker cell (Pinocchio-style "Model").
//
// Kinematic parameter vector (SI: metres, radians), size 5*n + 12, layout:
//   [5*j + 0] theta_offset of joint j   (theta_j = q_j + theta_offset_j)
//   [5*j + 1] d   [5*j + 2] a   [5*j + 3] alpha   [5*j + 4] beta          for j = 0..n-1 (base to flange)
//   [5*n + 0..5]  base_in_tracker  x, y, z, roll, pitch, yaw
//   [5*n + 6..11] tool_in_flange   x, y, z, roll, pitch, yaw
// Link transform of every joint: A_j = Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta).
// For a joint that is parallel_to_next, d is not a model parameter (fixed at 0, Hayati's modification uses beta);
// for the other joints beta is not (fixed at 0, classic DH). Those two are "non-canonical": the Jacobian still has
// their columns, but identification never estimates them (they are exactly redundant with canonical ones).
// Frames: T = Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll); pose = base_in_tracker * mount * A_1 ... A_n * flange *
// tool_in_flange, where mount and flange are fixed transforms (not parameters; zero for a robot written as DH).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace cellcal {

enum class JointParam { kThetaOffset = 0, kD = 1, kA = 2, kAlpha = 3, kBeta = 4 };
enum class FrameParam { kX = 0, kY = 1, kZ = 2, kRoll = 3, kPitch = 4, kYaw = 5 };

struct JointLimits {
  double lower_rad = -3.14159265358979323846;
  double upper_rad = 3.14159265358979323846;
};

// Optional mass properties of link j, expressed in DH frame j (after A_j); for gravity-dependent effects.
struct LinkInertia {
  double mass_kg = 0.0;
  Eigen::Vector3d com_m = Eigen::Vector3d::Zero();
};

class RobotModel {
 public:
  std::string name;
  std::vector<bool> parallel_to_next;   // one per joint
  std::vector<JointLimits> limits;      // one per joint
  std::vector<LinkInertia> links;       // empty, or one per joint
  Eigen::Vector3d gravity_in_base_mps2 = Eigen::Vector3d(0, 0, -9.81);
  Eigen::VectorXd nominal;              // kinematic parameter vector, layout above
  // Fixed transforms around the DH chain, x, y, z, roll, pitch, yaw (SI, as the frames): mount from the robot's base
  // link to DH frame 0, flange from DH frame n to its flange link. Zero for a robot file written as DH; a URDF's
  // joint axes and rotated origins can leave them (files/urdf.hpp), so that base_in_tracker stays the base link in the
  // tracker frame and tool_in_flange the target on the flange link. Never identified.
  Eigen::Matrix<double, 6, 1> mount = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> flange = Eigen::Matrix<double, 6, 1>::Zero();
  std::vector<std::string> joint_names;  // empty, or one per joint (a URDF's joint names)
  bool hasMount() const { return !mount.isZero(0.0); }
  bool hasFlange() const { return !flange.isZero(0.0); }

  int numJoints() const { return static_cast<int>(parallel_to_next.size()); }
  int numParams() const { return 5 * numJoints() + 12; }

  int jointParam(int joint, JointParam p) const { return 5 * joint + static_cast<int>(p); }
  int baseParam(FrameParam p) const { return 5 * numJoints() + static_cast<int>(p); }
  int toolParam(FrameParam p) const { return 5 * numJoints() + 6 + static_cast<int>(p); }

  // "joint3.a_m", "base.yaw_rad", "tool.x_m" (joints numbered from 1, as on a datasheet).
  std::string paramName(int index) const;
  // Same name with the human unit: "joint3.a_mm", "base.yaw_deg".
  std::string paramNameHuman(int index) const;
  // Value in human units (mm or deg) of a parameter expressed in SI.
  double toHuman(int index, double value_si) const;
  bool isLength(int index) const;
  // False for d of a parallel_to_next joint and beta of any other joint (see above).
  bool isCanonical(int index) const;
  std::vector<int> canonicalParams() const;

  // Structural checks (sizes, finite values, limits ordered, d = 0 on parallel joints).
  bool IsValid(std::string* error) const;

  // Model with other kinematic parameters (same structure).
  RobotModel withParams(const Eigen::VectorXd& params) const;
  // q within limits (inclusive)?
  bool withinLimits(const Eigen::VectorXd& q_rad) const;
};

}  // namespace cellcal
