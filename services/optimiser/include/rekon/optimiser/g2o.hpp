#pragma once
// The pose graph in g2o's text format, which g2o, GTSAM's readG2o and most
// SLAM tools read: VERTEX_SE3:QUAT per keyframe (its current world pose),
// FIX for the graph's anchor, EDGE_SE3:QUAT per kept edge (the relative pose
// to-in-from and the 21 upper-triangular entries of its information). g2o's
// rotation error is the quaternion's vector part, half of rekon's
// (relativePoseResidual), so the rotational information is scaled by 4 and
// the mixed blocks by 2: the same chi2 in both tools. A culled keyframe
// (PoseGraph::cullLinks) is an odometry edge that holds it rigidly to the
// keyframe it was culled onto.
//
// g2o has no edge kinds: rekon writes the odometry edges first, then the
// comment line kG2oLoopMarker, then the loop edges. Readers skip comments; a
// file without the marker (another tool's) reads as odometry only.
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "rekon/optimiser/pose_graph.hpp"

namespace rekon::optimiser {

inline constexpr std::string_view kG2oLoopMarker = "# rekon: the edges below are loop closures";

std::string toG2o(const PoseGraph& graph);

// What a g2o file holds, in file order, the information in rekon's units.
struct G2oGraph {
  std::vector<std::pair<int64_t, Pose>> vertices;
  std::optional<int64_t> fixed;
  std::vector<Constraint> edges;
};

// The inverse of toG2o. `name` (the file's path) heads each error: a
// rekon::Error of one line naming it, the line number and what is wrong (an
// unknown tag, a missing, extra or non-finite field, a quaternion that is not
// unit, a duplicate vertex, an edge or FIX naming an unknown vertex).
G2oGraph parseG2o(const std::string& text, const std::string& name);
// parseG2o of the file at `path`; rekon::Error naming it when unreadable.
G2oGraph readG2oFile(const std::string& path);

}  // namespace rekon::optimiser
