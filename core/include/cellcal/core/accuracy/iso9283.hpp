// ISO 9283 pose and distance characteristics from measured poses: what a production line accepts a robot by.
//
// A test pose is visited n times (cycles); each visit gives the commanded pose (what the controller, or a calibrated
// model, believes the joints reach) and the attained pose (measured, in the same frame). Per test pose:
//   AP_x = x̄ - x_c, AP_y, AP_z;  AP_p = sqrt(AP_x² + AP_y² + AP_z²)   (pose accuracy: barycentre against command)
//   AP_a = ā - a_c, AP_b, AP_c                                       (orientation: about the frame's x, y, z)
//   l_j = |P_j - P̄|,  RP_l = l̄ + 3 S_l,  S_l = sqrt(Σ (l_j - l̄)² / (n - 1))   (pose repeatability)
//   RP_a = ±3 S_a, S_a = sqrt(Σ (a_j - ā)² / (n - 1)), likewise b, c
//   vAP_p = max over approach directions h, k of |P̄_h - P̄_k|; vAP_a = max |ā_h - ā_k|, ...  (multi-directional)
// Between two test poses visited in the same cycles (D_j the distance of their attained positions in cycle j):
//   AD_p = D̄ - D_c;  AD_x = D̄_x - D_cx, ...;  RD = ±3 S_D, S_D = sqrt(Σ (D_j - D̄)² / (n - 1)).
// Each visit is taken relative to its own commanded pose (position deviation P_j - P_cj; orientation a_j, b_j, c_j
// the roll, pitch and yaw of R_attained R_commanded^T, about the frame's x, y, z), so visits whose joint readings
// differ slightly still count at one pose, and no angle wraps; for equal commands this is the standard's x̄ - x_c and
// ā - a_c to first order in the deviations (1e-8 rad at 1e-4 rad).
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/model/se3.hpp"

namespace cellcal {

struct Iso9283Visit {
  Pose commanded = Pose::Identity();
  Pose attained = Pose::Identity();
  bool has_orientation = true;  // false: a position reading (the orientation figures are left out)
  int cycle = 0;                // pairs the visits of two poses for AD and RD
  std::string approach;         // the direction it was approached from (vAP groups by it); "" = not known
};

struct Iso9283PoseInput {
  std::string name;  // P1..P5 in the standard's test
  std::vector<Iso9283Visit> visits;
};

struct Iso9283Pose {
  std::string name;
  int n = 0;
  bool oriented = false;  // every visit had an orientation: the a, b, c figures are given
  Eigen::Vector3d AP_xyz_m = Eigen::Vector3d::Zero();
  double AP_p_m = 0;
  Eigen::Vector3d AP_abc_rad = Eigen::Vector3d::Zero();
  double l_mean_m = 0, S_l_m = 0, RP_l_m = 0;
  Eigen::Vector3d S_abc_rad = Eigen::Vector3d::Zero(), RP_abc_rad = Eigen::Vector3d::Zero();  // RP_a = 3 S_a (±)
  int directions = 0;                      // distinct known approach directions
  std::optional<double> vAP_p_m;           // given with 2 directions or more
  std::optional<Eigen::Vector3d> vAP_abc_rad;
  std::vector<Eigen::Vector3d> deviations_m;  // P_j - P_cj per visit (the cloud of a report's figure)
};

struct Iso9283Distance {
  std::string from, to;
  int n = 0;               // cycles both poses have
  double D_c_m = 0;        // commanded distance (mean over the cycles)
  double D_mean_m = 0;     // D̄
  double AD_p_m = 0;       // D̄ - D_c
  Eigen::Vector3d AD_xyz_m = Eigen::Vector3d::Zero();
  double S_D_m = 0, RD_m = 0;  // RD = 3 S_D (±)
};

// Throws std::invalid_argument naming the pose: fewer than 2 visits, a non-finite pose.
Iso9283Pose iso9283Pose(const Iso9283PoseInput& input);

// The visits of `from` and `to` paired by cycle (each cycle once per pose). Throws std::invalid_argument naming the
// poses when fewer than 2 cycles pair or a cycle appears twice at one pose.
Iso9283Distance iso9283Distance(const Iso9283PoseInput& from, const Iso9283PoseInput& to);

// The roll, pitch and yaw (about x, y, z of the frame) of `attained` relative to `commanded`: of R_a R_c^T.
Eigen::Vector3d orientationDeviation(const Pose& attained, const Pose& commanded);

}  // namespace cellcal
