#include "rekon/report/trajectory_plot.hpp"

#include <algorithm>
#include <numeric>

#include "rekon/common/error.hpp"

namespace rekon::report {

std::pair<int, int> topViewAxes(const Trajectory& reference, TopView view) {
  if (view == TopView::XY || reference.empty()) return {0, 1};
  Eigen::Vector3d lo = reference.front().pose.translation(), hi = lo;
  for (const auto& p : reference) {
    lo = lo.cwiseMin(p.pose.translation());
    hi = hi.cwiseMax(p.pose.translation());
  }
  const Eigen::Vector3d extent = hi - lo;
  std::array<int, 3> order{0, 1, 2};
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return extent[a] > extent[b]; });
  return {std::min(order[0], order[1]), std::max(order[0], order[1])};
}

LinePlot trajectoryPlot(const std::vector<NamedTrajectory>& trajectories, TopView view, const std::string& title) {
  if (trajectories.empty()) throw Error("trajectory plot '" + title + "' has no trajectory; give at least one");
  const auto [a, b] = topViewAxes(trajectories.front().trajectory, view);
  const char* names[] = {"x", "y", "z"};
  PlotOptions options;
  options.title = title;
  options.x_label = std::string(names[a]) + " [m]";
  options.y_label = std::string(names[b]) + " [m]";
  options.equal_aspect = true;
  options.height = PlotOptions::kDefaultWidth * 3 / 4;
  LinePlot plot(options);
  for (const auto& t : trajectories) {
    Series s;
    s.name = t.name;
    s.dashed = t.dashed;
    for (const auto& p : t.trajectory) {
      s.x.push_back(p.pose.translation()[a]);
      s.y.push_back(p.pose.translation()[b]);
    }
    plot.add(std::move(s));
  }
  return plot;
}

}  // namespace rekon::report
