#include "rekon/slam_bench/in_process_slam.hpp"

#include <chrono>

#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/tracker/tracker.hpp"

namespace rekon::slam_bench {

using tracker::LoopClosureDetector;
using tracker::LoopConstraint;
using tracker::OdometryConstraint;
using tracker::Tracker;
using tracker::TrackerParams;
using tracker::TrackResult;

InProcessSlam runInProcess(const TumDataset& dataset, const TrackerParams& params) {
  InProcessSlam out;
  Tracker tracker(params);
  LoopClosureDetector detector(params);
  for (size_t i = 0; i < dataset.size(); ++i) {
    RgbdFrame f = dataset.load(i);
    f.id = static_cast<int64_t>(i);
    const TrackResult r = tracker.track(f, dataset.intrinsics());
    out.frames.push_back({f.id, r.timestamp, r.keyframe_id, r.pose_in_keyframe});
    out.odometry.push_back({r.timestamp, r.pose_world});
    if (r.reuse_edge) out.reuse_edges.push_back(*r.reuse_edge);
    out.keyframes_reused += r.keyframe_reused;
    if (!r.new_keyframe) continue;
    out.keyframes.push_back({r.keyframe_id, r.timestamp, r.keyframe_pose_world});
    if (r.odometry) out.odometry_edges.push_back(*r.odometry);
    const auto t0 = std::chrono::steady_clock::now();
    detector.addKeyframe(tracker.currentKeyframe(), r.odometry);
    for (const LoopConstraint& c : detector.detect(r.keyframe_id, out.stats)) out.loop_edges.push_back(c);
    out.check_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  out.keyframe_reuse_checks = tracker.keyframeReuseChecks();
  return out;
}

Optimised optimise(const InProcessSlam& slam, const optimiser::OptimiserServiceParams& params,
                   const LoopPose& loop_pose) {
  optimiser::PoseGraph graph(params.graph);
  for (const KeyframeAt& k : slam.keyframes) graph.addKeyframe(k.id, k.pose_world);
  auto add = [&](optimiser::EdgeKind kind, int64_t from, int64_t to, const Pose& relative, const Matrix6d& info) {
    optimiser::Constraint c;
    c.kind = kind;
    c.from_id = from;
    c.to_id = to;
    c.relative = relative;
    c.information = params.information_scale * info;
    graph.addConstraint(c);
  };
  for (const OdometryConstraint& o : slam.odometry_edges)
    add(optimiser::EdgeKind::Odometry, o.from_id, o.to_id, o.relative, o.information);
  for (const OdometryConstraint& e : slam.reuse_edges)
    add(optimiser::EdgeKind::Loop, e.from_id, e.to_id, e.relative, e.information);
  for (const LoopConstraint& l : slam.loop_edges) {
    const std::optional<Pose> relative = loop_pose ? loop_pose(l) : std::optional<Pose>(l.relative);
    if (relative) add(optimiser::EdgeKind::Loop, l.from_id, l.to_id, *relative, l.information);
  }
  Optimised out;
  out.ms = graph.optimise(true).ms;
  out.loop_edges_kept = graph.numLoopEdges();
  out.loop_edges_removed = graph.loopEdgesRemoved();
  out.trajectory = optimiser::frameTrajectory(graph, slam.frames, nullptr);
  return out;
}

}  // namespace rekon::slam_bench
