#include <spdlog/spdlog.h>

#include <iostream>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/report/run_report.hpp"

namespace rekon::report {

int reportCommand(int argc, char** argv) {
  ArgParser args("rekon report", "Writes report.html into a run folder of rekon run: mesh views, trajectory against "
                                 "ground truth, per-frame timing, re-integration activity and stats, all inside one page.");
  args.option("run", "the --out folder of rekon run (required)")
      .option("groundtruth", "TUM ground-truth trajectory (default: <dataset>/groundtruth.txt, dataset from <run>/dataset.txt)")
      .option("width", "width of the mesh renderings in pixels", std::to_string(RunReportOptions::kDefaultImageWidth))
      .option("height", "height of the mesh renderings in pixels", std::to_string(RunReportOptions::kDefaultImageHeight))
      .option("top-view", "trajectory plot axes: extent (the two the ground truth spans most) or xy", "extent");
  if (!args.parse(argc, argv)) return 0;
  if (args.get("run").empty()) throw Error("--run is required; see rekon report --help");
  RunReportOptions options;
  options.groundtruth = args.get("groundtruth");
  options.image_width = args.getInt("width");
  options.image_height = args.getInt("height");
  if (options.image_width < 16 || options.image_height < 16) {
    throw Error("--width and --height must be at least 16 pixels");
  }
  const std::string view = args.get("top-view");
  if (view == "xy") options.top_view = TopView::XY;
  else if (view != "extent") throw Error("--top-view '" + view + "' is not one of: extent, xy");
  const RunReportResult result = writeRunReport(args.get("run"), options);
  std::cout << result.html_path << "\n";
  return 0;
}

}  // namespace rekon::report
