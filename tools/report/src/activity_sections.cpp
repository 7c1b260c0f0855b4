// Per-frame timing, re-integration activity and the stats table.
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <optional>
#include <numeric>

#include "rekon/common/error.hpp"
#include "rekon/report/html.hpp"
#include "rekon/report/run_files.hpp"
#include "report_sections.hpp"

namespace rekon::report {
namespace fs = std::filesystem;
namespace {

// More columns than this in mapper_reintegration.csv are listed but not plotted.
constexpr size_t kMaxActivityPlots = 8;
constexpr size_t kMaxConfigBytes = 64 * 1024;
constexpr size_t kMaxNotableLogLines = 40;
// Plots of one quantity, several to a row.
constexpr int kSmallPlotWidth = PlotOptions::kDefaultWidth / 2 + 60;
constexpr int kSmallPlotHeight = PlotOptions::kDefaultHeight * 3 / 4;

std::optional<CsvTable> readOptionalCsv(const fs::path& path, const std::vector<std::string>& leading,
                                        const std::string& why_absent, Page& page) {
  const std::string name = path.filename().string();
  if (!fs::exists(path)) {
    page.absentInput(name + ": " + why_absent);
    return std::nullopt;
  }
  try {
    CsvTable t = readCsvTable(path.string(), leading);
    if (t.rows.empty()) {
      page.absentInput(name + ": has a header but no rows");
      return std::nullopt;
    }
    return t;
  } catch (const Error& e) {
    page.absentInput(name + ": unreadable (" + std::string(e.what()) + ")");
    return std::nullopt;
  }
}

struct Summary {
  size_t count = 0;
  double mean = NAN, p50 = NAN, p95 = NAN, max = NAN, total = 0;
};

// Nearest-rank percentiles over the finite values.
Summary summarise(const std::vector<double>& values) {
  std::vector<double> v;
  for (double x : values) {
    if (std::isfinite(x)) v.push_back(x);
  }
  Summary s;
  s.count = v.size();
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  const auto rank = [&](double q) {
    const auto r = static_cast<size_t>(std::ceil(q * static_cast<double>(v.size())));
    return v[std::clamp<size_t>(r, 1, v.size()) - 1];
  };
  s.total = std::accumulate(v.begin(), v.end(), 0.0);
  s.mean = s.total / static_cast<double>(v.size());
  s.p50 = rank(0.5);
  s.p95 = rank(0.95);
  s.max = v.back();
  return s;
}

void flatten(const YAML::Node& node, const std::string& prefix, std::vector<std::vector<std::string>>& rows) {
  if (node.IsMap()) {
    for (const auto& kv : node) flatten(kv.second, prefix + (prefix.empty() ? "" : ".") + kv.first.as<std::string>(), rows);
  } else if (node.IsSequence()) {
    std::string joined;
    for (const auto& item : node) joined += (joined.empty() ? "" : ", ") + (item.IsScalar() ? item.Scalar() : std::string("..."));
    rows.push_back({prefix, "[" + joined + "]"});
  } else if (node.IsScalar()) {
    rows.push_back({prefix, node.Scalar()});
  } else {
    rows.push_back({prefix, "null"});
  }
}

std::string readText(const fs::path& path, size_t max_bytes) {
  std::ifstream in(path);
  std::string text(max_bytes, '\0');
  in.read(text.data(), static_cast<std::streamsize>(max_bytes));
  text.resize(static_cast<size_t>(in.gcount()));
  if (text.size() == max_bytes) text += "\n... (cut)";
  return text;
}

// The sensor's frame period from the player's stats (sequence duration / frames).
std::optional<double> framePeriodMs(const fs::path& run) {
  try {
    if (!fs::exists(run / "stats.json")) return std::nullopt;
    const YAML::Node player = YAML::LoadFile((run / "stats.json").string())["player"];
    if (!player || !player.IsMap()) return std::nullopt;
    const double frames = player["frames"].as<double>(0.0), seconds = player["sequence_seconds"].as<double>(0.0);
    if (frames < 2 || seconds <= 0) return std::nullopt;
    return 1000.0 * seconds / frames;  // the player counts one period per frame (span + one period)
  } catch (const YAML::Exception&) {
    return std::nullopt;  // the stats section reports an unreadable stats.json
  }
}

}  // namespace

void timingSection(Page& page, const fs::path& run, const std::vector<std::string>& services) {
  page.body << "<h2>Per-frame timing</h2>\n";
  PlotOptions po;
  po.title = "time per frame";
  po.x_label = "frame id";
  po.y_label = "ms";
  po.y_includes_zero = true;
  LinePlot combined(po);
  std::vector<std::vector<std::string>> rows;
  std::vector<std::pair<std::string, CsvTable>> detailed;
  for (const auto& service : services) {
    const bool timed = std::find(kTimedServices.begin(), kTimedServices.end(), service) != kTimedServices.end();
    if (!timed && !fs::exists(run / (service + kTimingSuffix))) continue;
    auto table = readOptionalCsv(run / (service + kTimingSuffix), kTimingColumns,
                                 "not in the run folder (rekon-" + service + " did not write per-frame timing)", page);
    if (!table) continue;
    Series s;
    s.name = service;
    s.x = table->values(0);
    s.y = table->values(1);
    const Summary sum = summarise(s.y);
    rows.push_back({service, std::to_string(sum.count), number(sum.mean, 2), number(sum.p50, 2), number(sum.p95, 2),
                    number(sum.max, 2), number(sum.total / 1000.0, 2)});
    combined.add(std::move(s));
    if (table->columns.size() > kTimingColumns.size()) detailed.emplace_back(service, std::move(*table));
  }
  if (rows.empty()) {
    page.body << "<p>No service wrote <code>&lt;service&gt;_timing.csv</code>.</p>\n";
    return;
  }
  page.table({"service", "frames", "mean [ms]", "median [ms]", "p95 [ms]", "max [ms]", "total [s]"}, rows);
  if (const auto period = framePeriodMs(run)) {
    // A service above this line falls behind a live camera.
    double first = std::numeric_limits<double>::infinity(), last = -first;
    for (const auto& s : combined.series()) {
      for (double x : s.x) {
        if (std::isfinite(x)) first = std::min(first, x), last = std::max(last, x);
      }
    }
    Series line("frame period " + number(*period, 1) + " ms", {first, last}, {*period, *period});
    line.dashed = true;
    line.color = "#888888";
    combined.add(std::move(line));
  }
  page.plot(combined, "timing");
  // Times (ms, *_ms) share one plot per service; every other column gets its own.
  for (const auto& [service, table] : detailed) {
    const auto is_time = [](const std::string& c) { return c == "ms" || c.ends_with("_ms"); };
    PlotOptions o = po;
    o.title = service + ": time per frame by part";
    LinePlot times(o);
    for (size_t c = 1; c < table.columns.size(); ++c) {
      if (is_time(table.columns[c])) times.add({table.columns[c], table.values(0), table.values(static_cast<int>(c))});
    }
    if (times.series().size() > 1) page.plot(times, "timing_" + service + "_parts");
    for (size_t c = 2; c < table.columns.size(); ++c) {
      if (is_time(table.columns[c])) continue;
      PlotOptions oc = po;
      oc.title = service + ": " + table.columns[c] + " per frame";
      oc.y_label = table.columns[c];
      oc.width = kSmallPlotWidth;
      oc.height = kSmallPlotHeight;
      LinePlot plot(oc);
      Series s("", table.values(0), table.values(static_cast<int>(c)));
      s.color = paletteColor(c - 1);
      plot.add(std::move(s));
      page.plot(plot, "timing_" + service + "_" + table.columns[c]);
    }
  }
}

// Columns of mapper_reintegration.csv that count on over the run (the row's
// state then) rather than what one round did.
namespace {
bool isRunningCount(const std::string& column) { return column == "graph_version" || column == "frames_fused"; }
}  // namespace

void reintegrationSection(Page& page, const fs::path& run) {
  page.body << "<h2>Re-integration activity</h2>\n";
  const auto table = readOptionalCsv(run / kReintegrationFile, {kReintegrationColumns.front()},
                                     "not in the run folder (the mapper recorded no re-integration rounds)", page);
  if (!table) {
    page.body << "<p>No re-integration record.</p>\n";
    return;
  }
  const std::vector<double> time = table->values(0);
  std::vector<std::vector<std::string>> rows;
  for (size_t c = 1; c < table->columns.size(); ++c) {
    const std::vector<double> v = table->values(static_cast<int>(c));
    const Summary s = summarise(v);
    // A running count (graph_version, frames_fused) says its last value; a
    // sum of it is no quantity (27 077 "graph versions" on a 1 000-frame run).
    if (isRunningCount(table->columns[c]))
      rows.push_back({table->columns[c], "at the end: " + number(v.back(), 0), "-", number(s.max, 0)});
    else
      rows.push_back({table->columns[c], number(s.total, 1), number(s.mean, 2), number(s.max, 1)});
  }
  page.body << "<p>" << table->rows.size() << " rounds over " << number(time.back() - time.front(), 1) << " s.</p>\n";
  page.table({"column", "total", "mean per round", "max"}, rows);
  for (size_t c = 1; c < table->columns.size() && c <= kMaxActivityPlots; ++c) {
    PlotOptions o;
    o.title = table->columns[c] + " per round";
    o.x_label = "time [s]";
    o.y_label = table->columns[c];
    o.width = kSmallPlotWidth;
    o.height = kSmallPlotHeight;
    o.y_includes_zero = true;
    LinePlot plot(o);
    Series s("", time, table->values(static_cast<int>(c)));
    s.markers = true;
    s.color = paletteColor(c - 1);
    plot.add(std::move(s));
    page.plot(plot, "reintegration_" + table->columns[c]);
  }
}

void statsSection(Page& page, const fs::path& run) {
  page.body << "<h2>Stats</h2>\n";
  const fs::path path = run / "stats.json";
  if (!fs::exists(path)) {
    page.absentInput("stats.json: not written (rekon run writes it when the services stop)");
    page.body << "<p>No stats.json.</p>\n";
    return;
  }
  YAML::Node stats;
  try {
    stats = YAML::LoadFile(path.string());  // JSON is YAML
  } catch (const YAML::Exception& e) {
    page.absentInput("stats.json: unreadable (" + std::string(e.what()) + ")");
    return;
  }
  if (!stats.IsMap()) {
    page.absentInput("stats.json: not a JSON object");
    return;
  }
  std::vector<std::vector<std::string>> run_rows;
  std::vector<std::pair<std::string, YAML::Node>> services;
  for (const auto& kv : stats) {
    if (kv.second.IsMap()) services.emplace_back(kv.first.as<std::string>(), kv.second);
    else flatten(kv.second, kv.first.as<std::string>(), run_rows);
  }
  page.body << "<h3>run</h3>\n";
  page.table({"key", "value"}, run_rows);
  for (const auto& [name, node] : services) {
    std::vector<std::vector<std::string>> rows;
    flatten(node, "", rows);
    page.body << "<h3>" << escapeHtml(name) << "</h3>\n";
    page.table({"key", "value"}, rows);
  }
}

void setupSection(Page& page, const fs::path& run, const std::vector<std::string>& services) {
  page.body << "<h2>Set-up and logs</h2>\n";
  const fs::path config = run / "config.yaml";
  if (fs::exists(config)) {
    page.body << "<details><summary>config.yaml (the whole configuration of the run)</summary><pre>"
              << escapeHtml(readText(config, kMaxConfigBytes)) << "</pre></details>\n";
  } else {
    page.absentInput("config.yaml: not in the run folder");
  }
  std::vector<std::vector<std::string>> rows;
  for (const auto& service : services) {
    const fs::path log = run / (service + ".log");
    if (!fs::exists(log)) continue;  // services that did not run: their timing line already says so
    std::ifstream in(log);
    size_t lines = 0, warnings = 0, errors = 0;
    std::vector<std::string> notable;
    for (std::string line; std::getline(in, line);) {
      ++lines;
      const bool warning = line.find("[warning]") != std::string::npos, error = line.find("[error]") != std::string::npos ||
                                                                             line.find("[critical]") != std::string::npos;
      warnings += warning;
      errors += error;
      if ((warning || error) && notable.size() < kMaxNotableLogLines) notable.push_back(line);
    }
    rows.push_back({service, std::to_string(lines), std::to_string(warnings), std::to_string(errors)});
    if (!notable.empty()) {
      page.body << "<details><summary>" << escapeHtml(service) << ".log: first warnings and errors</summary><pre>";
      for (const auto& l : notable) page.body << escapeHtml(l) << "\n";
      page.body << "</pre></details>\n";
    }
  }
  if (!rows.empty()) page.table({"log", "lines", "warnings", "errors"}, rows);
}

}  // namespace rekon::report
