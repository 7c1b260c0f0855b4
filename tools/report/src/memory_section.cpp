// Memory: what keyframe fusion saves against keeping every input frame, the
// voxels, and each service's resident set (peak, and over time when the
// launcher sampled it).
#include <yaml-cpp/yaml.h>

#include <map>

#include "rekon/common/error.hpp"
#include "rekon/report/html.hpp"
#include "rekon/report/run_files.hpp"
#include "report_sections.hpp"

namespace rekon::report {
namespace fs = std::filesystem;
namespace {

constexpr double kMiB = 1024.0 * 1024.0;

std::optional<double> numberAt(const YAML::Node& node, const char* key) {
  if (!node[key] || !node[key].IsScalar()) return std::nullopt;
  try {
    return node[key].as<double>();
  } catch (const YAML::Exception&) {
    return std::nullopt;
  }
}

void statsTables(Page& page, const fs::path& run) {
  YAML::Node stats;
  try {
    if (!fs::exists(run / "stats.json")) return;  // the stats section names it as absent
    stats = YAML::LoadFile((run / "stats.json").string());
  } catch (const YAML::Exception&) {
    return;  // the stats section names it as unreadable
  }
  if (!stats.IsMap()) return;
  std::vector<std::vector<std::string>> rss_rows;
  for (const auto& kv : stats) {
    if (!kv.second.IsMap()) continue;
    if (const auto rss = numberAt(kv.second, "peak_rss_mb")) rss_rows.push_back({kv.first.as<std::string>(), number(*rss, 1)});
  }
  if (!rss_rows.empty()) page.table({"service", "peak RSS [MiB]"}, rss_rows);
  const YAML::Node mapper = stats["mapper"];
  if (!mapper || !mapper.IsMap()) return;
  const auto input = numberAt(mapper, "input_frame_bytes"), keyframes = numberAt(mapper, "keyframe_bytes");
  if (!input || !keyframes) {
    page.absentInput("stats.json: the mapper wrote no input_frame_bytes / keyframe_bytes (an older mapper)");
    return;
  }
  std::vector<std::vector<std::string>> rows;
  const auto ratio = [&](double v) { return *input > 0 ? number(100.0 * v / *input, 1) : std::string("nan"); };
  rows.push_back({"input frames (16-bit depth + BGR, as received)", number(*input / kMiB, 1), "100.0"});
  rows.push_back({"KF keyframes in memory (float depth + float weight + BGR)", number(*keyframes / kMiB, 1), ratio(*keyframes)});
  if (const auto store = numberAt(mapper, "keyframe_store_bytes"))
    rows.push_back({"keyframe store, used (shared memory)", number(*store / kMiB, 1), ratio(*store)});
  if (const auto voxels = numberAt(mapper, "voxel_bytes")) rows.push_back({"voxels, all blocks (active + host)", number(*voxels / kMiB, 1), ratio(*voxels)});
  if (const auto active = numberAt(mapper, "active_voxel_bytes_peak"))
    rows.push_back({"voxels, active blocks at peak", number(*active / kMiB, 1), ratio(*active)});
  page.table({"mapper holds", "MiB", "% of input"}, rows);
}

void rssPlot(Page& page, const fs::path& run) {
  const fs::path path = run / kRssFile;
  if (!fs::exists(path)) {
    page.absentInput(std::string(kRssFile) + ": not in the run folder (the launcher did not sample RSS)");
    return;
  }
  std::vector<RssSample> samples;
  try {
    samples = readRssCsv(path.string());
  } catch (const Error& e) {
    page.absentInput(std::string(kRssFile) + ": unreadable (" + e.what() + ")");
    return;
  }
  if (samples.empty()) {
    page.absentInput(std::string(kRssFile) + ": has a header but no rows");
    return;
  }
  std::map<std::string, Series> by_service;
  for (const RssSample& s : samples) {
    Series& series = by_service[s.service];
    series.name = s.service;
    series.x.push_back(s.seconds);
    series.y.push_back(s.rss_mb);
  }
  PlotOptions o;
  o.title = "resident set size over time";
  o.x_label = "time since the start of the run [s]";
  o.y_label = "RSS [MiB]";
  o.y_includes_zero = true;
  LinePlot plot(o);
  for (auto& [name, series] : by_service) plot.add(std::move(series));
  page.plot(plot, "rss");
}

}  // namespace

void memorySection(Page& page, const fs::path& run) {
  page.body << "<h2>Memory</h2>\n";
  statsTables(page, run);
  rssPlot(page, run);
}

}  // namespace rekon::report
