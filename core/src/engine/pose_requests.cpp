#include "cellcal/core/engine/pose_requests.hpp"

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "cellcal/core/identification/pose_selection.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

PoseRequester::PoseRequester(const CellRobot& robot, const PoseRequestSettings& s, std::uint64_t seed)
    : robot_(&robot), settings_(s) {
  if (s.count < 1) throw std::invalid_argument("engine.pose_requests.count is 0: no pose is proposed");
  const RobotModel& m = robot.model;
  const Eigen::VectorXd& p = m.nominal;
  const auto b = p.segment<6>(m.baseParam(FrameParam::kX));
  tracker_in_base_m_ = poseFromXyzRpy(b[0], b[1], b[2], b[3], b[4], b[5]).inverse().translation();
  PosePlanOptions o;
  o.count = s.count;
  o.candidates = s.candidates;
  o.kind = robot.measurement;
  o.min_radius_m = s.min_radius_m;
  o.seed = seed;
  TrackerSetup t;
  t.position_in_base_m = tracker_in_base_m_;
  t.min_range_m = s.min_range_m;
  t.max_range_m = s.max_range_m > 0 ? s.max_range_m : std::numeric_limits<double>::infinity();
  t.link_radius_m = s.link_radius_m;
  t.acceptance_rad = s.acceptance_rad;
  o.tracker = t;
  std::string error;
  if (!o.IsValid(&error)) throw std::invalid_argument("engine.pose_requests: " + error);
  candidates_ = measurableCandidates(m, p, o);
  if (static_cast<int>(candidates_.q.size()) < s.count)
    throw std::invalid_argument("engine.pose_requests for " + robot.robot_id + ": " + candidates_.tooFewText(s.count, s.min_radius_m));
}

PoseProposal PoseRequester::propose(const CalibrationSnapshot& snap) const {
  PoseProposal out;
  out.version = snap.version;
  const auto n = static_cast<Eigen::Index>(snap.estimated.size());
  if (n == 0 || snap.covariance.rows() < n) return out;
  PoseSelectionOptions o;
  o.criterion = SelectionCriterion::kPredictionVariance;
  o.kind = robot_->measurement;
  o.sigma_position_m = settings_.sigma_position_m;
  o.sigma_orientation_rad = settings_.sigma_orientation_rad;
  SelectionFigures f;
  // The estimate's covariance is symmetric by construction; the block is copied once per proposal.
  const Eigen::MatrixXd P = snap.covariance.topLeftCorner(n, n);
  const std::vector<int> chosen =
      selectInformativePoses(robot_->model, snap.params, snap.estimated, P, candidates_.q, settings_.count, o, &f);
  out.q_rad.reserve(chosen.size());
  for (int i : chosen) out.q_rad.push_back(candidates_.q[static_cast<size_t>(i)]);
  out.predicted_sigma_now_m = std::sqrt(std::max(0.0, f.mean_position_variance_before_m2));
  out.predicted_sigma_after_m = std::sqrt(std::max(0.0, f.mean_position_variance_after_m2));
  return out;
}

std::string poseRequesterText(const PoseRequester& r, const PoseRequestSettings& s) {
  const CandidateSet& c = r.candidates();
  const Eigen::Vector3d t = r.trackerInBase_m() * 1e3;
  std::ostringstream o;
  o.precision(0);
  o << std::fixed << "proposes the " << s.count << " most informative of " << c.q.size() << " measurable candidates ("
    << c.drawn << " drawn: " << c.near_axis << " near joint 1's axis, " << c.out_of_range << " out of range, "
    << c.occluded << " with the beam crossing the robot, " << c.facing_away << " facing away; tracker at (" << t.x()
    << ", " << t.y() << ", " << t.z() << ") mm in the base frame)";
  return o.str();
}

}  // namespace cellcal
