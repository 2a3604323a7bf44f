#include "cellcal/core/accuracy/iso9283_plan.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {
namespace {

// The plane's corners (indices into isoCubeCorners) in the order P2..P5 sit by them.
constexpr int kPlaneCorners[4][4] = {{0, 1, 6, 7}, {1, 2, 7, 4}, {2, 3, 4, 5}, {3, 0, 5, 6}};

Pose at(const Eigen::Vector3d& p, const Eigen::Matrix3d& R) {
  Pose T = Pose::Identity();
  T.linear() = R;
  T.translation() = p;
  return T;
}

// The points a cube must reach: its centre, the eight corners, P2..P5 of the plane; with their names.
std::vector<std::pair<std::string, Pose>> cubePoints(const IsoCube& cube, int plane) {
  std::vector<std::pair<std::string, Pose>> out;
  const auto corners = isoCubeCorners(cube);
  const auto poses = isoTestPoses(cube, plane);
  out.emplace_back("P1 (the centre)", poses[0]);
  for (int k = 0; k < 8; ++k) out.emplace_back("corner C" + std::to_string(k + 1), at(corners[static_cast<size_t>(k)], cube.orientation));
  for (int k = 1; k < 5; ++k) out.emplace_back("P" + std::to_string(k + 1), poses[static_cast<size_t>(k)]);
  return out;
}

// The joints at `target` reached from the centre's joints along the straight line to it (the orientation is the
// same at every point of the cube), in steps of at most kStep_m, each solved from the one before: the robot keeps its
// branch (no wrist or elbow flip between the test poses) and the whole segment is within reach.
constexpr double kStep_m = 0.025;
IkResult alongLine(const RobotModel& model, const Eigen::VectorXd& params, const Pose& centre, const Eigen::VectorXd& centre_q,
                   const Pose& target, const IkOptions& ik) {
  const Eigen::Vector3d d = target.translation() - centre.translation();
  const int steps = std::max(1, static_cast<int>(std::ceil(d.norm() / kStep_m)));
  IkResult r;
  r.status = IkStatus::kSolved;
  r.q_rad = centre_q;
  for (int k = 1; k <= steps && r.ok(); ++k) {
    Pose T = target;
    T.translation() = centre.translation() + d * (static_cast<double>(k) / steps);
    r = solveInverseKinematics(model, params, T, r.q_rad, ik);
  }
  return r;
}

// Whether every point of the cube is reached from the centre's joints; the first one that is not, with why.
bool reached(const RobotModel& model, const Eigen::VectorXd& params, const IsoCube& cube, int plane,
             const Eigen::VectorXd& centre_q, const IkOptions& ik, std::string* why) {
  const Pose centre = at(cube.centre_m, cube.orientation);
  for (const auto& [name, T] : cubePoints(cube, plane)) {
    const IkResult r = alongLine(model, params, centre, centre_q, T, ik);
    if (!r.ok()) {
      if (why) *why = name + ": " + r.message;
      return false;
    }
  }
  return true;
}

}  // namespace

bool IsoPlanOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (plane < 1 || plane > 4) return fail("plane must be 1, 2, 3 or 4");
  if (edge_m && !(*edge_m > 0 && std::isfinite(*edge_m))) return fail("the cube's edge must be > 0");
  if (centre_m && !centre_m->allFinite()) return fail("the cube's centre must be finite");
  if (!(max_edge_m > 0) || !(edge_resolution_m > 0) || edge_resolution_m >= max_edge_m)
    return fail("max_edge_m > edge_resolution_m > 0");
  if (candidates < 1) return fail("candidates must be >= 1");
  if (!std::isfinite(min_z_m)) return fail("min_z_m must be finite");
  if (!(min_radius_m >= 0)) return fail("min_radius_m must be >= 0");
  return true;
}

std::array<Eigen::Vector3d, 8> isoCubeCorners(const IsoCube& cube) {
  static const double unit[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
  std::array<Eigen::Vector3d, 8> c;
  const Eigen::Vector3d low = cube.centre_m - Eigen::Vector3d::Constant(cube.edge_m / 2);
  for (int k = 0; k < 8; ++k) c[static_cast<size_t>(k)] = low + cube.edge_m * Eigen::Vector3d(unit[k][0], unit[k][1], unit[k][2]);
  return c;
}

std::array<Pose, 5> isoTestPoses(const IsoCube& cube, int plane) {
  if (plane < 1 || plane > 4) throw std::invalid_argument("ISO 9283 test plane " + std::to_string(plane) + ": expected 1 to 4");
  const auto c = isoCubeCorners(cube);
  std::array<Pose, 5> p;
  p[0] = at(cube.centre_m, cube.orientation);
  for (int k = 0; k < 4; ++k) {
    // On the diagonal from the corner through the centre, 10 % of the diagonal's length from the corner.
    const Eigen::Vector3d corner = c[static_cast<size_t>(kPlaneCorners[plane - 1][k])];
    p[static_cast<size_t>(k) + 1] = at(corner + 0.2 * (cube.centre_m - corner), cube.orientation);
  }
  return p;
}

namespace {

// The best cube's centre moved and its orientation turned a little while that lets a larger cube fit (a random search
// alone leaves a third of the edge on the table), in shrinking steps; best_q: the joints at its centre.
void growCube(const RobotModel& model, const Eigen::VectorXd& p0, const IsoPlanOptions& o, const IkOptions& search,
              IsoPlan& best, Eigen::VectorXd& best_q) {
  double step_m = 0.05, step_rad = degToRad(8);
  while (step_m > 2e-3) {
    bool improved = false;
    for (int move = 0; move < 12; ++move) {
      IsoCube cube = best.cube;
      const double sign = move % 2 ? -1 : 1;
      const int axis = (move / 2) % 3;
      if (move < 6) {
        if (o.centre_m) continue;  // a given centre stays
        cube.centre_m[axis] += sign * step_m;
      } else {
        cube.orientation = Eigen::AngleAxisd(sign * step_rad, Eigen::Vector3d::Unit(axis)) * cube.orientation;
      }
      const IkResult r = solveInverseKinematics(model, p0, at(cube.centre_m, cube.orientation), best_q, search);
      if (!r.ok()) continue;
      double lo = best.cube.edge_m + o.edge_resolution_m;
      double hi = std::min({o.max_edge_m, 2 * (cube.centre_m.z() - o.min_z_m),
                            std::sqrt(2.0) * (cube.centre_m.head<2>().norm() - o.min_radius_m)});
      if (lo > hi) continue;
      cube.edge_m = lo;
      if (!reached(model, p0, cube, o.plane, r.q_rad, search, nullptr)) continue;
      while (hi - lo > o.edge_resolution_m) {
        cube.edge_m = 0.5 * (lo + hi);
        (reached(model, p0, cube, o.plane, r.q_rad, search, nullptr) ? lo : hi) = cube.edge_m;
      }
      cube.edge_m = lo;
      best.cube = cube;
      best_q = r.q_rad;
      ++best.refinements;
      improved = true;
    }
    if (!improved) {
      step_m /= 2;
      step_rad /= 2;
    }
  }
}

}  // namespace

IsoPlan planIso9283(const RobotModel& model, const Eigen::VectorXd& params, const IsoPlanOptions& o) {
  std::string error;
  if (!o.IsValid(&error)) throw std::invalid_argument("IsoPlanOptions: " + error);
  // Poses in the robot's base frame: the base frame's parameters at zero.
  Eigen::VectorXd p0 = params;
  p0.segment<6>(model.baseParam(FrameParam::kX)).setZero();
  KinematicsData data(model);
  IkOptions search;  // while searching, fewer restarts: a point a near start does not reach is taken as out of reach
  search.restarts = 2;
  search.max_iterations = 200;
  search.position_tolerance_m = 1e-8;
  search.orientation_tolerance_rad = 1e-8;
  std::mt19937_64 rng(o.seed);
  IsoPlan best;
  std::optional<Eigen::VectorXd> best_q;
  std::string last_why;
  const int n = model.numJoints();
  for (int k = 0; k < o.candidates; ++k) {
    // A random configuration within the inner 90 % of each joint's range: its tool orientation, and its position as
    // the centre unless one is given (then its joints seed the centre's solution).
    Eigen::VectorXd q(n);
    for (int j = 0; j < n; ++j) {
      const double lo = model.limits[static_cast<size_t>(j)].lower_rad, hi = model.limits[static_cast<size_t>(j)].upper_rad;
      const double mid = 0.5 * (lo + hi), half = 0.45 * (hi - lo);
      q[j] = std::uniform_real_distribution<double>(mid - half, mid + half)(rng);
    }
    const Pose T = forwardKinematics(model, data, p0, q);
    IsoCube cube;
    cube.orientation = T.linear();
    cube.centre_m = o.centre_m ? *o.centre_m : T.translation();
    ++best.candidates_tried;
    if (o.centre_m) {
      const IkResult r = solveInverseKinematics(model, p0, at(cube.centre_m, cube.orientation), q, search);
      if (!r.ok()) {
        last_why = "P1 (the centre): " + r.message;
        continue;
      }
      q = r.q_rad;
    }
    // The lowest corners stay above min_z_m; the nearest stay min_radius_m from the base frame's z axis (joint 1's:
    // the cube stands beside the robot, not around its column).
    const double room = std::min(2 * (cube.centre_m.z() - o.min_z_m),
                                 std::sqrt(2.0) * (cube.centre_m.head<2>().norm() - o.min_radius_m));
    if (o.edge_m) {
      cube.edge_m = *o.edge_m;
      if (cube.edge_m > room) {
        last_why = "the cube reaches below min_z or within min_radius of the base's z axis (its centre at " +
                   std::to_string(cube.centre_m.z() * 1e3) + " mm up, " +
                   std::to_string(cube.centre_m.head<2>().norm() * 1e3) + " mm out)";
        continue;
      }
      if (!reached(model, p0, cube, o.plane, q, search, &last_why)) continue;
      best.cube = cube;
      best_q = q;
      break;
    }
    // The largest edge: only worth bisecting when it beats the best so far.
    double lo = best_q ? best.cube.edge_m + o.edge_resolution_m : o.edge_resolution_m;
    double hi = std::min(o.max_edge_m, room);
    if (lo > hi) continue;
    cube.edge_m = lo;
    if (!reached(model, p0, cube, o.plane, q, search, &last_why)) continue;
    while (hi - lo > o.edge_resolution_m) {
      cube.edge_m = 0.5 * (lo + hi);
      (reached(model, p0, cube, o.plane, q, search, nullptr) ? lo : hi) = cube.edge_m;
    }
    cube.edge_m = lo;
    best.cube = cube;
    best_q = q;
  }
  if (best_q && !o.edge_m) growCube(model, p0, o, search, best, *best_q);
  if (!best_q)
    throw std::invalid_argument(std::string(o.edge_m ? "the cube of that edge" : "no cube") + " is reached within the joint limits with one tool orientation (" +
                                std::to_string(best.candidates_tried) + " tool orientations tried" +
                                (o.centre_m ? " at the given centre" : "") + "); last: " + last_why);
  // The test poses, each solved to the full tolerance from the centre's joints (one branch).
  best.plane = o.plane;
  best.poses = isoTestPoses(best.cube, o.plane);
  const IkOptions exact;
  for (int k = 0; k < 5; ++k) {
    const IkResult r = k == 0 ? solveInverseKinematics(model, p0, best.poses[0], *best_q, exact)
                              : alongLine(model, p0, best.poses[0], best.q_rad[0], best.poses[static_cast<size_t>(k)], exact);
    if (!r.ok())
      throw std::invalid_argument("P" + std::to_string(k + 1) + " of the chosen cube: " + r.message);
    best.q_rad[static_cast<size_t>(k)] = r.q_rad;
    const Pose F = forwardKinematics(model, data, p0, r.q_rad);
    best.worst_position_error_m =
        std::max(best.worst_position_error_m, (F.translation() - best.poses[static_cast<size_t>(k)].translation()).norm());
    best.worst_orientation_error_rad = std::max(
        best.worst_orientation_error_rad, logSO3(F.linear() * best.poses[static_cast<size_t>(k)].linear().transpose()).norm());
  }
  return best;
}

}  // namespace cellcal
