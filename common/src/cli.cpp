#include "rekon/common/cli.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "rekon/common/error.hpp"

namespace rekon {

ArgParser::ArgParser(std::string program, std::string summary) : program_(std::move(program)), summary_(std::move(summary)) {}

ArgParser& ArgParser::examples(std::string lines) {
  examples_ = std::move(lines);
  return *this;
}

ArgParser& ArgParser::option(const std::string& name, const std::string& help, const std::string& fallback) {
  specs_[name] = {help, fallback, true, false};
  option_order_.push_back(name);
  return *this;
}
ArgParser& ArgParser::repeated(const std::string& name, const std::string& help) {
  specs_[name] = {help, "", true, true};
  option_order_.push_back(name);
  return *this;
}
ArgParser& ArgParser::flag(const std::string& name, const std::string& help) {
  specs_[name] = {help, "", false, false};
  option_order_.push_back(name);
  return *this;
}
ArgParser& ArgParser::positional(const std::string& name, const std::string& help) {
  positionals_.emplace_back(name, help);
  return *this;
}

bool ArgParser::parse(int argc, char** argv) {
  size_t next_positional = 0;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      std::cout << usage();
      return false;
    }
    if (arg.rfind("--", 0) == 0) {
      std::string name = arg.substr(2), value;
      const auto eq = name.find('=');
      const bool inline_value = eq != std::string::npos;
      if (inline_value) {
        value = name.substr(eq + 1);
        name = name.substr(0, eq);
      }
      const auto it = specs_.find(name);
      if (it == specs_.end()) {
        std::vector<std::string> known;
        for (const auto& [option, spec] : specs_) known.push_back(option);
        const auto near = nearestName(name, known);
        throw Error(program_ + ": unknown option --" + name + (near ? "; did you mean --" + *near + "?" : "") + "; see " +
                    program_ + " --help");
      }
      if (!it->second.takes_value) {
        values_[name].push_back("1");
        continue;
      }
      if (!inline_value) {
        if (i + 1 >= argc) throw Error(program_ + ": option --" + name + " needs a value; see " + program_ + " --help");
        value = argv[++i];
      }
      if (it->second.repeated) values_[name].push_back(value);
      else values_[name] = {value};
      continue;
    }
    if (next_positional >= positionals_.size()) throw Error(program_ + ": unexpected argument '" + arg + "'; see " + program_ + " --help");
    values_[positionals_[next_positional++].first] = {arg};
  }
  if (next_positional < positionals_.size()) {
    throw Error(program_ + ": missing " + positionals_[next_positional].first + "; see " + program_ + " --help");
  }
  return true;
}

bool ArgParser::has(const std::string& name) const { return values_.count(name) > 0; }
bool ArgParser::flagSet(const std::string& name) const { return has(name); }

std::string ArgParser::get(const std::string& name) const {
  const auto it = values_.find(name);
  if (it != values_.end() && !it->second.empty()) return it->second.back();
  const auto spec = specs_.find(name);
  return spec != specs_.end() ? spec->second.fallback : "";
}

double ArgParser::getDouble(const std::string& name) const {
  const std::string v = get(name);
  try {
    size_t used = 0;
    const double d = std::stod(v, &used);
    if (used != v.size() || !std::isfinite(d)) throw std::invalid_argument(v);
    return d;
  } catch (const std::exception&) {
    throw Error(program_ + ": --" + name + " '" + v + "' is not a finite number");
  }
}

int ArgParser::getInt(const std::string& name) const {
  const std::string v = get(name);
  try {
    size_t used = 0;
    const int n = std::stoi(v, &used);
    if (used != v.size()) throw std::invalid_argument(v);
    return n;
  } catch (const std::exception&) {
    throw Error(program_ + ": --" + name + " '" + v + "' is not an integer");
  }
}

const std::vector<std::string>& ArgParser::all(const std::string& name) const {
  static const std::vector<std::string> kNone;
  const auto it = values_.find(name);
  return it == values_.end() ? kNone : it->second;
}

std::string ArgParser::usage() const {
  std::ostringstream out;
  out << "usage: " << program_;
  for (const auto& p : positionals_) out << " " << p.first;
  out << " [options]\n\n" << summary_ << "\n";
  if (!positionals_.empty()) {
    out << "\narguments:\n";
    for (const auto& p : positionals_) out << "  " << p.first << "\n      " << p.second << "\n";
  }
  out << "\noptions:\n";
  for (const auto& name : option_order_) {
    const Spec& s = specs_.at(name);
    out << "  --" << name << (s.takes_value ? " VALUE" : "") << "\n      " << s.help;
    if (!s.fallback.empty()) out << " (default: " << s.fallback << ")";
    if (s.repeated) out << " (repeatable)";
    out << "\n";
  }
  out << "  --help\n      show this help\n";
  if (!examples_.empty()) {
    out << "\nexamples:\n";
    std::istringstream lines(examples_);
    for (std::string line; std::getline(lines, line);) out << "  " << line << "\n";
  }
  return out.str();
}

void createOutputFolder(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw Error("cannot create output folder '" + dir + "' (" + ec.message() + "); choose a writable --out");
  if (!std::filesystem::is_directory(dir)) throw Error("output '" + dir + "' is not a folder; choose another --out");
}

namespace {

// Optimal string alignment distance: insertions, deletions, substitutions and
// swaps of two neighbouring characters each cost one.
size_t editDistance(const std::string& a, const std::string& b) {
  std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
  for (size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    for (size_t j = 1; j <= b.size(); ++j) {
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  }
  return d[a.size()][b.size()];
}

}  // namespace

std::optional<std::string> nearestName(const std::string& word, const std::vector<std::string>& candidates) {
  std::optional<std::string> best;
  size_t best_distance = std::max<size_t>(2, word.size() / 3) + 1;
  for (const std::string& c : candidates) {
    const size_t d = editDistance(word, c);
    if (d < best_distance) best = c, best_distance = d;
  }
  return best;
}

std::string didYouMean(const std::string& word, const std::vector<std::string>& candidates) {
  const auto near = nearestName(word, candidates);
  return near ? "; did you mean '" + *near + "'?" : "";
}

}  // namespace rekon
