// Gross errors in tracker readings (a broken beam, the wrong reflector, a bumped tracker): which rows a fit should
// not trust, judged against a scale measured from the residuals themselves, not assumed.
//
//   OutlierScreen s = screenOutliers(position_residuals, orientation_residuals, options);
//
// The robust scale is the per-axis sigma a median gives: sigma^2 = median |e|^2 / median(chi-square, 3 dof), for
// positions and (6D rows) orientations separately, so a few wild rows cannot inflate it. A row is an outlier when its
// position error exceeds `threshold` of those sigmas (and, with screen_orientation, when its orientation error does).
// Orientations are not screened by default: a model error that is mostly a rotation (a joint 6 zero drifting while
// the robot warms up) gives the orientation residual a tail of several robust sigmas that is no gross error. Fits that screen (solveGaussNewton,
// solveLevenbergMarquardt, fitExtendedRobust, diagnose) alternate: fit the rows kept, screen all rows against that
// fit, until the set of outliers repeats. On clean data nothing is flagged and the fit is the plain least-squares
// fit: screening costs nothing there.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace cellcal {

struct OutlierOptions {
  bool enabled = true;
  double threshold = 6.0;  // in robust sigmas per axis; a clean row exceeds 6 with probability ~1e-7 (Gaussian noise)
  int max_rounds = 6;      // fit-screen alternations at the most
  bool screen_orientation = false;
  bool IsValid(std::string* error) const;
};

struct OutlierScreen {
  std::vector<int> rows;             // flagged rows (indices into the residuals given), ascending
  std::vector<double> z;             // per row: its error in robust sigmas (the larger of position and orientation)
  double sigma_position_m = 0;       // robust per-axis sigma of the position residuals
  double sigma_orientation_rad = 0;  // of the orientation residuals (0 without 6D rows)
  bool flagged(int row) const;
};

// orientation_residuals: rotation-vector norms (rad) per row, or NaN for a row without orientation; may be empty.
OutlierScreen screenOutliers(const std::vector<Eigen::Vector3d>& position_residuals,
                             const std::vector<double>& orientation_residuals, const OutlierOptions& options);

// The rows of `all` (0..n-1) not in `flagged` (ascending).
std::vector<int> keptRows(int n, const std::vector<int>& flagged);

// The elements of v at `rows`, in that order (e.g. the observations keptRows keeps, and their drivers).
template <typename T>
std::vector<T> subset(const std::vector<T>& v, const std::vector<int>& rows) {
  std::vector<T> out;
  out.reserve(rows.size());
  for (int i : rows) out.push_back(v[static_cast<size_t>(i)]);
  return out;
}

}  // namespace cellcal
