// Benchmark of loop-closure detection: the tracker over a TUM-layout dataset
// in process, every new keyframe checked synchronously, and each accepted
// loop constraint (and each odometry constraint) compared with the dataset's
// ground truth; then the keyframe graph optimised by rekon_optimiser's
// PoseGraph (as rekon-optimiser's final optimisation) and the ATE of every
// frame, odometry alone against with loop closures. Prints numbers; asserts nothing.
//   loop_closure_bench DATASET [FRAMES] [tracker.key=value ...]
// Environment: DUMP=1 prints "DUMP error coarse_ratio fine_ratio baseline_m
// angle_deg pixels id_gap cross_check_m intensity_sigma depth_sigma" per
// accepted loop; ORACLE=1 gives the optimiser the accepted loops with their
// ground-truth poses instead (what perfect loop poses would achieve).
#include <algorithm>
#include <cstdlib>
#include <cstdio>
#include <iostream>
#include <map>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/se3.hpp"
#include "rekon/eval/trajectory_eval.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/slam_bench/in_process_slam.hpp"

namespace rekon::slam_bench {
namespace {

struct ErrorStats {
  std::vector<double> trans, rot;
  void add(const Pose& est, const Pose& truth) {
    trans.push_back(translationDistance(est, truth));
    rot.push_back(rotationAngle(est, truth) * 180.0 / std::numbers::pi);
  }
  static double quantile(std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
  }
  void print(const char* what) const {
    std::printf("%s: %zu, translation error median %.4f m p90 %.4f m max %.4f m; rotation median %.3f p90 %.3f max %.3f deg\n",
                what, trans.size(), quantile(trans, 0.5), quantile(trans, 0.9), quantile(trans, 1.0),
                quantile(rot, 0.5), quantile(rot, 0.9), quantile(rot, 1.0));
  }
};

// The ground-truth pose of every keyframe the dataset has one for.
class KeyframeTruth {
 public:
  KeyframeTruth(const InProcessSlam& slam, const Trajectory& gt, double information_scale)
      : information_scale_(information_scale) {
    for (const auto& k : slam.keyframes) {
      const int g = nearestInTime(gt, k.timestamp, 0.02);
      if (g >= 0) truth_[k.id] = gt[static_cast<size_t>(g)].pose;
    }
  }
  // The true pose of `to` in `from`.
  std::optional<Pose> relative(int64_t from, int64_t to) const {
    if (!truth_.count(from) || !truth_.count(to)) return std::nullopt;
    return Pose(truth_.at(from).inverse() * truth_.at(to));
  }
  // chi2 of an edge at the true poses, with the optimiser's information scale.
  double chi2(int64_t from, int64_t to, const Pose& relative, const Matrix6d& info) const {
    const Vector6d r = optimiser::relativePoseResidual(truth_.at(from), truth_.at(to), relative);
    return information_scale_ * r.dot(info * r);
  }

 private:
  std::map<int64_t, Pose> truth_;
  double information_scale_;
};

struct EdgeErrors {
  ErrorStats odometry, loops;
  std::vector<double> odometry_chi2, loop_chi2;
  int far_loops = 0;  // off by more than 8 cm
};

// Every edge against the ground truth; prints each loop off by more than
// 8 cm, and with DUMP=1 every loop.
EdgeErrors compareEdges(const InProcessSlam& slam, const KeyframeTruth& truth) {
  EdgeErrors out;
  for (const auto& o : slam.odometry_edges) {
    const auto t = truth.relative(o.from_id, o.to_id);
    if (!t) continue;
    out.odometry.add(o.relative, *t);
    out.odometry_chi2.push_back(truth.chi2(o.from_id, o.to_id, o.relative, o.information));
  }
  for (const auto& c : slam.loop_edges) {
    const auto t = truth.relative(c.from_id, c.to_id);
    if (!t) continue;
    out.loops.add(c.relative, *t);
    out.loop_chi2.push_back(truth.chi2(c.from_id, c.to_id, c.relative, c.information));
    const double error = translationDistance(c.relative, *t);
    if (getenv("DUMP"))
      std::printf("DUMP %.4f %.3f %.3f %.3f %.2f %d %ld %.4f %.4f %.4f\n", error, c.coarse_ratio, c.fine_ratio,
                  t->translation().norm(), rotationAngle(*t, Pose::Identity()) * 57.3, c.valid_pixels,
                  static_cast<long>(c.to_id - c.from_id), c.cross_check_m, c.intensity_sigma, c.depth_sigma);
    if (error > 0.08) {
      ++out.far_loops;
      std::printf("loop %ld -> %ld off by %.3f m %.2f deg (ratios %.3f %.3f, %d px)\n", static_cast<long>(c.from_id),
                  static_cast<long>(c.to_id), error, rotationAngle(c.relative, *t) * 180.0 / std::numbers::pi,
                  c.coarse_ratio, c.fine_ratio, c.valid_pixels);
    }
  }
  return out;
}

void printStats(const InProcessSlam& slam, const EdgeErrors& e, double information_scale) {
  e.odometry.print("odometry constraints");
  e.loops.print("loop constraints");
  const auto& stats = slam.stats;
  std::printf("keyframes=%ld candidates=%ld accepted=%ld rejected=%ld off_by_more_than_8cm=%d check_ms_per_keyframe=%.1f\n",
              static_cast<long>(stats.keyframes_checked), static_cast<long>(stats.candidates),
              static_cast<long>(stats.accepted), static_cast<long>(stats.rejected), e.far_loops,
              slam.check_ms / static_cast<double>(std::max<int64_t>(stats.keyframes_checked, 1)));
  std::printf("keyframes_reused=%ld reuse_edges=%zu keyframe_reuse_checks=%ld (tracker.keyframe_reuse)\n",
              static_cast<long>(slam.keyframes_reused), slam.reuse_edges.size(),
              static_cast<long>(slam.keyframe_reuse_checks));
  std::printf("chi2 at the ground truth (information x %.0e): odometry median %.1f p90 %.1f, loops median %.1f p90 %.1f "
              "(6 dof: 5.35 median if calibrated)\n",
              information_scale, ErrorStats::quantile(e.odometry_chi2, 0.5), ErrorStats::quantile(e.odometry_chi2, 0.9),
              ErrorStats::quantile(e.loop_chi2, 0.5), ErrorStats::quantile(e.loop_chi2, 0.9));
}

// SWEEP=1: the same keyframes and constraints, optimised again with the loop
// edges filtered.
void sweep(const InProcessSlam& slam, const optimiser::OptimiserServiceParams& graph_params, const Trajectory& gt,
           double ate_odometry) {
  for (const double ratio : {0.0, 0.85, 0.9, 0.95}) {
    for (const int gap : {1, 5, 10, 20, 30}) {
      for (const double cross : {0.05, 0.02}) {
        for (const double depth_sigma : {1e9, 0.05}) {
          const auto filtered =
              optimise(slam, graph_params, [&](const tracker::LoopConstraint& l) -> std::optional<Pose> {
                if (l.cross_check_m <= cross && l.depth_sigma <= depth_sigma && l.fine_ratio >= ratio &&
                    l.to_id - l.from_id >= gap)
                  return l.relative;
                return std::nullopt;
              });
          const double ate = eval::evaluateTrajectory(gt, filtered.trajectory).ate_rmse_m;
          std::printf("SWEEP min_fine_ratio %.2f min_gap %d max_cross %.2f max_depth_sigma %.2f: %zu loops kept, "
                      "ATE %.4f m (ratio %.3f)\n",
                      ratio, gap, cross, std::min(depth_sigma, 9.99), filtered.loop_edges_kept, ate, ate / ate_odometry);
        }
      }
    }
  }
}

void run(const std::string& dataset_dir, int max_frames, const std::vector<std::string>& sets) {
  const auto config = Config::load("", sets);
  const auto params = tracker::trackerParamsFromConfig(config);
  const auto graph_params = optimiser::optimiserParamsFromConfig(config);
  DatasetOptions options;
  options.max_frames = max_frames;
  const TumDataset dataset(dataset_dir, options);
  if (!dataset.hasGroundTruth()) throw Error(dataset_dir + " has no groundtruth.txt");
  const Trajectory gt = dataset.groundTruth();
  const auto slam = runInProcess(dataset, params);

  const KeyframeTruth truth(slam, gt, graph_params.information_scale);
  const EdgeErrors errors = compareEdges(slam, truth);
  LoopPose loop_pose;
  if (getenv("ORACLE"))
    loop_pose = [&](const tracker::LoopConstraint& c) -> std::optional<Pose> {
      const auto t = truth.relative(c.from_id, c.to_id);
      return t ? t : std::optional<Pose>(c.relative);
    };
  const auto result = optimise(slam, graph_params, loop_pose);
  std::printf("graph: %zu keyframes, %zu loop edges kept, %zu removed, %.1f ms\n", slam.keyframes.size(),
              result.loop_edges_kept, result.loop_edges_removed, result.ms);
  const double ate_odometry = eval::evaluateTrajectory(gt, slam.odometry).ate_rmse_m;
  const double ate_loops = eval::evaluateTrajectory(gt, result.trajectory).ate_rmse_m;
  std::printf("ate_odometry_m=%.4f ate_with_loops_m=%.4f ratio=%.3f\n", ate_odometry, ate_loops,
              ate_loops / ate_odometry);
  printStats(slam, errors, graph_params.information_scale);
  if (getenv("SWEEP")) sweep(slam, graph_params, gt, ate_odometry);
}

}  // namespace
}  // namespace rekon::slam_bench

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: loop_closure_bench DATASET [FRAMES] [tracker.key=value ...]\n";
    return 2;
  }
  try {
    std::vector<std::string> sets;
    for (int i = 3; i < argc; ++i) sets.emplace_back(argv[i]);
    rekon::slam_bench::run(argv[1], argc > 2 ? std::stoi(argv[2]) : 0, sets);
  } catch (const rekon::Error& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
  return 0;
}
