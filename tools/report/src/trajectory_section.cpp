#include <spdlog/spdlog.h>

#include "rekon/common/error.hpp"
#include "rekon/report/html.hpp"
#include "rekon/report/trajectory_plot.hpp"
#include "report_sections.hpp"

namespace rekon::report {
namespace fs = std::filesystem;
namespace {

std::optional<Trajectory> readOptional(const std::string& path, const std::string& what, Page& page) {
  if (path.empty()) return std::nullopt;
  if (!fs::exists(path)) {
    page.absentInput(what + ": " + path + " not found");
    return std::nullopt;
  }
  try {
    Trajectory t = readTumTrajectory(path);
    if (t.empty()) {
      page.absentInput(what + ": " + path + " has no poses");
      return std::nullopt;
    }
    return t;
  } catch (const Error& e) {
    page.absentInput(what + ": unreadable (" + std::string(e.what()) + ")");
    return std::nullopt;
  }
}

Trajectory aligned(const Trajectory& t, const Pose& alignment) {
  Trajectory out = t;
  for (auto& p : out) p.pose = alignment * p.pose;
  return out;
}

std::vector<std::string> errorRow(const std::string& name, const eval::TrajectoryErrors& e) {
  return {name, std::to_string(e.matched), number(e.ate_rmse_m * 100, 2), number(e.ate_mean_m * 100, 2),
          number(e.ate_median_m * 100, 2), number(e.ate_max_m * 100, 2), number(e.rpe_trans_m_per_s * 100, 2),
          number(e.rpe_rot_deg_per_s, 2)};
}

}  // namespace

TrajectoryInputs readTrajectories(const fs::path& run, const std::string& gt_path, Page& page) {
  TrajectoryInputs in;
  in.ground_truth = readOptional(gt_path, "ground truth", page);
  in.estimate = readOptional((run / "trajectory.txt").string(), "estimated trajectory (final poses)", page);
  in.odometry = readOptional((run / "odometry.txt").string(), "tracker odometry (before pose-graph optimisation)", page);
  return in;
}

std::optional<eval::TrajectoryErrors> trajectorySection(Page& page, const TrajectoryInputs& in,
                                                         const RunReportOptions& options) {
  page.body << "<h2>Trajectory seen from above</h2>\n";
  struct Estimate {
    const char* name;
    const std::optional<Trajectory>* trajectory;
    bool dashed;
  };
  const Estimate estimates[] = {{"estimate (trajectory.txt)", &in.estimate, false},
                                {"odometry (odometry.txt)", &in.odometry, true}};
  std::vector<NamedTrajectory> shown;
  if (in.ground_truth) shown.push_back({"ground truth", *in.ground_truth, false});
  std::optional<eval::TrajectoryErrors> ate;
  std::vector<std::vector<std::string>> rows;
  for (const auto& e : estimates) {
    if (!*e.trajectory) continue;
    if (!in.ground_truth) {
      shown.push_back({e.name, **e.trajectory, e.dashed});
      continue;
    }
    try {
      const eval::TrajectoryErrors errors = eval::evaluateTrajectory(*in.ground_truth, **e.trajectory);
      rows.push_back(errorRow(e.name, errors));
      shown.push_back({e.name, aligned(**e.trajectory, errors.alignment), e.dashed});
      if (e.trajectory == &in.estimate) ate = errors;
    } catch (const Error& err) {
      page.absentInput(std::string(e.name) + " against the ground truth: " + err.what());
      shown.push_back({std::string(e.name) + ", unaligned", **e.trajectory, e.dashed});
    }
  }
  if (shown.empty()) {
    page.body << "<p>No trajectory to show.</p>\n";
    return ate;
  }
  if (!rows.empty()) {
    page.body << "<p>Estimates rigidly aligned to the ground truth (Horn); errors as the TUM RGB-D benchmark measures them.</p>\n";
    page.table({"trajectory", "matched poses", "ATE RMSE [cm]", "ATE mean [cm]", "ATE median [cm]", "ATE max [cm]",
                "RPE [cm/s]", "RPE [deg/s]"},
               rows);
  } else if (!in.ground_truth) {
    page.body << "<p>No ground truth: the estimate is shown in its own frame.</p>\n";
  }
  page.plot(trajectoryPlot(shown, options.top_view, "camera positions seen from above"), "trajectory");
  return ate;
}

}  // namespace rekon::report
