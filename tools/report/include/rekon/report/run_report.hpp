#pragma once
// The report of one `rekon run`: `<run_dir>/report.html`, a single page that
// opens offline (every image inside it) with the rendered final mesh (and the
// uncorrected one when the run kept it), the trajectory against ground truth
// seen from above with its ATE, per-frame timing of each service,
// re-integration activity over time and the stats table. Inputs a run did not
// produce are listed as absent; they never stop the report. The plots are
// also saved as SVG + CSV under `<run_dir>/report/`.
#include <optional>
#include <string>
#include <vector>

#include "rekon/eval/trajectory_eval.hpp"
#include "rekon/report/trajectory_plot.hpp"

namespace rekon::report {

// The file `rekon run` writes into the run folder with the dataset's path on
// its first line; the default ground truth is <that path>/groundtruth.txt.
inline constexpr const char* kDatasetPathFile = "dataset.txt";

struct RunReportOptions {
  static constexpr int kDefaultImageWidth = 800;
  static constexpr int kDefaultImageHeight = 600;
  std::string groundtruth;  // TUM trajectory; empty = from dataset.txt
  int image_width = kDefaultImageWidth;   // mesh renderings
  int image_height = kDefaultImageHeight;
  TopView top_view = TopView::MostExtent;
};

struct RunReportResult {
  std::string html_path;
  // One line per input the run did not have (or could not be read), with why.
  std::vector<std::string> absent;
  std::optional<eval::TrajectoryErrors> ate;  // trajectory.txt against the ground truth
  size_t images = 0;                          // inline images in the page
};

// Throws rekon::Error only when run_dir is not a folder or report.html cannot be written.
RunReportResult writeRunReport(const std::string& run_dir, const RunReportOptions& options = {});

// `rekon report --run DIR [--groundtruth FILE]`
int reportCommand(int argc, char** argv);

}  // namespace rekon::report
