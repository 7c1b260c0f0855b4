#include "preflight.hpp"

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "rekon/common/bus.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/player/player.hpp"
#include "rekon/tracker/params.hpp"

namespace rekon {
namespace fs = std::filesystem;
namespace {

enum class Kind { kNumber, kBool, kOther };

bool isNumber(const std::string& s) {
  try {
    size_t used = 0;
    const double d = std::stod(s, &used);
    return used == s.size() && std::isfinite(d);
  } catch (const std::exception&) {
    return false;
  }
}

Kind kindOf(const YAML::Node& n) {
  if (!n.IsScalar()) return Kind::kOther;
  if (n.Tag() == "!") return Kind::kOther;  // a quoted string
  const std::string& s = n.Scalar();
  if (s == "true" || s == "false") return Kind::kBool;
  return isNumber(s) ? Kind::kNumber : Kind::kOther;
}

// The effective value of every scalar key against its default's kind.
void checkKinds(const YAML::Node& defaults, const YAML::Node& effective, const std::string& prefix) {
  for (const auto& kv : defaults) {
    const std::string name = kv.first.as<std::string>();
    const std::string key = prefix.empty() ? name : prefix + "." + name;
    const YAML::Node value = effective[name];
    if (kv.second.IsMap()) {
      checkKinds(kv.second, value, key);
      continue;
    }
    const Kind want = kindOf(kv.second);
    if (want == Kind::kOther || kindOf(value) == want) continue;
    const std::string text = value.IsScalar() ? value.Scalar() : "a list or mapping";
    throw Error("config key " + key + " = '" + text + "' is not " + (want == Kind::kBool ? "true or false" : "a number") +
                " (its default is " + kv.second.Scalar() + "); fix the --set or the --config file");
  }
}

}  // namespace

void checkConfigValues(const Config& config, const std::string& dataset) {
  checkKinds(YAML::Load(defaultConfigYaml()), YAML::Load(config.dump()), "");
  // The services' own parsers: what they would refuse at start-up is refused now.
  mapper::MapperParams::fromConfig(config).fusion.validate();
  tracker::trackerParamsFromConfig(config);
  optimiser::optimiserParamsFromConfig(config);
  BusOptions::fromConfig(config);
  LifecycleTimes::fromConfig(config);
  if (!dataset.empty()) PlayerParams::fromConfig(config, dataset);
  if (config.getDouble("viewer.serve_after_run_s") < -1)
    throw Error("config key viewer.serve_after_run_s must be -1 (until Ctrl-C), 0 (stop with the run) or seconds");
}

DatasetSpan checkDataset(const std::string& dir) {
  if (!fs::is_directory(dir)) throw Error(dir + ": dataset folder not found; give a TUM RGB-D folder (rgb.txt, depth.txt, camera.yaml)");
  const TumDataset dataset(dir);  // throws naming the missing or empty file
  return {static_cast<long long>(dataset.size()), dataset.duration()};
}

void checkCameraSpec(const std::string& spec) {
  // The drivers rekon-camera's openCamera knows, and realsense (rekon-realsense,
  // which finds its device through Intel's SDK and says in one line when it cannot).
  const std::string driver = spec.substr(0, spec.find(':'));
  if (driver == "realsense") return;
  if (driver != "openni2" && driver != "freenect") {
    throw Error("--camera " + spec + ": unknown driver '" + driver +
                "'; use realsense[:SERIAL], openni2[:URI|FILE.oni] or freenect[:INDEX] (rekon cameras lists what is "
                "connected)");
  }
}

void checkRealSensePlayback(const std::string& path) {
  if (!fs::is_regular_file(path))
    throw Error("--playback " + path + ": no such RealSense recording; give the path of a .bag file (rekon-realsense-write "
                "makes one from a dataset)");
}

bool isRunOutput(const std::string& f) {
  static const std::vector<std::string> files = {"trajectory.txt", "mesh.ply", "mesh_uncorrected.ply", "stats.json",
                                                 "config.yaml",    "report.html", "dataset.txt", "odometry.txt"};
  if (std::find(files.begin(), files.end(), f) != files.end()) return true;
  return f.ends_with(".log") || f.ends_with("_stats.json") || f.ends_with(".csv");
}

void claimRunFolder(const std::string& out, bool force) {
  if (!fs::exists(fs::path(out) / "config.yaml") && !fs::exists(fs::path(out) / "stats.json")) return;
  if (!force) {
    throw Error(out + " holds an earlier run (its config.yaml, stats.json, mesh.ply...); give a fresh --out folder, "
                "or --force to replace that run");
  }
  int removed = 0;
  for (const auto& entry : fs::directory_iterator(out)) {
    if (entry.is_regular_file() && isRunOutput(entry.path().filename().string())) removed += fs::remove(entry.path());
  }
  spdlog::info("--force: removed the {} files of the earlier run in {}", removed, out);
}

}  // namespace rekon
