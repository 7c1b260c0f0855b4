// Keyframe culling (issue 49): on a synthetic room walked three times, with
// loop edges between the laps, a graph that culls the revisits onto the first
// lap's keyframes gives the trajectory of the graph that keeps them all,
// within a stated tolerance, with fewer keyframes and edges.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "rekon/common/pose.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"

namespace rekon::optimiser {
namespace {

// Three laps of 40 keyframes around a 2 m circle (31 cm apart, so no two
// neighbours on a lap are within the culling radius), 5 mm / 2 mrad noise per
// edge and axis, 300 loop edges between a keyframe and one 1 or 2 laps later.
SyntheticGraphSpec roomSpec() { return {.keyframes = 120, .laps = 3, .loop_edges = 300, .seed = 11}; }

// Culling within 10 cm and 15 degrees: a loop edge joins a revisit to the
// keyframe 0-2 places from its first-lap place (0-62 cm away, 31 cm apart),
// so the revisits with an edge to their own place are culled.
PoseGraphParams cullingParams() {
  PoseGraphParams p;
  p.cull_radius_m = 0.2;
  p.cull_angle_deg = 15.0;
  return p;
}

// As the tracker sends it: each keyframe, then the edges that end at it (its
// odometry edge, then its loop edges to earlier keyframes), an optimisation
// after each keyframe's batch, and the final one.
void addAsItArrives(PoseGraph& graph, const SyntheticGraph& g) {
  for (size_t k = 0; k < g.initial.size(); ++k) {
    const auto id = static_cast<int64_t>(k);
    graph.addKeyframe(id, g.initial[k]);
    for (const Constraint& c : g.constraints) {
      if (std::max(c.from_id, c.to_id) == id) graph.addConstraint(c);
    }
    graph.optimise(false);
  }
  graph.optimise(true);
}

double maxDistance(const std::vector<std::pair<int64_t, Pose>>& a, const std::vector<std::pair<int64_t, Pose>>& b) {
  EXPECT_EQ(a.size(), b.size());
  double worst = 0.0;
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    EXPECT_EQ(a[i].first, b[i].first);
    worst = std::max(worst, translationDistance(a[i].second, b[i].second));
  }
  return worst;
}

TEST(PoseGraphCulling, GivesTheTrajectoryOfTheUnboundedGraphWithFewerKeyframesAndEdges) {
  const SyntheticGraph g = makeSyntheticGraph(roomSpec());
  PoseGraph full;
  addAsItArrives(full, g);
  PoseGraph culled(cullingParams());
  addAsItArrives(culled, g);

  // Every keyframe still has a pose (culled ones derived from their kept keyframe).
  ASSERT_EQ(culled.numKeyframes(), g.truth.size());
  const double apart = maxDistance(full.poses(), culled.poses());
  const double full_error = maxTranslationError(g.truth, full.poses());
  const double culled_error = maxTranslationError(g.truth, culled.poses());
  // Measured (2026-12-06, this seed): 24 of the 80 revisits culled, 309 of 418 edges kept (85 merged, 24
  // dropped), the two graphs at most 3.46 mm apart, the largest error from the truth 16.95 mm against
  // 16.91 mm unbounded. Bounds with margin: 6 mm apart (1.7x), the error at most 10 % above the
  // unbounded graph's (measured 0.2 %), at least 12 keyframes culled and 60 edges fewer (half of what was
  // measured: culling that stopped would fail them).
  EXPECT_LT(apart, 0.006);
  EXPECT_LT(culled_error, 1.1 * full_error);
  EXPECT_GE(culled.numCulled(), 12u);
  EXPECT_LE(culled.numConstraints() + 60, full.numConstraints());
  std::printf("culled %zu of %zu keyframes, %zu of %zu edges kept (%zu merged, %zu dropped); max apart %.2f mm, error "
              "%.2f mm (unbounded %.2f mm)\n",
              culled.numCulled(), culled.numKeyframes(), culled.numConstraints(), full.numConstraints(),
              culled.edgesMerged(), culled.edgesDroppedByCulling(), 1e3 * apart, 1e3 * culled_error,
              1e3 * full_error);
}

// The cap on moved loop edges (loop_neighbours_max): four laps, so that each first-lap keyframe gets the
// edges of three revisits, culled onto it and its neighbours. Past the cap a revisit's edge is re-routed
// onto a pair its kept keyframe has already (the information kept, rigidly at the current poses) instead
// of pairing it with one more keyframe.
TEST(PoseGraphCulling, CappedMovedLoopEdgesPairFewerKeyframesAndKeepTheTrajectory) {
  const SyntheticGraph g = makeSyntheticGraph({.keyframes = 160, .laps = 4, .loop_edges = 600, .seed = 11});
  PoseGraph uncapped(cullingParams());
  addAsItArrives(uncapped, g);
  PoseGraphParams params = cullingParams();
  params.loop_neighbours_max = 2;
  PoseGraph capped(params);
  addAsItArrives(capped, g);

  const double apart = maxDistance(uncapped.poses(), capped.poses());
  const double uncapped_error = maxTranslationError(g.truth, uncapped.poses());
  const double capped_error = maxTranslationError(g.truth, capped.poses());
  std::printf("capped: %zu loop edges (uncapped %zu), %zu re-routed, %zu dropped; max apart %.2f mm, error %.2f mm "
              "(uncapped %.2f mm)\n",
              capped.numLoopEdges(), uncapped.numLoopEdges(), capped.edgesRerouted(), capped.edgesDroppedByCap(),
              1e3 * apart, 1e3 * capped_error, 1e3 * uncapped_error);
  // Measured (2026-12-07, this seed): 240 loop edges against 303, 89 re-routed, none dropped; the graphs
  // at most 5.63 mm apart, the largest error from the truth 20.75 mm against 20.04 mm uncapped (+3.5 %).
  // Bounds with margin: at least 40 re-routed and 30 loop edges fewer (about half of what was measured: a
  // cap that stopped working fails them), 9 mm apart (1.6x), the error at most 10 % above the uncapped one.
  EXPECT_GE(capped.edgesRerouted(), 40u);
  EXPECT_LE(capped.numLoopEdges() + 30, uncapped.numLoopEdges());
  EXPECT_LT(apart, 0.009);
  EXPECT_LT(capped_error, 1.1 * uncapped_error);
}

// One pass of 100 keyframes round the 2 m circle, 12.6 cm apart: each is within the culling radius of
// its predecessor and linked to it by odometry, but no keyframe is a revisit, so none is culled and the
// graph is the unbounded one. (Culling a pass's own neighbours froze what its loop edges average.)
TEST(PoseGraphCulling, NeverCullsAKeyframeOntoANeighbourOfItsOwnPass) {
  const SyntheticGraph g = makeSyntheticGraph({.keyframes = 100, .laps = 1, .seed = 5});
  PoseGraph full;
  addAsItArrives(full, g);
  PoseGraph culled(cullingParams());
  addAsItArrives(culled, g);
  EXPECT_EQ(culled.numCulled(), 0u);
  EXPECT_EQ(culled.numConstraints(), full.numConstraints());
  EXPECT_LT(maxDistance(full.poses(), culled.poses()), 1e-9);
}

}  // namespace
}  // namespace rekon::optimiser
