#pragma once
// Rigid poses (Eigen::Isometry3d, camera-to-world unless named otherwise) and
// TUM-format trajectories ("timestamp tx ty tz qx qy qz qw" per line).
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace rekon {

using Pose = Eigen::Isometry3d;

// True when every entry is finite and the rotation is orthonormal with det +1.
bool isValidPose(const Pose& pose, double tolerance = 1e-6);
// Throws rekon::Error naming `what` when the pose is not valid.
void requireValidPose(const Pose& pose, const std::string& what);

Pose poseFromQuatTrans(const Eigen::Quaterniond& q, const Eigen::Vector3d& t);
// Re-orthonormalises a rotation drifted by float rounding (nearest rotation).
Pose orthonormalised(const Pose& pose);
// The world pose of a keyframe newer than the pose graph: its odometry pose
// `odometry` moved as the graph moved the newest earlier keyframe it has
// (graph pose `anchor_graph`, odometry pose `anchor_odometry`).
Pose movedWithGraph(const Pose& anchor_graph, const Pose& anchor_odometry, const Pose& odometry);

// Translation distance and rotation angle (radians) between two poses.
double translationDistance(const Pose& a, const Pose& b);
double rotationAngle(const Pose& a, const Pose& b);

struct StampedPose {
  double timestamp = 0.0;
  Pose pose = Pose::Identity();
};
using Trajectory = std::vector<StampedPose>;

// Reads a TUM trajectory; lines starting with '#' are comments. Throws
// rekon::Error naming the file and line for a malformed or non-finite entry.
Trajectory readTumTrajectory(const std::string& path);
void writeTumTrajectory(const Trajectory& trajectory, const std::string& path);

// Index of the entry nearest in time to `timestamp` within max_difference, or -1.
int nearestInTime(const Trajectory& trajectory, double timestamp, double max_difference);

}  // namespace rekon
