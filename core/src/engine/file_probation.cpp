#include "cellcal/core/engine/file_probation.hpp"

#include <algorithm>
#include <iomanip>
#include <limits>
#include <sstream>
#include <utility>

namespace cellcal {

bool FileProbation::hold(Held held) {
  held_.push_back(std::move(held));
  return held_.size() >= kPoses;
}

std::string FileProbation::refusal(const std::string& file, double gate) const {
  std::ostringstream why;
  why << "calibration_file " << file << " does not fit this cell: its first " << held_.size() << " poses lie";
  double least_nis = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < held_.size(); ++k) {
    why << (k ? ", " : " ") << std::fixed << std::setprecision(2) << held_[k].prior_error_m * 1e3;
    least_nis = std::min(least_nis, held_[k].nis_per_row);
  }
  why << " mm from where it predicts them (normalized innovation " << std::scientific << std::setprecision(2)
      << least_nis << " per row or more, gate " << std::defaultfloat << gate
      << "): calibrated on another set-up, the tracker moved, or another robot. Started from the nominal model and "
         "the cell file's registration instead (to keep the file's kinematics: `cellcal calibrate --frames-only` on a "
         "few poses of this cell, then start from that file)";
  return why.str();
}

std::vector<FileProbation::Held> FileProbation::take() {
  std::vector<Held> out = std::move(held_);
  held_.clear();
  return out;
}

}  // namespace cellcal
