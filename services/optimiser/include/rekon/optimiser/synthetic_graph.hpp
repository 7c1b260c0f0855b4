#pragma once
// Synthetic pose graphs with known poses, for tests and the benchmark: a
// camera circling a room `laps` times, odometry edges between consecutive
// keyframes and loop edges between keyframes that revisit a place on a later
// lap. Every edge is the true relative pose perturbed by Gaussian noise drawn
// with the covariance its information matrix claims.
#include <cstdint>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/optimiser/pose_graph.hpp"

namespace rekon::optimiser {

struct SyntheticGraphSpec {
  int keyframes = 100;
  int laps = 1;               // loop edges need at least 2
  int loop_edges = 0;
  double radius_m = 2.0;      // of the circle the camera travels
  double sigma_translation_m = 0.005;  // per edge, each axis
  double sigma_rotation_rad = 0.002;   // per edge, each axis
  uint64_t seed = 1;
};

struct SyntheticGraph {
  std::vector<Pose> truth;    // keyframe i has id i
  std::vector<Pose> initial;  // chained odometry from truth[0], as a tracker reports it
  std::vector<Constraint> constraints;
};

// Information diag(1/sigma_t^2 x3, 1/sigma_r^2 x3) in (v, w) order.
Matrix6d isotropicInformation(double sigma_translation_m, double sigma_rotation_rad);

SyntheticGraph makeSyntheticGraph(const SyntheticGraphSpec& spec);

// How far keyframe k of a one-lap graph closed by one exact loop edge may lie
// from the truth: the error is a Brownian bridge pinned at both ends, with
// per-axis standard deviation s * sqrt(k (N - k) / N) where s combines the
// translation noise and the rotation noise at the circle's diameter as lever
// arm. The bound is `sigmas` of those per axis, in 3-D (sqrt(3) * sigmas * sd).
double loopClosureErrorBound(const SyntheticGraphSpec& spec, int k, double sigmas);

// Largest camera-centre distance between estimate and truth (same frame:
// keyframe 0 is fixed at its true pose).
double maxTranslationError(const std::vector<Pose>& truth, const std::vector<std::pair<int64_t, Pose>>& estimate);

}  // namespace rekon::optimiser
