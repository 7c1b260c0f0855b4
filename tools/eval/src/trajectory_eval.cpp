#include "rekon/eval/trajectory_eval.hpp"

#include <fmt/format.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "rekon/common/error.hpp"

namespace rekon::eval {
namespace {

std::vector<size_t> byTime(const Trajectory& t) {
  std::vector<size_t> order(t.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return t[a].timestamp < t[b].timestamp; });
  return order;
}

double rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / static_cast<double>(v.size()));
}

}  // namespace

std::vector<std::pair<size_t, size_t>> associate(const Trajectory& gt, const Trajectory& est, double max_difference,
                                                 double est_offset) {
  const std::vector<size_t> est_order = byTime(est);
  std::vector<double> est_times(est_order.size());
  for (size_t i = 0; i < est_order.size(); ++i) est_times[i] = est[est_order[i]].timestamp + est_offset;
  struct Candidate {
    double diff;
    size_t gt, est;
  };
  std::vector<Candidate> candidates;
  for (size_t g = 0; g < gt.size(); ++g) {
    const double t = gt[g].timestamp;
    auto it = std::lower_bound(est_times.begin(), est_times.end(), t - max_difference);
    for (; it != est_times.end() && *it <= t + max_difference; ++it) {
      const size_t e = est_order[static_cast<size_t>(it - est_times.begin())];
      candidates.push_back({std::abs(*it - t), g, e});
    }
  }
  std::stable_sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) { return a.diff < b.diff; });
  std::vector<char> gt_used(gt.size(), 0), est_used(est.size(), 0);
  std::vector<std::pair<size_t, size_t>> pairs;
  for (const auto& c : candidates) {
    if (gt_used[c.gt] || est_used[c.est]) continue;
    gt_used[c.gt] = est_used[c.est] = 1;
    pairs.emplace_back(c.gt, c.est);
  }
  std::sort(pairs.begin(), pairs.end(),
            [&](const auto& a, const auto& b) { return gt[a.first].timestamp < gt[b.first].timestamp; });
  return pairs;
}

Pose alignRigid(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to) {
  if (from.size() != to.size() || from.empty()) throw Error("rigid alignment needs two equally long, non-empty point lists");
  const double n = static_cast<double>(from.size());
  Eigen::Vector3d mf = Eigen::Vector3d::Zero(), mt = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < from.size(); ++i) {
    mf += from[i];
    mt += to[i];
  }
  mf /= n;
  mt /= n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < from.size(); ++i) cov += (to[i] - mt) * (from[i] - mf).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d s = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) s(2, 2) = -1;  // no reflections
  Pose out = Pose::Identity();
  out.linear() = svd.matrixU() * s * svd.matrixV().transpose();
  out.translation() = mt - out.linear() * mf;
  return out;
}

TrajectoryErrors evaluateTrajectory(const Trajectory& gt, const Trajectory& est, const TrajectoryEvalOptions& options) {
  const auto pairs = associate(gt, est, options.max_time_difference_s, options.time_offset_s);
  if (pairs.size() < 2) {
    throw Error("only " + std::to_string(pairs.size()) + " of " + std::to_string(est.size()) +
                " estimated poses have a ground-truth pose within " + fmt::format("{}", options.max_time_difference_s) +
                " s; check that both trajectories use the same clock (a live camera stamps frames with this computer's "
                "clock: to score a recording made from a dataset against its ground truth, run it with --set "
                "camera.clock=recording)");
  }
  TrajectoryErrors r;
  r.matched = pairs.size();

  std::vector<Eigen::Vector3d> p_gt, p_est;
  for (const auto& [g, e] : pairs) {
    p_gt.push_back(gt[g].pose.translation());
    p_est.push_back(est[e].pose.translation());
  }
  r.alignment = alignRigid(p_est, p_gt);
  std::vector<double> ate;
  for (size_t i = 0; i < pairs.size(); ++i) ate.push_back((p_gt[i] - r.alignment * p_est[i]).norm());
  r.ate_rmse_m = rms(ate);
  double sum = 0;
  for (double x : ate) sum += x;
  r.ate_mean_m = sum / static_cast<double>(ate.size());
  r.ate_max_m = *std::max_element(ate.begin(), ate.end());
  std::vector<double> sorted = ate;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2), sorted.end());
  r.ate_median_m = sorted[sorted.size() / 2];

  // RPE: for each pair i, the first pair j at least delta later.
  const double span = gt[pairs.back().first].timestamp - gt[pairs.front().first].timestamp;
  r.rpe_delta_s = std::min(options.rpe_delta_s, span);
  std::vector<double> trans, rot;
  size_t j = 0;
  for (size_t i = 0; i < pairs.size(); ++i) {
    const double ti = gt[pairs[i].first].timestamp;
    j = std::max(j, i + 1);
    while (j < pairs.size() && gt[pairs[j].first].timestamp < ti + r.rpe_delta_s - 1e-9) ++j;
    if (j >= pairs.size()) break;
    const double dt = gt[pairs[j].first].timestamp - ti;
    if (dt <= 0) continue;
    const Pose d_gt = gt[pairs[i].first].pose.inverse() * gt[pairs[j].first].pose;
    const Pose d_est = est[pairs[i].second].pose.inverse() * est[pairs[j].second].pose;
    const Pose e = d_gt.inverse() * d_est;
    trans.push_back(e.translation().norm() / dt);
    // Through the quaternion: exact for tiny angles, where acos of the trace is not.
    rot.push_back(Eigen::AngleAxisd(e.linear()).angle() * 180.0 / std::numbers::pi / dt);
  }
  r.rpe_pairs = trans.size();
  r.rpe_trans_m_per_s = rms(trans);
  r.rpe_rot_deg_per_s = rms(rot);
  return r;
}

std::optional<Pose> firstPoseAlignment(const Trajectory& est, const Trajectory& ref, double max_difference) {
  if (est.empty()) return std::nullopt;
  const int r = nearestInTime(ref, est.front().timestamp, max_difference);
  if (r < 0) return std::nullopt;
  return ref[static_cast<size_t>(r)].pose * est.front().pose.inverse();
}

}  // namespace rekon::eval
