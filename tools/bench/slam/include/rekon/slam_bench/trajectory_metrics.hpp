#pragma once
// Trajectory error metrics for tracker_bench and the tracker's tests: ATE
// and RPE from rekon_eval (as `rekon eval traj`), plus drift per metre of
// path.
#include "rekon/common/pose.hpp"

namespace rekon::slam_bench {

struct TrajectoryErrors {
  int matched = 0;                  // estimated poses with ground truth within 20 ms
  double ate_rmse_m = 0.0;          // after the best rigid alignment (no scale)
  double rpe_trans_m_per_s = 0.0;   // RMSE of the translation drift over 1 s windows
  double rpe_rot_deg_per_s = 0.0;   // RMSE of the rotation drift over 1 s windows
  double drift_per_m = 0.0;         // RMSE of the translation drift over 1 m of ground-truth path, m/m
  double drift_deg_per_m = 0.0;     // likewise for rotation, degrees per metre
  double path_length_m = 0.0;       // of the matched ground truth
};

TrajectoryErrors compareTrajectories(const Trajectory& estimate, const Trajectory& ground_truth);

}  // namespace rekon::slam_bench
