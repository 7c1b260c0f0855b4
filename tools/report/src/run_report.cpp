#include "rekon/report/run_report.hpp"

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <set>
#include <sstream>

#include "report_sections.hpp"
#include "rekon/common/error.hpp"
#include "rekon/report/html.hpp"
#include "rekon/report/run_files.hpp"

namespace rekon::report {
namespace fs = std::filesystem;
namespace {

constexpr const char* kStyle =
    "body{font-family:sans-serif;margin:24px;max-width:1700px;color:#222}"
    "h1{font-size:22px}h2{font-size:18px;margin-top:32px;border-bottom:1px solid #ccc}"
    "table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
    "td.num{text-align:right;font-family:monospace}figure{display:inline-block;margin:8px}"
    "figcaption{font-size:12px;color:#555}.absent{color:#555}img{max-width:100%}"
    ".interrupted{background:#fff3d6;border:1px solid #e0b040;padding:6px 10px}";

// stats.json's "interrupted": the launcher's mark of a run stopped by Ctrl-C.
bool wasInterrupted(const fs::path& run) {
  try {
    return fs::exists(run / "stats.json") && YAML::LoadFile((run / "stats.json").string())["interrupted"].as<bool>(false);
  } catch (const YAML::Exception&) {
    return false;  // the stats section says what is wrong with the file
  }
}

// What the report looked for and did not find, after the sections: an
// explanation, not an error (a default run has every input).
void notFoundSection(std::ostringstream& html, const std::vector<std::string>& absent) {
  if (absent.empty()) return;
  html << "<h2>Not in this report</h2>\n<p>Inputs the report looked for in the run folder and did not find, and why; "
          "the sections above show everything else.</p>\n<ul class=\"absent\">\n";
  for (const auto& a : absent) html << "<li>" << escapeHtml(a) << "</li>\n";
  html << "</ul>\n";
}

std::string utcNow() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M:%S UTC", &tm);
  return buf;
}

std::string firstLine(const fs::path& file) {
  std::ifstream in(file);
  std::string line;
  std::getline(in, line);
  const size_t a = line.find_first_not_of(" \t\r");
  if (a == std::string::npos) return "";
  return line.substr(a, line.find_last_not_of(" \t\r") - a + 1);
}

// The ground truth file: the option, else <dataset>/groundtruth.txt from dataset.txt.
std::string groundTruthPath(const fs::path& run, const RunReportOptions& options, Page& page) {
  if (!options.groundtruth.empty()) return options.groundtruth;
  const fs::path pointer = run / kDatasetPathFile;
  if (!fs::exists(pointer)) {
    page.absentInput("ground truth: no --groundtruth given and no " + std::string(kDatasetPathFile) +
                     " in the run folder naming the dataset");
    return "";
  }
  const std::string dataset = firstLine(pointer);
  if (dataset.empty()) {
    page.absentInput("ground truth: " + pointer.string() + " is empty; it should hold the dataset folder");
    return "";
  }
  return (fs::path(dataset) / "groundtruth.txt").string();
}

// The dataset's ground-truth surface (synthetic scenes write mesh_gt.ply
// beside their frames), "" when the run's dataset has none: then the report
// says why it has no CORR/COMPL.
std::string groundTruthMeshPath(const fs::path& run, Page& page) {
  if (!fs::exists(run / kDatasetPathFile)) return "";
  const fs::path mesh = fs::path(firstLine(run / kDatasetPathFile)) / "mesh_gt.ply";
  if (fs::exists(mesh)) return mesh.string();
  page.absentInput("surface errors (CORR/COMPL): " + mesh.string() + " does not exist; a dataset needs a ground-truth "
                   "surface for them (synthetic scenes have one, real datasets rarely do)");
  return "";
}

std::vector<std::string> servicesOfRun(const fs::path& run) {
  std::vector<std::string> services = {"player", "tracker", "optimiser", "mapper"};
  try {
    if (fs::exists(run / "config.yaml")) {
      const YAML::Node listed = YAML::LoadFile((run / "config.yaml").string())["run"]["services"];
      if (listed && listed.IsSequence()) services = listed.as<std::vector<std::string>>();
    }
  } catch (const YAML::Exception& e) {
    spdlog::warn("report: {}/config.yaml: {}; assuming the default services", run.string(), e.what());
  }
  // Timing files of services not in the list still belong in the report.
  std::set<std::string> known(services.begin(), services.end());
  std::vector<std::string> extra;
  for (const auto& entry : fs::directory_iterator(run)) {
    const std::string name = entry.path().filename().string();
    const std::string suffix = kTimingSuffix;
    if (name.size() > suffix.size() && name.ends_with(suffix)) {
      const std::string service = name.substr(0, name.size() - suffix.size());
      if (!known.count(service)) extra.push_back(service);
    }
  }
  std::sort(extra.begin(), extra.end());
  services.insert(services.end(), extra.begin(), extra.end());
  return services;
}

}  // namespace

void Page::absentInput(const std::string& what) {
  absent.push_back(what);
  spdlog::info("report: absent: {}", what);
}

void Page::plot(const LinePlot& p, const std::string& stem) {
  p.save((fs::path(plot_dir) / (stem + ".svg")).string());
  body << "<figure>" << inlineSvgImage(p.svg(), p.options().title) << "</figure>\n";
  ++images;
}

void Page::table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  body << "<table><tr>";
  for (const auto& h : header) body << "<th>" << escapeHtml(h) << "</th>";
  body << "</tr>\n";
  for (const auto& r : rows) {
    body << "<tr>";
    for (size_t i = 0; i < r.size(); ++i) body << (i ? "<td class=\"num\">" : "<td>") << escapeHtml(r[i]) << "</td>";
    body << "</tr>\n";
  }
  body << "</table>\n";
}

std::string number(double v, int decimals) {
  if (!std::isfinite(v)) return "nan";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

RunReportResult writeRunReport(const std::string& run_dir, const RunReportOptions& options) {
  const fs::path run(run_dir);
  if (!fs::is_directory(run)) throw Error(run_dir + ": run folder not found; give the --out folder of rekon run");
  Page page;
  page.plot_dir = (run / "report").string();
  fs::create_directories(page.plot_dir);

  const std::string gt_path = groundTruthPath(run, options, page);
  const TrajectoryInputs trajectories = readTrajectories(run, gt_path, page);
  RunReportResult result;
  result.ate = trajectorySection(page, trajectories, options);
  meshSection(page, run, options, trajectories, groundTruthMeshPath(run, page));
  const std::vector<std::string> services = servicesOfRun(run);
  timingSection(page, run, services);
  reintegrationSection(page, run);
  memorySection(page, run);
  statsSection(page, run);
  setupSection(page, run, services);

  std::ostringstream html;
  html << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>rekon run report</title><style>"
       << kStyle << "</style></head><body>\n<h1>rekon run report</h1>\n<p>Run folder <code>"
       << escapeHtml(fs::absolute(run).lexically_normal().string()) << "</code>, report written " << utcNow()
       << ". Plots with their data as CSV: <code>report/</code>.</p>\n";
  if (result.ate) {
    html << "<p><b>ATE RMSE " << number(result.ate->ate_rmse_m * 100.0, 2) << " cm</b> over " << result.ate->matched
         << " poses.</p>\n";
  }
  if (wasInterrupted(run)) {
    html << "<p class=\"interrupted\">This run was <b>interrupted</b> (Ctrl-C): its outputs cover the frames up to "
            "then, without the final pass.</p>\n";
  }
  html << page.body.str();
  notFoundSection(html, page.absent);
  html << "</body></html>\n";

  result.html_path = (run / "report.html").string();
  std::ofstream out(result.html_path);
  out << html.str();
  if (!out) throw Error(result.html_path + ": cannot write the report; check that the run folder is writable");
  result.absent = page.absent;
  result.images = page.images;
  spdlog::info("report: {} ({} images, {} absent inputs)", result.html_path, result.images, result.absent.size());
  return result;
}

}  // namespace rekon::report
