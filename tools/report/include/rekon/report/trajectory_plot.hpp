#pragma once
// Trajectories seen from above: the camera positions projected onto two world
// axes, one metre as long on both, for the run report.
#include <string>
#include <utility>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/report/plot.hpp"

namespace rekon::report {

enum class TopView {
  MostExtent,  // the two world axes along which the reference moves most
  XY,          // world x and y (z up, as in rekon's synthetic scenes)
};

// The two axes (0 = x, 1 = y, 2 = z) of the view, smaller index first.
std::pair<int, int> topViewAxes(const Trajectory& reference, TopView view);

struct NamedTrajectory {
  std::string name;
  Trajectory trajectory;
  bool dashed = false;
};

// One series per trajectory; the axes are chosen on the first one (the
// reference, e.g. the ground truth). Throws rekon::Error when there is none.
LinePlot trajectoryPlot(const std::vector<NamedTrajectory>& trajectories, TopView view, const std::string& title);

}  // namespace rekon::report
