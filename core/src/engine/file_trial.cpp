#include "cellcal/core/engine/file_trial.hpp"

#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <utility>

#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/identification/statistics.hpp"

namespace cellcal {

std::string FileVerdict::text(const std::string& file) const {
  char b[700];
  if (!judged) {
    std::snprintf(b, sizeof b,
                  "calibration_file %s is kept without a judgement against its nominal kinematics: its first %zu poses "
                  "visit %zu distinct positions, fewer than the %zu it is judged on",
                  file.c_str(), poses, positions, FileTrial::kPositions);
    return b;
  }
  std::snprintf(b, sizeof b,
                "calibration_file %s %s: on its first %zu positions (%zu poses; frames registered on every other "
                "position, judged on the %zu readings of the others) it holds %.4f mm held-out mean, its nominal "
                "kinematics registered alike %.4f mm (%.1f standard errors %s)%s",
                file.c_str(), nominal_better ? "does worse here than the nominal kinematics it started from" : "kept",
                positions, poses, judged_readings, mean_file_mm, mean_nominal_mm, std::abs(z),
                z > 0 ? "in favour of the nominal kinematics" : "in favour of the file",
                nominal_better ? ". Started from the nominal model and the cell file's registration instead, taking "
                                 "those poses again"
                               : "");
  return b;
}

void FileTrial::start(CalibratedModel file_model, Eigen::VectorXd nominal_params) {
  restore(std::move(file_model), std::move(nominal_params), {});
}

void FileTrial::restore(CalibratedModel file_model, Eigen::VectorXd nominal_params, std::vector<DrivenReading> poses) {
  file_model_ = std::move(file_model);
  nominal_ = std::move(nominal_params);
  take();
  active_ = true;
  for (auto& p : poses) add(std::move(p));
}

void FileTrial::add(DrivenReading pose) {
  const Eigen::VectorXd& q = pose.reading.observation.q_rad;
  auto at = [&](std::size_t first) {
    const Eigen::VectorXd& f = poses_[first].reading.observation.q_rad;
    return f.size() == q.size() && (f - q).cwiseAbs().maxCoeff() < kSameRad;
  };
  std::size_t k = 0;
  while (k < first_pose_.size() && !at(first_pose_[k])) ++k;
  if (k == first_pose_.size()) first_pose_.push_back(poses_.size());
  position_.push_back(k);
  poses_.push_back(std::move(pose));
}

bool FileTrial::keep(const DrivenReading& pose) {
  if (!active_) return false;
  add(pose);
  return first_pose_.size() >= kPositions || poses_.size() >= kMaxPoses;
}

FileVerdict FileTrial::judge(const RobotModel& model) const {
  if (!active_) throw std::logic_error("FileTrial::judge: no trial");
  FileVerdict v;
  v.poses = poses_.size();
  v.positions = first_pose_.size();
  if (v.positions < kPositions) return v;
  std::vector<Observation> ident, verify;
  std::vector<Drivers> idr, vdr;
  for (std::size_t k = 0; k < poses_.size(); ++k) {
    const bool registered = position_[k] % 2 == 0;
    (registered ? ident : verify).push_back(poses_[k].reading.observation);
    (registered ? idr : vdr).push_back(poses_[k].drivers);
  }
  // The file's model carried as `--frames-only` carries it: its frames refined on the registration rows.
  ExtendedFit carried;
  static_cast<CalibratedModel&>(carried) = file_model_;
  carried.params = refineFrames(model, file_model_.params, file_model_.extensions, file_model_.extension_params, ident, idr)
                       .params;
  carried.converged = true;
  const NominalComparison c = compareWithNominal(model, carried, nominal_, ident, idr, verify, vdr);
  v.judged = true;
  v.nominal_better = c.nominal_better;
  v.mean_file_mm = c.mean_carried_mm;
  v.mean_nominal_mm = c.mean_nominal_mm;
  // The difference the decision is made on (the mean distances), reading by reading, in its standard errors.
  const auto rf = positionResiduals(model, carried, verify, vdr), rn = positionResiduals(model, c.nominal, verify, vdr);
  std::vector<double> d;
  for (std::size_t k = 0; k < rf.size(); ++k) d.push_back(rf[k].norm() - rn[k].norm());
  v.z = meanZ(d);
  v.judged_readings = verify.size();
  return v;
}

std::vector<DrivenReading> FileTrial::take() {
  active_ = false;
  position_.clear();
  first_pose_.clear();
  std::vector<DrivenReading> out = std::move(poses_);
  poses_.clear();
  return out;
}

}  // namespace cellcal
