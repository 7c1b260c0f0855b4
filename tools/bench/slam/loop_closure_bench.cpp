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
#include <string>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/eval/trajectory_eval.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/slam_bench/in_process_slam.hpp"

namespace {

struct ErrorStats {
  std::vector<double> trans, rot;
  void add(const rekon::Pose& est, const rekon::Pose& truth) {
    trans.push_back(rekon::translationDistance(est, truth));
    rot.push_back(rekon::rotationAngle(est, truth) * 180.0 / std::numbers::pi);
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

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: loop_closure_bench DATASET [FRAMES] [tracker.key=value ...]\n";
    return 2;
  }
  try {
    std::vector<std::string> sets;
    for (int i = 3; i < argc; ++i) sets.emplace_back(argv[i]);
    const auto config = rekon::Config::load("", sets);
    const auto params = rekon::tracker::trackerParamsFromConfig(config);
    const auto graph_params = rekon::optimiser::optimiserParamsFromConfig(config);
    rekon::DatasetOptions options;
    options.max_frames = argc > 2 ? std::stoi(argv[2]) : 0;
    const rekon::TumDataset dataset(argv[1], options);
    if (!dataset.hasGroundTruth()) throw rekon::Error(std::string(argv[1]) + " has no groundtruth.txt");
    const rekon::Trajectory gt = dataset.groundTruth();
    const auto slam = rekon::slam_bench::runInProcess(dataset, params);

    std::map<int64_t, rekon::Pose> kf_truth;
    for (const auto& k : slam.keyframes) {
      const int g = rekon::nearestInTime(gt, k.timestamp, 0.02);
      if (g >= 0) kf_truth[k.id] = gt[static_cast<size_t>(g)].pose;
    }
    auto truthOf = [&](int64_t from, int64_t to) -> std::optional<rekon::Pose> {
      if (!kf_truth.count(from) || !kf_truth.count(to)) return std::nullopt;
      return rekon::Pose(kf_truth[from].inverse() * kf_truth[to]);
    };
    auto chi2AtTruth = [&](int64_t from, int64_t to, const rekon::Pose& relative, const rekon::Matrix6d& info) {
      const rekon::Vector6d r = rekon::optimiser::relativePoseResidual(kf_truth[from], kf_truth[to], relative);
      return graph_params.information_scale * r.dot(info * r);
    };
    ErrorStats loops, odometry;
    std::vector<double> odometry_chi2, loop_chi2;
    for (const auto& o : slam.odometry_edges) {
      const auto truth = truthOf(o.from_id, o.to_id);
      if (!truth) continue;
      odometry.add(o.relative, *truth);
      odometry_chi2.push_back(chi2AtTruth(o.from_id, o.to_id, o.relative, o.information));
    }
    int far_loops = 0;
    for (const auto& c : slam.loop_edges) {
      const auto truth = truthOf(c.from_id, c.to_id);
      if (!truth) continue;
      loops.add(c.relative, *truth);
      loop_chi2.push_back(chi2AtTruth(c.from_id, c.to_id, c.relative, c.information));
      const double error = rekon::translationDistance(c.relative, *truth);
      if (getenv("DUMP"))
        std::printf("DUMP %.4f %.3f %.3f %.3f %.2f %d %ld %.4f %.4f %.4f\n", error, c.coarse_ratio, c.fine_ratio,
                    truth->translation().norm(), rekon::rotationAngle(*truth, rekon::Pose::Identity()) * 57.3,
                    c.valid_pixels, static_cast<long>(c.to_id - c.from_id), c.cross_check_m, c.intensity_sigma,
                    c.depth_sigma);
      if (error > 0.08) {
        ++far_loops;
        std::printf("loop %ld -> %ld off by %.3f m %.2f deg (ratios %.3f %.3f, %d px)\n", static_cast<long>(c.from_id),
                    static_cast<long>(c.to_id), error,
                    rekon::rotationAngle(c.relative, *truth) * 180.0 / std::numbers::pi, c.coarse_ratio, c.fine_ratio,
                    c.valid_pixels);
      }
    }
    rekon::slam_bench::LoopPose loop_pose;
    if (getenv("ORACLE"))
      loop_pose = [&](const rekon::tracker::LoopConstraint& c) -> std::optional<rekon::Pose> {
        const auto truth = truthOf(c.from_id, c.to_id);
        return truth ? truth : std::optional<rekon::Pose>(c.relative);
      };
    const auto result = rekon::slam_bench::optimise(slam, graph_params, loop_pose);
    std::printf("graph: %zu keyframes, %zu loop edges kept, %zu removed, %.1f ms\n", slam.keyframes.size(),
                result.loop_edges_kept, result.loop_edges_removed, result.ms);
    const double ate_odometry = rekon::eval::evaluateTrajectory(gt, slam.odometry).ate_rmse_m;
    const double ate_loops = rekon::eval::evaluateTrajectory(gt, result.trajectory).ate_rmse_m;
    std::printf("ate_odometry_m=%.4f ate_with_loops_m=%.4f ratio=%.3f\n", ate_odometry, ate_loops,
                ate_loops / ate_odometry);
    odometry.print("odometry constraints");
    loops.print("loop constraints");
    const auto& stats = slam.stats;
    std::printf("keyframes=%ld candidates=%ld accepted=%ld rejected=%ld off_by_more_than_8cm=%d check_ms_per_keyframe=%.1f\n",
                static_cast<long>(stats.keyframes_checked), static_cast<long>(stats.candidates),
                static_cast<long>(stats.accepted), static_cast<long>(stats.rejected), far_loops,
                slam.check_ms / static_cast<double>(std::max<int64_t>(stats.keyframes_checked, 1)));
    std::printf("chi2 at the ground truth (information x %.0e): odometry median %.1f p90 %.1f, loops median %.1f p90 %.1f "
                "(6 dof: 5.35 median if calibrated)\n",
                graph_params.information_scale, ErrorStats::quantile(odometry_chi2, 0.5),
                ErrorStats::quantile(odometry_chi2, 0.9), ErrorStats::quantile(loop_chi2, 0.5),
                ErrorStats::quantile(loop_chi2, 0.9));
    if (getenv("SWEEP")) {
      // The same keyframes and constraints, optimised again with the loop
      // edges filtered.
      for (const double ratio : {0.0, 0.85, 0.9, 0.95}) {
        for (const int gap : {1, 5, 10, 20, 30}) {
          for (const double cross : {0.05, 0.02}) {
            for (const double depth_sigma : {1e9, 0.05}) {
              const auto filtered = rekon::slam_bench::optimise(
                  slam, graph_params, [&](const rekon::tracker::LoopConstraint& l) -> std::optional<rekon::Pose> {
                    if (l.cross_check_m <= cross && l.depth_sigma <= depth_sigma && l.fine_ratio >= ratio &&
                        l.to_id - l.from_id >= gap)
                      return l.relative;
                    return std::nullopt;
                  });
              const double ate = rekon::eval::evaluateTrajectory(gt, filtered.trajectory).ate_rmse_m;
              std::printf("SWEEP min_fine_ratio %.2f min_gap %d max_cross %.2f max_depth_sigma %.2f: %zu loops kept, "
                          "ATE %.4f m (ratio %.3f)\n",
                          ratio, gap, cross, std::min(depth_sigma, 9.99), filtered.loop_edges_kept, ate,
                          ate / ate_odometry);
            }
          }
        }
      }
    }
  } catch (const rekon::Error& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
  return 0;
}
