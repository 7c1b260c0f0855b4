#pragma once
// Which KF keyframes to correct on a pose-graph update (paper section 4.3):
// the movement of a keyframe is ||s t_i - s t'_i|| over its Euler angles and
// translation with s = (2, 2, 2, 1, 1, 1); BundleFusion re-integrates the m
// most-moved keyframes, the paper the m consecutive ones with the largest
// summed movement (eq. 3), so that the streaming sphere moves once.
#include <cstddef>
#include <string>
#include <vector>

#include "rekon/common/pose.hpp"

namespace rekon::mapper {

// kNone: keyframes are integrated once and never corrected (the baseline of the evaluation).
enum class ReintegrationMode { kConsecutive, kMostMoved, kNone };
ReintegrationMode parseReintegrationMode(const std::string& text);  // "consecutive" | "most_moved" | "none"
std::string toString(ReintegrationMode mode);

// Rotation as Z-Y-X Euler angles (roll about x, pitch about y, yaw about z), then translation.
Eigen::Matrix<double, 6, 1> eulerAndTranslation(const Pose& pose);
// ||s t - s t'||, angle differences wrapped to (-pi, pi].
double poseMovement(const Pose& integrated, const Pose& updated);

// Eq. (3): the 0-based j* maximising the sum of movement[j .. j+m-1] over
// j in [0, K-m] (the first such j on ties); all K when K <= m. Returns the
// indices of that window whose movement exceeds min_movement (none when no
// keyframe moved). With near_slack > 0 and a distance per keyframe (from the
// camera), the window chosen is instead the nearest (smallest summed
// distance) of those whose summed movement is at least (1 - near_slack) x the
// largest: nearly the same correction, with blocks that are active already.
std::vector<size_t> selectConsecutive(const std::vector<double>& movement, int m, double min_movement = 0.0,
                                      const std::vector<double>& distance = {}, double near_slack = 0.0);
// BundleFusion: the m largest movements above min_movement, in descending order.
std::vector<size_t> selectMostMoved(const std::vector<double>& movement, int m, double min_movement = 0.0);
std::vector<size_t> selectForReintegration(ReintegrationMode mode, const std::vector<double>& movement, int m,
                                           double min_movement, const std::vector<double>& distance = {},
                                           double near_slack = 0.0);

}  // namespace rekon::mapper
