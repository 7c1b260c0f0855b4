#pragma once
// The pose graph in g2o's text format, which g2o, GTSAM's readG2o and most
// SLAM tools read: VERTEX_SE3:QUAT per keyframe (its current world pose),
// FIX for the graph's anchor, EDGE_SE3:QUAT per kept edge (the relative pose
// to-in-from and the 21 upper-triangular entries of its information). g2o's
// rotation error is the quaternion's vector part, half of rekon's
// (relativePoseResidual), so the rotational information is scaled by 4 and
// the mixed blocks by 2: the same chi2 in both tools.
#include <string>

#include "rekon/optimiser/pose_graph.hpp"

namespace rekon::optimiser {

std::string toG2o(const PoseGraph& graph);

}  // namespace rekon::optimiser
