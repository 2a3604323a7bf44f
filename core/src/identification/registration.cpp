#include "cellcal/core/identification/registration.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

Eigen::Matrix<double, 6, 1> xyzRpyFromPose(const Pose& T) {
  const Eigen::Matrix3d R = T.linear();
  Eigen::Matrix<double, 6, 1> v;
  v.head<3>() = T.translation();
  v[4] = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));  // pitch
  v[3] = std::atan2(R(2, 1), R(2, 2));                 // roll
  v[5] = std::atan2(R(1, 0), R(0, 0));                 // yaw
  return v;
}

void rigidFit(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b, Eigen::Matrix3d& R,
              Eigen::Vector3d& t, Eigen::Vector3d* line) {
  Eigen::Vector3d ca = Eigen::Vector3d::Zero(), cb = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < a.size(); ++i) {
    ca += a[i];
    cb += b[i];
  }
  ca /= static_cast<double>(a.size());
  cb /= static_cast<double>(b.size());
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < a.size(); ++i) H += (a[i] - ca) * (b[i] - cb).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  if (svd.singularValues()[1] < 1e-9 * std::max(1.0, svd.singularValues()[0])) {
    if (!line) throw std::invalid_argument("registration: flange positions are (nearly) collinear");
    // H = sum (a_i - ca)(b_i - cb)^T ~ s u v^T: u is a's line, v b's, in the sense that pairs them.
    const Eigen::Vector3d u = svd.matrixU().col(0), v = svd.matrixV().col(0);
    R = Eigen::Quaterniond::FromTwoVectors(u, v).toRotationMatrix();
    t = cb - R * ca;
    *line = v;
    return;
  }
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
  R = svd.matrixV() * D * svd.matrixU().transpose();
  t = cb - R * ca;
}


namespace {

Eigen::Matrix3d projectToRotation(const Eigen::Matrix3d& M) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

}  // namespace

RegistrationResult registerFrames(const RobotModel& model, const Eigen::VectorXd& initial,
                                  const std::vector<Observation>& obs, int iterations) {
  if (obs.size() < 4) throw std::invalid_argument("registration: needs at least 4 observations");
  const int b0 = model.baseParam(FrameParam::kX), t0 = model.toolParam(FrameParam::kX);
  Eigen::VectorXd p = initial;
  p.segment<6>(b0).setZero();
  p.segment<6>(t0).setZero();
  KinematicsData data(model);
  // Flange poses in the base frame (base and tool identity).
  std::vector<Pose> flange;
  for (const auto& o : obs) flange.push_back(forwardKinematics(model, data, p, o.q_rad));
  std::vector<Eigen::Vector3d> measured;
  for (const auto& o : obs) measured.push_back(o.measured_in_tracker.translation());
  // The robot file's target offset: kept along any direction of the flange the rows do not turn (a grid measured at
  // one tool orientation cannot tell the target's offset from the base's position).
  const Eigen::Vector3d file_tool = initial.segment<3>(t0);
  Eigen::Vector3d tool = Eigen::Vector3d::Zero();
  Eigen::Matrix3d Rb = Eigen::Matrix3d::Identity();
  Eigen::Vector3d tb = Eigen::Vector3d::Zero();
  RegistrationResult out;
  const double n = static_cast<double>(obs.size());
  for (int it = 0; it < iterations; ++it) {
    std::vector<Eigen::Vector3d> a;
    for (const auto& F : flange) a.push_back(F * tool);
    Eigen::Vector3d line = Eigen::Vector3d::Zero();
    rigidFit(a, measured, Rb, tb, &line);
    out.line_direction.reset();
    if (line.squaredNorm() > 0) out.line_direction = line;
    double ss = 0;
    for (size_t i = 0; i < obs.size(); ++i) ss += (Rb * a[i] + tb - measured[i]).squaredNorm();
    const double noise_m = std::sqrt(ss / (3 * n));
    // Linear least squares in (tb, tool) with Rb fixed: m_i = tb + Rb (p_i + R_i tool). tb is the mean of what the
    // tool leaves, so the tool solves the centred rows: (R_i - R_mean) tool = Rb^T (m_i - tb_mean) - p_i centred.
    Eigen::Matrix3d R_mean = Eigen::Matrix3d::Zero();
    Eigen::Vector3d y_mean = Eigen::Vector3d::Zero();
    std::vector<Eigen::Vector3d> y(obs.size());
    for (size_t i = 0; i < obs.size(); ++i) {
      y[i] = Rb.transpose() * measured[i] - flange[i].translation();
      R_mean += flange[i].linear() / n;
      y_mean += y[i] / n;
    }
    Eigen::Matrix3d N = Eigen::Matrix3d::Zero();
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < obs.size(); ++i) {
      const Eigen::Matrix3d D = flange[i].linear() - R_mean;
      N += D.transpose() * D;
      g += D.transpose() * (y[i] - y_mean - D * file_tool);
    }
    // A direction is solved where the rows pin it to better than 50 mm at the noise the base fit leaves; along the
    // others the target stays where the robot file puts it.
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(N);
    const double min_eig = noise_m * noise_m / (0.05 * 0.05);
    tool = file_tool;
    for (int k = 0; k < 3; ++k)
      if (es.eigenvalues()[k] > std::max(min_eig, 1e-12 * es.eigenvalues()[2]))
        tool += es.eigenvectors().col(k) * es.eigenvectors().col(k).dot(g) / es.eigenvalues()[k];
    tb = Rb * (y_mean - R_mean * tool);
    out.iterations = it + 1;
  }
  // Tool orientation from oriented readings: R_meas = Rb R_flange R_tool.
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  int oriented = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    if (obs[i].kind != MeasurementKind::kPose6D) continue;
    sum += (Rb * flange[i].linear()).transpose() * obs[i].measured_in_tracker.linear();
    ++oriented;
  }
  Pose base = Pose::Identity();
  base.linear() = Rb;
  base.translation() = tb;
  Pose T = Pose::Identity();
  T.translation() = tool;
  if (oriented > 0) T.linear() = projectToRotation(sum);
  p.segment<6>(b0) = xyzRpyFromPose(base);
  p.segment<6>(t0) = xyzRpyFromPose(T);
  double ss = 0;
  for (const auto& o : obs)
    ss += (forwardKinematics(model, data, p, o.q_rad).translation() - o.measured_in_tracker.translation()).squaredNorm();
  out.rms_position_m = std::sqrt(ss / static_cast<double>(obs.size()));
  out.params = p;
  return out;
}

RegistrationResult refineFrames(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<Extension>& extensions, const Eigen::VectorXd& extension_params,
                                const std::vector<Observation>& observations, const std::vector<Drivers>& drivers,
                                int iterations, const std::vector<int>& held) {
  if (drivers.size() != observations.size()) throw std::invalid_argument("refineFrames: one Drivers entry per observation");
  if (params.size() != model.numParams()) throw std::invalid_argument("refineFrames: params has the wrong size");
  std::vector<int> frames;
  auto free = [&](int c) { return std::find(held.begin(), held.end(), c) == held.end(); };
  for (int k = 0; k < 6; ++k)
    if (free(model.toolParam(static_cast<FrameParam>(k)))) frames.push_back(model.toolParam(static_cast<FrameParam>(k)));
  for (int k = 0; k < 6; ++k)
    if (free(model.baseParam(static_cast<FrameParam>(k)))) frames.push_back(model.baseParam(static_cast<FrameParam>(k)));
  const int rows = totalRows(observations);
  KinematicsData data(model);
  RegistrationResult out;
  out.params = params;
  auto stack = [&](const Eigen::VectorXd& p, Eigen::VectorXd& r, Eigen::MatrixXd* J) {
    r.resize(rows);
    if (J) J->resize(rows, static_cast<Eigen::Index>(frames.size()));
    Eigen::Matrix<double, 6, 1> ri;
    Eigen::MatrixXd Ji;
    int row = 0;
    for (size_t i = 0; i < observations.size(); ++i) {
      const Eigen::VectorXd pe = extensions.empty()
                                     ? p
                                     : extendedParams(model, p, extensions, extension_params, observations[i].q_rad, drivers[i]);
      const int n = whitenedResidual(model, data, pe, observations[i], ri, J ? &Ji : nullptr);
      r.segment(row, n) = ri.head(n);
      if (J)
        for (size_t c = 0; c < frames.size(); ++c) J->block(row, static_cast<Eigen::Index>(c), n, 1) = Ji.block(0, frames[c], n, 1);
      row += n;
    }
  };
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stack(out.params, r, &J);
  std::vector<int> order(frames.size());
  for (size_t c = 0; c < order.size(); ++c) order[c] = static_cast<int>(c);
  const std::vector<int> cols = independentColumns(J, order);
  double cost = r.squaredNorm();
  for (int it = 0; it < iterations; ++it) {
    Eigen::MatrixXd A(rows, static_cast<Eigen::Index>(cols.size()));
    for (size_t c = 0; c < cols.size(); ++c) A.col(static_cast<Eigen::Index>(c)) = J.col(cols[c]);
    const Eigen::VectorXd step = A.colPivHouseholderQr().solve(r);
    Eigen::VectorXd trial = out.params;
    for (size_t c = 0; c < cols.size(); ++c) trial[frames[static_cast<size_t>(cols[c])]] += step[static_cast<Eigen::Index>(c)];
    Eigen::VectorXd r2;
    stack(trial, r2, nullptr);
    out.iterations = it + 1;
    if (!(r2.squaredNorm() < cost)) break;
    const bool small = cost - r2.squaredNorm() < 1e-12 * cost;
    out.params = trial;
    cost = r2.squaredNorm();
    if (small) break;
    stack(out.params, r, &J);
  }
  // Position RMS of the refined model.
  double sq = 0;
  for (size_t i = 0; i < observations.size(); ++i) {
    const Eigen::VectorXd pe = extensions.empty() ? out.params
                                                  : extendedParams(model, out.params, extensions, extension_params,
                                                                   observations[i].q_rad, drivers[i]);
    sq += (forwardKinematics(model, data, pe, observations[i].q_rad).translation() -
           observations[i].measured_in_tracker.translation()).squaredNorm();
  }
  out.rms_position_m = observations.empty() ? 0 : std::sqrt(sq / static_cast<double>(observations.size()));
  return out;
}

std::optional<SetupChange> findSetupChange(const RobotModel& model, const Eigen::VectorXd& initial,
                                           const std::vector<Observation>& obs, double ratio, int min_rows) {
  const int n = static_cast<int>(obs.size());
  if (n < 2 * min_rows) return std::nullopt;
  // Sum of squared residuals of a side registered on its own (infinite where it cannot be registered).
  auto sse = [&](int from, int to) {
    try {
      const std::vector<Observation> side(obs.begin() + from, obs.begin() + to);
      const double rms = registerFrames(model, initial, side).rms_position_m;
      return rms * rms * (to - from);
    } catch (const std::invalid_argument&) {
      return std::numeric_limits<double>::infinity();
    }
  };
  SetupChange best;
  double best_sse = std::numeric_limits<double>::infinity();
  auto tryAt = [&](int k) {
    if (k < min_rows || k > n - min_rows) return;
    const double v = sse(0, k) + sse(k, n);
    if (v < best_sse) {
      best_sse = v;
      best.first_row = k;
    }
  };
  const int step = std::max(1, n / 40);
  for (int k = min_rows; k <= n - min_rows; k += step) tryAt(k);
  if (best.first_row < 0) return std::nullopt;
  const int coarse = best.first_row;
  for (int k = coarse - step + 1; k < coarse + step; ++k) tryAt(k);
  best.rms_single_m = std::sqrt(sse(0, n) / n);
  best.rms_first_m = std::sqrt(sse(0, best.first_row) / best.first_row);
  best.rms_second_m = std::sqrt(sse(best.first_row, n) / (n - best.first_row));
  const double split_rms = std::sqrt(best_sse / n);
  if (!(best.rms_single_m > ratio * split_rms)) return std::nullopt;
  return best;
}

}  // namespace cellcal
