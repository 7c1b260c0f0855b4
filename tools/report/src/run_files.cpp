#include "rekon/report/run_files.hpp"

#include <charconv>
#include <cmath>
#include <fstream>
#include <limits>

#include "rekon/common/error.hpp"

namespace rekon::report {
namespace {

std::string trimmed(const std::string& s) {
  const size_t a = s.find_first_not_of(" \t\r");
  if (a == std::string::npos) return "";
  return s.substr(a, s.find_last_not_of(" \t\r") - a + 1);
}

std::vector<std::string> splitFields(const std::string& line) {
  std::vector<std::string> fields;
  size_t start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    fields.push_back(trimmed(line.substr(start, comma == std::string::npos ? std::string::npos : comma - start)));
    if (comma == std::string::npos) return fields;
    start = comma + 1;
  }
}

bool parseNumber(const std::string& s, double& v) {
  if (s == "nan" || s == "NaN") {
    v = std::numeric_limits<double>::quiet_NaN();
    return true;
  }
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  return ec == std::errc() && end == s.data() + s.size() && !s.empty();
}

}  // namespace

int CsvTable::column(const std::string& name) const {
  for (size_t i = 0; i < columns.size(); ++i) {
    if (columns[i] == name) return static_cast<int>(i);
  }
  return -1;
}

std::vector<double> CsvTable::values(int column) const {
  std::vector<double> v;
  v.reserve(rows.size());
  for (const auto& r : rows) v.push_back(r.at(static_cast<size_t>(column)));
  return v;
}

CsvTable readCsvTable(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open the CSV file; check the path");
  CsvTable table;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    line = trimmed(line);
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> fields = splitFields(line);
    if (table.columns.empty()) {
      for (const auto& f : fields) {
        if (f.empty()) throw Error(path + ":" + std::to_string(number) + ": empty column name in the header");
      }
      table.columns = std::move(fields);
      continue;
    }
    if (fields.size() != table.columns.size()) {
      throw Error(path + ":" + std::to_string(number) + ": " + std::to_string(fields.size()) + " fields, the header has " +
                  std::to_string(table.columns.size()));
    }
    std::vector<double> row(fields.size());
    for (size_t i = 0; i < fields.size(); ++i) {
      if (!parseNumber(fields[i], row[i])) {
        throw Error(path + ":" + std::to_string(number) + ": '" + fields[i] + "' in column " + table.columns[i] +
                    " is not a number");
      }
    }
    table.rows.push_back(std::move(row));
  }
  if (table.columns.empty()) throw Error(path + ": no header line; the first line names the columns, e.g. frame_id,ms");
  return table;
}

std::vector<RssSample> readRssCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open the CSV file; check the path");
  std::vector<RssSample> samples;
  std::string line;
  int number = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++number;
    line = trimmed(line);
    if (line.empty() || line[0] == '#') continue;
    const std::vector<std::string> f = splitFields(line);
    if (!header) {
      if (f != std::vector<std::string>{"seconds", "service", "rss_mb"})
        throw Error(path + ":" + std::to_string(number) + ": the header must be seconds,service,rss_mb");
      header = true;
      continue;
    }
    RssSample s;
    if (f.size() != 3 || f[1].empty() || !parseNumber(f[0], s.seconds) || !parseNumber(f[2], s.rss_mb))
      throw Error(path + ":" + std::to_string(number) + ": expected seconds,service,rss_mb with two numbers, got '" + line + "'");
    s.service = f[1];
    samples.push_back(std::move(s));
  }
  if (!header) throw Error(path + ": no header line; the first line must be seconds,service,rss_mb");
  return samples;
}

CsvTable readCsvTable(const std::string& path, const std::vector<std::string>& leading_columns) {
  CsvTable table = readCsvTable(path);
  bool ok = table.columns.size() >= leading_columns.size();
  for (size_t i = 0; ok && i < leading_columns.size(); ++i) ok = table.columns[i] == leading_columns[i];
  if (!ok) {
    std::string want;
    for (const auto& c : leading_columns) want += (want.empty() ? "" : ",") + c;
    throw Error(path + ": the header must start with " + want + " (see tools/report/README.md)");
  }
  return table;
}

}  // namespace rekon::report
