#include "preflight.hpp"

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <cmath>
#include <filesystem>

#include "rekon/camera/source.hpp"
#include "rekon/common/bus.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon/optimiser/params.hpp"
#include "rekon/player/player.hpp"
#include "rekon/tracker/params.hpp"
#include "realsense_probe.hpp"

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
  dataset.checkImagesExist();
  return {static_cast<long long>(dataset.size()), dataset.duration()};
}

void checkCameraSpec(const std::string& spec, const std::string& playback, const Config& config) {
  // The drivers rekon-camera's openCamera knows, and realsense (rekon-realsense,
  // which finds its device through Intel's SDK).
  const size_t colon = spec.find(':');
  const std::string driver = spec.substr(0, colon), device = colon == std::string::npos ? "" : spec.substr(colon + 1);
  if (driver == "realsense") return checkRealSense(spec, playback, config);
  if (driver != "openni2" && driver != "freenect") {
    throw Error("--camera " + spec + ": unknown driver '" + driver +
                "'; use realsense[:SERIAL], openni2[:URI|FILE.oni] or freenect[:INDEX] (rekon cameras lists what is "
                "connected)");
  }
  if (driver == "openni2" && device.ends_with(".oni")) {
    if (!fs::is_regular_file(device)) throw Error("--camera " + spec + ": OpenNI2 recording not found; check the path after openni2:");
    return;
  }
  // The device itself: what the drivers see now (libfreenect's fakenect sees its recording).
  std::vector<std::string> seen;
  for (const camera::CameraInfo& c : camera::listCameras()) {
    if (c.driver == driver) seen.push_back(c.uri);
  }
  if (seen.empty()) {
    throw Error("--camera " + spec + ": no " + driver + " device is connected; check its USB cable and power (rekon "
                "cameras lists what the drivers see)");
  }
  if (!device.empty() && std::find(seen.begin(), seen.end(), device) == seen.end()) {
    std::string list;
    for (const std::string& uri : seen) list += (list.empty() ? "" : ", ") + driver + ":" + uri;
    throw Error("--camera " + spec + ": no such " + driver + " device; connected: " + list + " (rekon cameras)");
  }
}

void checkRealSense(const std::string& spec, const std::string& playback, const Config& config) {
  if (!playback.empty() && !fs::is_regular_file(playback))
    throw Error("--playback " + playback + ": no such RealSense recording; give the path of a .bag file "
                "(rekon-realsense-write makes one from a dataset)");
  // The service's own check, through the SDK, with the mode and device the run gives it.
  const size_t colon = spec.find(':');
  std::vector<std::string> args;
  for (const char* key : {"realsense.width", "realsense.height", "realsense.fps"})
    args.insert(args.end(), {"--set", std::string(key) + "=" + std::to_string(config.getInt(key))});
  for (const char* key : {"realsense.device", "realsense.playback"})
    if (!config.getString(key).empty()) args.insert(args.end(), {"--set", std::string(key) + "=" + config.getString(key)});
  if (colon != std::string::npos) args.insert(args.end(), {"--device", spec.substr(colon + 1)});
  if (!playback.empty()) args.insert(args.end(), {"--playback", fs::absolute(playback).string()});
  const std::string why = whyRealSenseCannotOpen(args);
  if (!why.empty()) throw Error("--camera " + spec + ": " + why);
}

void checkViewerPort(const Config& config) {
  const int port = config.getInt("viewer.port");
  if (port == 0) return;  // any free port
  const std::string address = config.getString("viewer.bind");
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(port));
  if (port < 0 || port > 65535 || inet_pton(AF_INET, address.c_str(), &a.sin_addr) != 1)
    throw Error("viewer.bind " + address + " / viewer.port " + std::to_string(port) + ": not an IPv4 address and port");
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return;  // the viewer will say why
  const int one = 1;
  setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);  // as the viewer does: a closed run's port is free
  const int rc = bind(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a), err = errno;
  close(fd);
  if (rc == 0) return;
  if (err == EADDRINUSE)
    throw Error("viewer.port " + std::to_string(port) + " on " + address + " is in use (another rekon view or program); "
                "stop it, or --set viewer.port=0 for any free port");
  throw Error("viewer.bind " + address + ":" + std::to_string(port) + ": cannot listen (" + std::strerror(err) + ")");
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
  // Everything a run writes: its files and the report's folder (left behind before).
  long long removed = 0;
  for (const auto& entry : fs::directory_iterator(out)) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && isRunOutput(name)) removed += fs::remove(entry.path());
    if (entry.is_directory() && name == "report") removed += static_cast<long long>(fs::remove_all(entry.path()));
  }
  spdlog::info("--force: removed the {} files of the earlier run in {}", removed, out);
}

}  // namespace rekon
