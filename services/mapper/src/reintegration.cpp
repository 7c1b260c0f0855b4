#include "rekon/mapper/reintegration.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "rekon/common/error.hpp"

namespace rekon::mapper {

ReintegrationMode parseReintegrationMode(const std::string& text) {
  if (text == "consecutive") return ReintegrationMode::kConsecutive;
  if (text == "most_moved") return ReintegrationMode::kMostMoved;
  if (text == "none") return ReintegrationMode::kNone;
  throw Error("mapper.reintegration '" + text +
              "' is unknown; use consecutive (the paper), most_moved (BundleFusion) or none (never correct)");
}

std::string toString(ReintegrationMode mode) {
  switch (mode) {
    case ReintegrationMode::kConsecutive: return "consecutive";
    case ReintegrationMode::kMostMoved: return "most_moved";
    case ReintegrationMode::kNone: return "none";
  }
  return "?";
}

Eigen::Matrix<double, 6, 1> eulerAndTranslation(const Pose& pose) {
  const Eigen::Matrix3d r = pose.linear();
  Eigen::Matrix<double, 6, 1> v;
  v(0) = std::atan2(r(2, 1), r(2, 2));                                     // roll
  v(1) = std::asin(std::clamp(-r(2, 0), -1.0, 1.0));                        // pitch
  v(2) = std::atan2(r(1, 0), r(0, 0));                                     // yaw
  v.tail<3>() = pose.translation();
  return v;
}

double poseMovement(const Pose& integrated, const Pose& updated) {
  Eigen::Matrix<double, 6, 1> d = eulerAndTranslation(integrated) - eulerAndTranslation(updated);
  for (int i = 0; i < 3; ++i) d(i) = std::remainder(d(i), 2.0 * M_PI);
  const Eigen::Matrix<double, 6, 1> s = (Eigen::Matrix<double, 6, 1>() << 2, 2, 2, 1, 1, 1).finished();
  return s.cwiseProduct(d).norm();
}

namespace {

// Calls visit(j, window sum of a) for every window start j in [0, K - window].
template <typename Visit>
void slideWindow(const std::vector<double>& a, size_t window, Visit visit) {
  double sum = std::accumulate(a.begin(), a.begin() + static_cast<std::ptrdiff_t>(window), 0.0);
  visit(size_t{0}, sum);
  for (size_t j = 1; j + window <= a.size(); ++j) {
    sum += a[j + window - 1] - a[j - 1];  // sliding window: O(K) for all j
    visit(j, sum);
  }
}

}  // namespace

std::vector<size_t> selectConsecutive(const std::vector<double>& movement, int m, double min_movement,
                                      const std::vector<double>& distance, double near_slack) {
  if (m < 1) throw Error("mapper.m must be at least 1 (keyframes re-integrated per graph update)");
  if (!(near_slack >= 0.0 && near_slack < 1.0)) throw Error("mapper.near_window_slack must be in [0, 1)");
  const size_t k = movement.size(), window = std::min(k, static_cast<size_t>(m));
  if (k == 0) return {};
  double best = -1.0;
  size_t best_j = 0;
  slideWindow(movement, window, [&](size_t j, double sum) {
    if (sum > best) best = sum, best_j = j;
  });
  if (near_slack > 0.0 && distance.size() == k) {
    // Among the windows that moved nearly as much, the one nearest the camera
    // (smallest summed distance): its blocks are active already.
    std::vector<char> moved_enough(k - window + 1, 0);
    slideWindow(movement, window, [&](size_t j, double sum) { moved_enough[j] = sum >= (1.0 - near_slack) * best; });
    double nearest = -1.0;
    slideWindow(distance, window, [&](size_t j, double sum) {
      if (moved_enough[j] && (nearest < 0.0 || sum < nearest)) nearest = sum, best_j = j;
    });
  }
  std::vector<size_t> chosen;
  for (size_t i = best_j; i < best_j + window; ++i)
    if (movement[i] > min_movement) chosen.push_back(i);
  return chosen;
}

std::vector<size_t> selectMostMoved(const std::vector<double>& movement, int m, double min_movement) {
  if (m < 1) throw Error("mapper.m must be at least 1 (keyframes re-integrated per graph update)");
  std::vector<size_t> order;
  for (size_t i = 0; i < movement.size(); ++i)
    if (movement[i] > min_movement) order.push_back(i);
  const size_t n = std::min(order.size(), static_cast<size_t>(m));
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n), order.end(),
                    [&](size_t a, size_t b) { return movement[a] > movement[b] || (movement[a] == movement[b] && a < b); });
  order.resize(n);
  return order;
}

std::vector<size_t> selectForReintegration(ReintegrationMode mode, const std::vector<double>& movement, int m,
                                           double min_movement, const std::vector<double>& distance, double near_slack) {
  switch (mode) {
    case ReintegrationMode::kConsecutive: return selectConsecutive(movement, m, min_movement, distance, near_slack);
    case ReintegrationMode::kMostMoved: return selectMostMoved(movement, m, min_movement);
    case ReintegrationMode::kNone: return {};
  }
  return {};
}

}  // namespace rekon::mapper
