#include "rekon/slam_bench/trajectory_metrics.hpp"

#include <cmath>
#include <numbers>
#include <vector>

#include "rekon/eval/trajectory_eval.hpp"

namespace rekon::slam_bench {

TrajectoryErrors compareTrajectories(const Trajectory& estimate, const Trajectory& ground_truth) {
  // ATE and RPE as `rekon eval traj` computes them; drift per metre of path is
  // the tracker's own figure.
  const eval::TrajectoryErrors e = eval::evaluateTrajectory(ground_truth, estimate);
  TrajectoryErrors out;
  out.matched = static_cast<int>(e.matched);
  out.ate_rmse_m = e.ate_rmse_m;
  out.rpe_trans_m_per_s = e.rpe_trans_m_per_s;
  out.rpe_rot_deg_per_s = e.rpe_rot_deg_per_s;
  std::vector<Pose> est, gt;
  for (const auto& [g, k] : eval::associate(ground_truth, estimate, eval::TrajectoryEvalOptions::kDefaultMaxTimeDifferenceS)) {
    gt.push_back(ground_truth[g].pose);
    est.push_back(estimate[k].pose);
  }
  const size_t n = est.size();
  if (n < 2) return out;

  // Drift per metre: pairs (i, j) with one metre of ground-truth path between them.
  std::vector<double> along(n, 0.0);
  for (size_t i = 1; i < n; ++i) along[i] = along[i - 1] + (gt[i].translation() - gt[i - 1].translation()).norm();
  out.path_length_m = along.back();
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
  return out;
}

}  // namespace rekon::slam_bench
