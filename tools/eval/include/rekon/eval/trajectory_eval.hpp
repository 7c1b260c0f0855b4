#pragma once
// Trajectory accuracy as the TUM RGB-D benchmark measures it: timestamps
// associated like associate.py, ATE after a rigid Horn/Umeyama alignment, and
// RPE per second.
#include <cstddef>
#include <utility>
#include <optional>
#include <vector>

#include "rekon/common/pose.hpp"

namespace rekon::eval {

struct TrajectoryEvalOptions {
  // Largest timestamp difference of an associated pair (associate.py's default).
  static constexpr double kDefaultMaxTimeDifferenceS = 0.02;
  // RPE interval (evaluate_rpe.py --delta 1 --delta_unit s).
  static constexpr double kDefaultRpeDeltaS = 1.0;
  double max_time_difference_s = kDefaultMaxTimeDifferenceS;
  // Added to the estimate's timestamps before they are associated
  // (associate.py's --offset): a trajectory on a clock shifted by a constant.
  double time_offset_s = 0.0;
  double rpe_delta_s = kDefaultRpeDeltaS;
};

struct TrajectoryErrors {
  size_t matched = 0;            // associated pose pairs
  double ate_rmse_m = 0.0;       // after alignment
  double ate_mean_m = 0.0;
  double ate_median_m = 0.0;
  double ate_max_m = 0.0;
  double rpe_trans_m_per_s = 0.0;  // rmse over all pairs (i, j) about rpe_delta_s apart, each divided by its time span
  double rpe_rot_deg_per_s = 0.0;
  size_t rpe_pairs = 0;
  double rpe_delta_s = 0.0;        // the interval used (shorter when the sequence is)
  Pose alignment = Pose::Identity();  // maps the estimate onto the ground truth
};

// Index pairs (gt, est) of timestamps within max_difference, each entry used at
// most once, closest pairs first (TUM associate.py), sorted by gt timestamp;
// `est_offset` is added to est's timestamps first (associate.py's --offset).
std::vector<std::pair<size_t, size_t>> associate(const Trajectory& gt, const Trajectory& est, double max_difference,
                                                 double est_offset = 0.0);

// The rigid motion (no scale) that best maps `from` onto `to` in the least-squares sense (Horn/Umeyama).
Pose alignRigid(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to);

// Throws rekon::Error when fewer than two poses associate.
// The tracker's world is its first camera: the transform that moves what was
// built in it (a mesh) into the reference trajectory's world, T_ref * T_est^-1
// at the estimate's first timestamp; nullopt when the reference has no pose
// within max_difference of it.
std::optional<Pose> firstPoseAlignment(const Trajectory& est, const Trajectory& ref, double max_difference = 0.02);

TrajectoryErrors evaluateTrajectory(const Trajectory& gt, const Trajectory& est, const TrajectoryEvalOptions& options = {});

}  // namespace rekon::eval
