#pragma once
// The sections of the run report, each appending its HTML to a Page and
// naming the inputs it did not find.
#include <filesystem>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/eval/trajectory_eval.hpp"
#include "rekon/report/plot.hpp"
#include "rekon/report/run_report.hpp"

namespace rekon::report {

struct Page {
  std::ostringstream body;
  std::vector<std::string> absent;
  std::string plot_dir;
  size_t images = 0;

  void absentInput(const std::string& what);
  // Saves the plot under plot_dir as <stem>.svg + .csv and shows it inline.
  void plot(const LinePlot& p, const std::string& stem);
  // The first column is text, the others right-aligned numbers.
  void table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows);
};

std::string number(double v, int decimals);

struct TrajectoryInputs {
  std::optional<Trajectory> ground_truth, estimate, odometry;
};
TrajectoryInputs readTrajectories(const std::filesystem::path& run, const std::string& gt_path, Page& page);

std::optional<eval::TrajectoryErrors> trajectorySection(Page& page, const TrajectoryInputs& in, const RunReportOptions& options);
// mesh.ply and mesh_uncorrected.ply rendered, and with `gt_mesh` (a
// ground-truth surface; "" for none) their CORR and COMPL against it.
void meshSection(Page& page, const std::filesystem::path& run, const RunReportOptions& options, const TrajectoryInputs& in,
                 const std::string& gt_mesh);
void timingSection(Page& page, const std::filesystem::path& run, const std::vector<std::string>& services);
void reintegrationSection(Page& page, const std::filesystem::path& run);
void statsSection(Page& page, const std::filesystem::path& run);
// Peak RSS per service, the mapper's keyframe and voxel bytes against the
// input's (stats.json), and RSS over time (rss.csv).
void memorySection(Page& page, const std::filesystem::path& run);
// config.yaml (folded) and, per service log, its warnings and errors.
void setupSection(Page& page, const std::filesystem::path& run, const std::vector<std::string>& services);

}  // namespace rekon::report
