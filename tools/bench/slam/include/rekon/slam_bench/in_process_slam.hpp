#pragma once
// The tracker, its loop-closure detector (every new keyframe checked at once,
// on the calling thread) and rekon_optimiser's PoseGraph in one process over
// a dataset: what rekon run's tracker and optimiser compute, without the
// timing of their threads, so the result is the same every run. Used by
// loop_closure_bench and the real-data loop-closure test (tests/tracker).
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "rekon/common/dataset.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/tracker/loop_closure.hpp"
#include "rekon/tracker/params.hpp"

namespace rekon::slam_bench {

struct KeyframeAt {
  int64_t id = -1;
  double timestamp = 0.0;
  Pose pose_world = Pose::Identity();  // the tracker's
};

struct InProcessSlam {
  Trajectory odometry;  // the tracker's pose of every frame
  std::vector<optimiser::TrackedFrame> frames;  // what the tracker publishes of each frame
  std::vector<KeyframeAt> keyframes;
  std::vector<tracker::OdometryConstraint> odometry_edges;
  std::vector<tracker::LoopConstraint> loop_edges;
  // tracker.keyframe_reuse's edges (TrackResult::reuse_edge), loop edges in the graph as in rekon-optimiser.
  std::vector<tracker::OdometryConstraint> reuse_edges;
  int64_t keyframes_reused = 0, keyframe_reuse_checks = 0;
  tracker::LoopClosureStats stats;
  double check_ms = 0.0;  // wall time of all loop checks
};

// Tracks every frame of `dataset` and checks every new keyframe for loops.
InProcessSlam runInProcess(const TumDataset& dataset, const tracker::TrackerParams& params);

struct Optimised {
  Trajectory trajectory;  // every frame, as rekon-optimiser writes trajectory.txt (frameTrajectory)
  size_t loop_edges_kept = 0, loop_edges_removed = 0;
  double ms = 0.0;
};

// The pose of a loop edge in the graph, or none to leave the edge out.
using LoopPose = std::function<std::optional<Pose>(const tracker::LoopConstraint&)>;

// The keyframe graph of `slam` (information x params.information_scale),
// optimised as rekon-optimiser's final optimisation. `loop_pose` (default:
// each loop's own relative pose) filters or replaces the loop edges.
Optimised optimise(const InProcessSlam& slam, const optimiser::OptimiserServiceParams& params,
                   const LoopPose& loop_pose = {});

}  // namespace rekon::slam_bench
