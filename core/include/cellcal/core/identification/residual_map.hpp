// What a calibrated model still gets wrong where the robot was measured: a map of the position residuals over joint
// space, for cells that revisit their working poses (teach points).
//
// A row's residual is its measured target position minus the model's (metres, in whatever frame the caller gives;
// calibrate uses the tracker frame). Each axis is a zero-mean Gaussian process over the joints with one
// squared-exponential kernel, a length scale per joint (ARD), signal sigma s and noise sigma n:
//   k(q, q') = s^2 exp(-1/2 sum_j ((q_j - q'_j) / l_j)^2),   cov(y_i, y_k) = k(q_i, q_k) + n^2 [i = k]
// fitResidualMap chooses l, s and n by the marginal likelihood of the three axes together on at most `fit_rows` rows
// (L-BFGS on its analytic gradient from three starts), then conditions on at most `max_rows` rows (drawn at random
// when there are more).
// predict(q) gives the posterior mean of the residual (the correction to add to the model's position), its 1-sigma
// (per axis, the posterior of the mean: what the map does not know there), and the distance from q to the nearest
// row it was made from, in length scales (sqrt(sum_j ((q_j - q'_j) / l_j)^2)). Beyond `max_distance` the map does
// not apply (applies = false, no correction): it never extrapolates.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace cellcal {

struct ResidualMapOptions {
  int fit_rows = 600;         // rows the hyperparameters are chosen on
  int max_rows = 2000;        // rows the map is conditioned on
  double max_distance = 1.0;  // in length scales: farther from every row, no correction
  std::uint64_t seed = 1;     // which rows, when there are more
  bool IsValid(std::string* error) const;
};

// The kernel of a map: a length scale per joint (rad), signal and noise sigmas (m), and how far it reaches.
struct ResidualMapKernel {
  Eigen::VectorXd length_rad;
  double signal_m = 0, noise_m = 0, max_distance = 1.0;
  bool IsValid(int joints, std::string* error) const;
};

class ResidualMap {
 public:
  struct Prediction {
    Eigen::Vector3d correction_m = Eigen::Vector3d::Zero();  // zero when !applies
    double sigma_m = 0;  // per axis, 1 sigma of the correction (with_sigma only)
    double distance = std::numeric_limits<double>::infinity();  // to the nearest row, in length scales
    bool applies = false;
  };
  // `with_sigma`: also the correction's sigma (a triangular solve over the rows: O(rows^2) per call).
  Prediction predict(const Eigen::VectorXd& q_rad, bool with_sigma = false) const;
  // An upper bound of predict(q, true).sigma_m at a bounded cost: the posterior sigma given only the `nearest` rows
  // closest to q (conditioning on fewer rows never lowers the variance), O(nearest^3). Equal to it when nearest >= rows.
  double sigmaBound_m(const Eigen::VectorXd& q_rad, int nearest = 48) const;

  bool empty() const { return q_.empty(); }
  std::size_t rows() const { return q_.size(); }
  const Eigen::VectorXd& lengthScales_rad() const { return length_rad_; }
  double signalSigma_m() const { return signal_m_; }
  double noiseSigma_m() const { return noise_m_; }
  double maxDistance() const { return max_distance_; }
  ResidualMapKernel kernel() const { return {length_rad_, signal_m_, noise_m_, max_distance_}; }
  // The rows it is conditioned on: configurations and residuals (what a robot file keeps of it).
  const std::vector<Eigen::VectorXd>& rowConfigurations() const { return q_; }
  const std::vector<Eigen::Vector3d>& rowResiduals() const { return y_; }
  // -log marginal likelihood per row of the fit (for reports and tests).
  double negLogLikelihoodPerRow() const { return nll_per_row_; }

 private:
  friend ResidualMap conditionResidualMap(std::vector<Eigen::VectorXd>, std::vector<Eigen::Vector3d>,
                                          const ResidualMapKernel&);
  friend ResidualMap fitResidualMap(const std::vector<Eigen::VectorXd>&, const std::vector<Eigen::Vector3d>&,
                                    const ResidualMapOptions&);
  std::vector<Eigen::VectorXd> q_;
  std::vector<Eigen::Vector3d> y_;
  Eigen::MatrixXd alpha_;  // rows x 3: K^-1 y
  Eigen::MatrixXd L_;      // Cholesky factor of K (lower)
  Eigen::VectorXd length_rad_;
  double signal_m_ = 0, noise_m_ = 0, max_distance_ = 1.0, nll_per_row_ = 0;
};

// The map of these rows with this kernel (what fitResidualMap ends with; a robot file's map is made again from its
// rows). Throws std::invalid_argument saying why when the sizes disagree, a value is not finite or the kernel is
// invalid.
ResidualMap conditionResidualMap(std::vector<Eigen::VectorXd> q_rad, std::vector<Eigen::Vector3d> residual_m,
                                 const ResidualMapKernel& kernel);

// Throws std::invalid_argument when the sizes disagree, fewer than 10 rows are given, or the options are invalid.
ResidualMap fitResidualMap(const std::vector<Eigen::VectorXd>& q_rad, const std::vector<Eigen::Vector3d>& residual_m,
                           const ResidualMapOptions& options = {});

}  // namespace cellcal
