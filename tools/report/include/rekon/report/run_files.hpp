#pragma once
// The per-frame and per-event CSV files that services write into the run
// folder (`--out` of `rekon run`), and reading them back for the report.
//
// <out>/<service>_timing.csv  (service = tracker, optimiser, mapper, player, ...)
//   Header `frame_id,ms` and optionally more columns, then one row per frame
//   the service handled, in the order handled:
//     frame_id  the frame's id as the player numbered it (0-based)
//     ms        wall time the service spent on that frame, in milliseconds
//     ...       any further numeric columns: a breakdown of ms (e.g.
//               `track_ms,select_ms`) or counts (e.g. `iterations`)
//   Example:
//     frame_id,ms,iterations
//     0,5.21,14
//     1,4.87,11
//
// <out>/mapper_reintegration.csv
//   One row per re-integration round (the mapper applying a new pose graph):
//     time_s                  seconds since the mapper's first frame
//     graph_version           version of the optimised pose graph applied
//     keyframes_reintegrated  KF keyframes de-integrated and re-integrated in the round
//     ms                      wall time of the round, in milliseconds
//     blocks_streamed         voxel blocks streamed in or out for the round
//   Further numeric columns are allowed and plotted too. Example:
//     time_s,graph_version,keyframes_reintegrated,ms,blocks_streamed
//     3.40,2,5,11.8,0
//
// <out>/rss.csv (written by the launcher while the services run)
//   Header `seconds,service,rss_mb`, one row per sample and service:
//     seconds  since the start of the run
//     service  the service's name (text, the only non-numeric column)
//     rss_mb   its resident set size then, in MiB
//
// Every other value is a decimal number ("nan" allowed for "not measured"). Lines
// starting with '#' and empty lines are skipped.
#include <string>
#include <vector>

namespace rekon::report {

inline constexpr const char* kTimingSuffix = "_timing.csv";
// The services that write <service>_timing.csv; the others (player, camera,
// viewer) have no per-frame work to time, so no such file is missed.
inline const std::vector<std::string> kTimedServices = {"tracker", "optimiser", "mapper"};
inline constexpr const char* kReintegrationFile = "mapper_reintegration.csv";
inline constexpr const char* kRssFile = "rss.csv";
inline const std::vector<std::string> kTimingColumns = {"frame_id", "ms"};
inline const std::vector<std::string> kReintegrationColumns = {"time_s", "graph_version", "keyframes_reintegrated", "ms",
                                                              "blocks_streamed"};

struct CsvTable {
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows;  // each as long as columns

  // Index of a column, or -1.
  int column(const std::string& name) const;
  std::vector<double> values(int column) const;
};

// Reads a numeric CSV with a header line. Throws rekon::Error naming the file
// and line for a row of the wrong length or a field that is not a number.
CsvTable readCsvTable(const std::string& path);
// The same, and requires that the header starts with `leading_columns`.
CsvTable readCsvTable(const std::string& path, const std::vector<std::string>& leading_columns);

struct RssSample {
  double seconds = 0.0;
  std::string service;
  double rss_mb = 0.0;
};
// Reads rss.csv; throws rekon::Error naming the file and line for a wrong
// header, a row of the wrong length or a value that is not a number.
std::vector<RssSample> readRssCsv(const std::string& path);

}  // namespace rekon::report
