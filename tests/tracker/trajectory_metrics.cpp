#include "trajectory_metrics.hpp"

#include <Eigen/SVD>
#include <cmath>
#include <numbers>
#include <vector>

namespace rekon::tracker::test {

TrajectoryErrors compareTrajectories(const Trajectory& estimate, const Trajectory& ground_truth) {
  constexpr double kMaxTimeDifference = 0.02;
  std::vector<Pose> est, gt;
  std::vector<double> stamps;
  for (const auto& e : estimate) {
    const int j = nearestInTime(ground_truth, e.timestamp, kMaxTimeDifference);
    if (j < 0) continue;
    est.push_back(e.pose);
    gt.push_back(ground_truth[j].pose);
    stamps.push_back(e.timestamp);
  }
  TrajectoryErrors out;
  out.matched = static_cast<int>(est.size());
  if (est.size() < 2) return out;

  // Horn / Umeyama without scale: R, t minimising sum |gt - (R est + t)|^2.
  const size_t n = est.size();
  Eigen::Vector3d me = Eigen::Vector3d::Zero(), mg = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    me += est[i].translation();
    mg += gt[i].translation();
  }
  me /= static_cast<double>(n);
  mg /= static_cast<double>(n);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < n; ++i) cov += (gt[i].translation() - mg) * (est[i].translation() - me).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d s = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) s(2, 2) = -1;
  const Eigen::Matrix3d r = svd.matrixU() * s * svd.matrixV().transpose();
  const Eigen::Vector3d t = mg - r * me;
  double sq = 0.0;
  for (size_t i = 0; i < n; ++i) sq += (gt[i].translation() - (r * est[i].translation() + t)).squaredNorm();
  out.ate_rmse_m = std::sqrt(sq / static_cast<double>(n));

  for (size_t i = 1; i < n; ++i) out.path_length_m += (gt[i].translation() - gt[i - 1].translation()).norm();

  // RPE over 1 s: for each i, the pose j closest to one second later.
  double st = 0.0, sr = 0.0;
  int pairs = 0;
  size_t j = 0;
  for (size_t i = 0; i < n; ++i) {
    while (j < n && stamps[j] < stamps[i] + 1.0) ++j;
    if (j >= n) break;
    const Pose de = est[i].inverse() * est[j];
    const Pose dg = gt[i].inverse() * gt[j];
    const Pose err = dg.inverse() * de;
    const double dt = stamps[j] - stamps[i];
    st += std::pow(err.translation().norm() / dt, 2);
    sr += std::pow(rotationAngle(Pose::Identity(), err) * 180.0 / std::numbers::pi / dt, 2);
    ++pairs;
  }
  // Drift per metre: pairs (i, j) with one metre of ground-truth path between them.
  std::vector<double> along(n, 0.0);
  for (size_t i = 1; i < n; ++i) along[i] = along[i - 1] + (gt[i].translation() - gt[i - 1].translation()).norm();
  double dt2 = 0.0, dr2 = 0.0;
  int segments = 0;
  size_t k = 0;
  for (size_t i = 0; i < n; ++i) {
    while (k < n && along[k] < along[i] + 1.0) ++k;
    if (k >= n) break;
    const Pose err = (gt[i].inverse() * gt[k]).inverse() * (est[i].inverse() * est[k]);
    const double len = along[k] - along[i];
    dt2 += std::pow(err.translation().norm() / len, 2);
    dr2 += std::pow(rotationAngle(Pose::Identity(), err) * 180.0 / std::numbers::pi / len, 2);
    ++segments;
  }
  if (segments > 0) {
    out.drift_per_m = std::sqrt(dt2 / segments);
    out.drift_deg_per_m = std::sqrt(dr2 / segments);
  }
  if (pairs > 0) {
    out.rpe_trans_m_per_s = std::sqrt(st / pairs);
    out.rpe_rot_deg_per_s = std::sqrt(sr / pairs);
  }
  return out;
}

}  // namespace rekon::tracker::test
