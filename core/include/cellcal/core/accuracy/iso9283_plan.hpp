// The ISO 9283 test's geometry: a cube in the robot's workspace (edges along the base frame's axes), one of its four
// diagonal planes, and the five test poses on it, reached with one tool orientation; and the joints that reach them.
//
// Corners, from the cube's lowest corner in units of its edge: C1 (0,0,0), C2 (1,0,0), C3 (1,1,0), C4 (0,1,0),
// C5 (0,0,1), C6 (1,0,1), C7 (1,1,1), C8 (0,1,1). The planes: 1 C1-C2-C7-C8, 2 C2-C3-C8-C5, 3 C3-C4-C5-C6,
// 4 C4-C1-C6-C7 (each through two opposite edges). P1 is the cube's centre (where the plane's diagonals cross); P2 to
// P5 lie on the plane's diagonals at 10 % of the diagonal's length from its corners, P2 by the plane's first corner
// and on around it (plane 1: P2 by C1, P3 by C2, P4 by C7, P5 by C8), so the standard's cycle P1 -> P5 -> P4 -> P3
// -> P2 goes around the plane.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

struct IsoCube {
  Eigen::Vector3d centre_m = Eigen::Vector3d::Zero();  // in the robot's base frame
  double edge_m = 0;
  Eigen::Matrix3d orientation = Eigen::Matrix3d::Identity();  // the tool's (target's) orientation at every pose
};

std::array<Eigen::Vector3d, 8> isoCubeCorners(const IsoCube& cube);
// P1..P5 of `plane` (1..4) in the base frame, with the cube's orientation. Throws std::invalid_argument for a plane
// outside 1..4.
std::array<Pose, 5> isoTestPoses(const IsoCube& cube, int plane);
// The standard's order of the poses in one cycle: P1, P5, P4, P3, P2 (0-based indices into isoTestPoses).
constexpr std::array<int, 5> kIsoCycleOrder = {0, 4, 3, 2, 1};
// A multi-directional test (vAP): cycles in these three orders in turn, so that each pose is approached from three
// other test poses (P1 from P2, P5 and P4 at the ends of the orders before it; P2 from P3, P1 and P5; ...), 0-based.
constexpr std::array<std::array<int, 5>, 3> kIsoDirectionOrders = {{{0, 4, 3, 2, 1}, {0, 1, 2, 3, 4}, {0, 2, 4, 1, 3}}};

struct IsoPlanOptions {
  std::optional<Eigen::Vector3d> centre_m;  // given: the cube is centred there (base frame)
  std::optional<double> edge_m;             // given: that edge, else the largest reached (up to max_edge_m)
  int plane = 1;
  double max_edge_m = 1.0;
  double min_z_m = 0.0;         // every corner above this height in the base frame (the robot's floor)
  double min_radius_m = 0.2;    // and this far from the base frame's z axis (beside the robot, not around it)
  int candidates = 200;         // random configurations tried as the cube's centre and tool orientation, the best
                                // then moved and turned in shrinking steps while a larger cube fits
  std::uint64_t seed = 1;
  double edge_resolution_m = 1e-3;  // the largest edge is found to this
  bool IsValid(std::string* error) const;
};

struct IsoPlan {
  IsoCube cube;
  int plane = 1;
  std::array<Pose, 5> poses;        // P1..P5, base frame
  std::array<Eigen::VectorXd, 5> q_rad;  // joints that reach them (one branch: each solved from P1's joints)
  double worst_position_error_m = 0, worst_orientation_error_rad = 0;  // forward kinematics of q_rad against poses
  int candidates_tried = 0;
  int refinements = 0;  // moves of the best candidate's centre or orientation that let a larger cube fit
};

// The cube and the joints of its test poses for `params` (base frame ignored: poses in the robot's base frame; the
// tool frame is the target). Every corner and the centre must be reached within the joint limits with the cube's
// orientation, and P2..P5 too, each along the straight line from the centre (solved in steps of 25 mm from the
// centre's joints: one branch, no flip between the test poses). Throws std::invalid_argument when no cube is reached (a given centre or edge out of
// reach: the message names the pose and how far the closest reached pose is from it).
IsoPlan planIso9283(const RobotModel& model, const Eigen::VectorXd& params, const IsoPlanOptions& options);

}  // namespace cellcal
