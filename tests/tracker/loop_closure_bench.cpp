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
#include <chrono>
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
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/tracker.hpp"

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
    rekon::optimiser::PoseGraph graph(graph_params.graph);
    auto addEdge = [&](rekon::optimiser::EdgeKind kind, int64_t from, int64_t to, const rekon::Pose& relative,
                       const rekon::tracker::Matrix6d& information) {
      rekon::optimiser::Constraint c;
      c.kind = kind;
      c.from_id = from;
      c.to_id = to;
      c.relative = relative;
      c.information = graph_params.information_scale * information;
      graph.addConstraint(c);
    };
    struct FrameInKeyframe {
      double timestamp;
      int64_t keyframe_id;
      rekon::Pose pose_in_keyframe;
    };
    std::vector<FrameInKeyframe> frames;
    rekon::Trajectory odometry_trajectory;
    rekon::DatasetOptions options;
    options.max_frames = argc > 2 ? std::stoi(argv[2]) : 0;
    const rekon::TumDataset dataset(argv[1], options);
    if (!dataset.hasGroundTruth()) throw rekon::Error(std::string(argv[1]) + " has no groundtruth.txt");
    const rekon::Trajectory gt = dataset.groundTruth();
    rekon::tracker::Tracker tracker(params);
    rekon::tracker::LoopClosureDetector detector(params);
    rekon::tracker::LoopClosureStats stats;
    std::map<int64_t, rekon::Pose> kf_truth;
    std::vector<std::pair<int64_t, rekon::Pose>> keyframe_poses;
    std::vector<rekon::tracker::OdometryConstraint> odometry_edges;
    std::vector<rekon::tracker::LoopConstraint> loop_edges;
    std::vector<double> odometry_chi2, loop_chi2;
    auto chi2AtTruth = [&](int64_t from, int64_t to, const rekon::Pose& relative, const rekon::tracker::Matrix6d& info) {
      const rekon::optimiser::Vector6d r =
          rekon::optimiser::relativePoseResidual(kf_truth[from], kf_truth[to], relative);
      return graph_params.information_scale * r.dot(info * r);
    };
    ErrorStats loops, odometry;
    double check_ms = 0.0;
    int far_loops = 0;
    for (size_t i = 0; i < dataset.size(); ++i) {
      rekon::RgbdFrame f = dataset.load(i);
      f.id = static_cast<int64_t>(i);
      const auto r = tracker.track(f, dataset.intrinsics());
      frames.push_back({r.timestamp, r.keyframe_id, r.pose_in_keyframe});
      odometry_trajectory.push_back({r.timestamp, r.pose_world});
      if (!r.new_keyframe) continue;
      graph.addKeyframe(r.keyframe_id, r.keyframe_pose_world);
      keyframe_poses.emplace_back(r.keyframe_id, r.keyframe_pose_world);
      if (r.odometry) odometry_edges.push_back(*r.odometry);
      if (r.odometry)
        addEdge(rekon::optimiser::EdgeKind::Odometry, r.odometry->from_id, r.odometry->to_id, r.odometry->relative,
                r.odometry->information);
      const int g = rekon::nearestInTime(gt, r.timestamp, 0.02);
      if (g < 0) continue;
      kf_truth[r.keyframe_id] = gt[static_cast<size_t>(g)].pose;
      if (r.odometry && kf_truth.count(r.odometry->from_id)) {
        odometry.add(r.odometry->relative, kf_truth[r.odometry->from_id].inverse() * kf_truth[r.keyframe_id]);
        odometry_chi2.push_back(chi2AtTruth(r.odometry->from_id, r.keyframe_id, r.odometry->relative, r.odometry->information));
      }
      const auto t0 = std::chrono::steady_clock::now();
      detector.addKeyframe(tracker.currentKeyframe(), r.odometry);
      for (const auto& c : detector.detect(r.keyframe_id, stats)) {
        if (getenv("ORACLE") && kf_truth.count(c.from_id)) addEdge(rekon::optimiser::EdgeKind::Loop, c.from_id, c.to_id, kf_truth[c.from_id].inverse() * kf_truth[c.to_id], c.information); else
        addEdge(rekon::optimiser::EdgeKind::Loop, c.from_id, c.to_id, c.relative, c.information);
        loop_edges.push_back(c);
        if (!kf_truth.count(c.from_id)) continue;
        loop_chi2.push_back(chi2AtTruth(c.from_id, c.to_id, c.relative, c.information));
        const rekon::Pose truth = kf_truth[c.from_id].inverse() * kf_truth[c.to_id];
        loops.add(c.relative, truth);
        if (getenv("DUMP")) std::printf("DUMP %.4f %.3f %.3f %.3f %.2f %d %ld %.4f %.4f %.4f\n", rekon::translationDistance(c.relative, truth), c.coarse_ratio, c.fine_ratio, truth.translation().norm(), rekon::rotationAngle(truth, rekon::Pose::Identity())*57.3, c.valid_pixels, static_cast<long>(c.to_id - c.from_id), c.cross_check_m, c.intensity_sigma, c.depth_sigma);
        if (rekon::translationDistance(c.relative, truth) > 0.08) {
          ++far_loops;
          std::printf("loop %ld -> %ld off by %.3f m %.2f deg (ratios %.3f %.3f, %d px)\n", static_cast<long>(c.from_id),
                      static_cast<long>(c.to_id), rekon::translationDistance(c.relative, truth),
                      rekon::rotationAngle(c.relative, truth) * 180.0 / std::numbers::pi, c.coarse_ratio, c.fine_ratio,
                      c.valid_pixels);
        }
      }
      check_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    }
    const auto report = graph.optimise(true);
    rekon::Trajectory optimised;
    for (const auto& f : frames) {
      if (const auto kf = graph.pose(f.keyframe_id)) optimised.push_back({f.timestamp, *kf * f.pose_in_keyframe});
    }
    std::printf("graph: %zu keyframes, %zu loop edges kept, %zu removed, %.1f ms\n", graph.numKeyframes(),
                graph.numLoopEdges(), graph.loopEdgesRemoved(), report.ms);
    const double ate_odometry = rekon::eval::evaluateTrajectory(gt, odometry_trajectory).ate_rmse_m;
    const double ate_loops = rekon::eval::evaluateTrajectory(gt, optimised).ate_rmse_m;
    std::printf("ate_odometry_m=%.4f ate_with_loops_m=%.4f ratio=%.3f\n", ate_odometry, ate_loops,
                ate_loops / ate_odometry);
    odometry.print("odometry constraints");
    loops.print("loop constraints");
    std::printf("keyframes=%ld candidates=%ld accepted=%ld rejected=%ld off_by_more_than_8cm=%d check_ms_per_keyframe=%.1f\n",
                static_cast<long>(stats.keyframes_checked), static_cast<long>(stats.candidates),
                static_cast<long>(stats.accepted), static_cast<long>(stats.rejected), far_loops,
                check_ms / static_cast<double>(std::max<int64_t>(stats.keyframes_checked, 1)));
    std::printf("chi2 at the ground truth (information x %.0e): odometry median %.1f p90 %.1f, loops median %.1f p90 %.1f "
                "(6 dof: 5.35 median if calibrated)\n",
                graph_params.information_scale, ErrorStats::quantile(odometry_chi2, 0.5),
                ErrorStats::quantile(odometry_chi2, 0.9), ErrorStats::quantile(loop_chi2, 0.5),
                ErrorStats::quantile(loop_chi2, 0.9));
    if (getenv("SWEEP")) {
      // The same keyframes and constraints, optimised again: loop edges kept
      // when their cross check is within `max_cross`, their information x `weight`.
      struct Filter {
        double min_fine_ratio, max_cross, max_depth_sigma;
        int min_gap;
      };
      auto ateWith = [&](const Filter& f, size_t* kept) {
        rekon::optimiser::PoseGraph g(graph_params.graph);
        for (const auto& [id, pose] : keyframe_poses) g.addKeyframe(id, pose);
        auto add = [&](rekon::optimiser::EdgeKind kind, int64_t from, int64_t to, const rekon::Pose& rel,
                       const rekon::tracker::Matrix6d& info) {
          rekon::optimiser::Constraint c;
          c.kind = kind;
          c.from_id = from;
          c.to_id = to;
          c.relative = rel;
          c.information = graph_params.information_scale * info;
          g.addConstraint(c);
        };
        for (const auto& o : odometry_edges)
          add(rekon::optimiser::EdgeKind::Odometry, o.from_id, o.to_id, o.relative, o.information);
        for (const auto& l : loop_edges) {
          if (l.cross_check_m <= f.max_cross && l.depth_sigma <= f.max_depth_sigma && l.fine_ratio >= f.min_fine_ratio &&
              l.to_id - l.from_id >= f.min_gap)
            add(rekon::optimiser::EdgeKind::Loop, l.from_id, l.to_id, l.relative, l.information);
        }
        g.optimise(true);
        *kept = g.numLoopEdges();
        rekon::Trajectory t;
        for (const auto& fr : frames) {
          if (const auto kf = g.pose(fr.keyframe_id)) t.push_back({fr.timestamp, *kf * fr.pose_in_keyframe});
        }
        return rekon::eval::evaluateTrajectory(gt, t).ate_rmse_m;
      };
      for (const double ratio : {0.0, 0.85, 0.9, 0.95}) {
        for (const int gap : {1, 5, 10, 20, 30}) {
          for (const double cross : {0.05, 0.02}) {
            for (const double depth_sigma : {1e9, 0.05}) {
              size_t kept = 0;
              const double ate = ateWith({ratio, cross, depth_sigma, gap}, &kept);
              std::printf("SWEEP min_fine_ratio %.2f min_gap %d max_cross %.2f max_depth_sigma %.2f: %zu loops kept, "
                          "ATE %.4f m (ratio %.3f)\n",
                          ratio, gap, cross, std::min(depth_sigma, 9.99), kept, ate, ate / ate_odometry);
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
