#include "rekon/mapper/store/session.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/common/pose_text.hpp"
#include "rekon/common/files.hpp"
#include "spill_file.hpp"

namespace rekon::store {
namespace {

namespace fs = std::filesystem;

std::string join(const std::string& dir, const std::string& name) { return (fs::path(dir) / name).string(); }
std::string infoPath(const std::string& dir) { return join(dir, "session.yaml"); }
std::string keyframeDir(const std::string& dir) { return join(dir, "keyframes"); }
std::string imagesPath(const std::string& dir, int64_t id) {
  return join(keyframeDir(dir), fmt::format("kf_{:06d}.rks", id));
}
std::string metaPath(const std::string& dir, int64_t id) { return join(keyframeDir(dir), fmt::format("kf_{:06d}.txt", id)); }

// Seven finite numbers with a unit quaternion (within 1e-6) from `in`; nullopt otherwise.
std::optional<Pose> readPose(std::istream& in) {
  double v[7];
  for (double& x : v) {
    if (!(in >> x) || !std::isfinite(x)) return std::nullopt;
  }
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 1e-6) return std::nullopt;
  return poseFromQuatTrans(q, Eigen::Vector3d(v[0], v[1], v[2]));
}

std::string infoYaml(const SessionInfo& s) {
  const Intrinsics& k = s.camera;
  return fmt::format(
      "# A rekon session (services/mapper/src/store/SESSION.md).\n"
      "format_version: {}\n"
      "camera: {{width: {}, height: {}, fx: {:.9g}, fy: {:.9g}, cx: {:.9g}, cy: {:.9g}}}\n"
      "volume: {{voxel_size: {:.9g}, truncation: {:.9g}, max_depth: {:.9g}}}\n",
      s.format_version, k.width, k.height, k.fx, k.fy, k.cx, k.cy, s.voxel_size, s.truncation, s.max_depth);
}

SessionInfo readInfo(const std::string& dir) {
  const std::string path = infoPath(dir);
  if (!fs::exists(path)) throw Error(dir + " is not a rekon session (no session.yaml); give the folder of rekon run --session");
  SessionInfo s;
  try {
    const YAML::Node y = YAML::LoadFile(path);
    s.format_version = y["format_version"].as<int>();
    if (s.format_version > kSessionFormatVersion)
      throw Error(path + " has format version " + std::to_string(s.format_version) + ", newer than this rekon's " +
                  std::to_string(kSessionFormatVersion) + "; open it with the rekon that wrote it");
    const YAML::Node c = y["camera"], v = y["volume"];
    s.camera.width = c["width"].as<int>();
    s.camera.height = c["height"].as<int>();
    s.camera.fx = c["fx"].as<double>();
    s.camera.fy = c["fy"].as<double>();
    s.camera.cx = c["cx"].as<double>();
    s.camera.cy = c["cy"].as<double>();
    s.voxel_size = v["voxel_size"].as<double>();
    s.truncation = v["truncation"].as<double>();
    s.max_depth = v["max_depth"].as<double>();
  } catch (const YAML::Exception& e) {
    throw Error(path + " is damaged (" + e.msg + "); a session.yaml is written whole, so this file was edited or corrupted");
  }
  s.camera.validate(path);
  if (!(s.voxel_size > 0 && s.truncation > 0 && s.max_depth > 0))
    throw Error(path + ": volume voxel_size, truncation and max_depth must be > 0");
  return s;
}

// kf_<id>.txt: "id anchor first_frame last_frame frames timestamp" then the pose in the anchor.
std::string metaText(const fusion::FusedKeyframe& kf) {
  return fmt::format("{} {} {} {} {} {:.6f} {}\n", kf.id, kf.anchor_keyframe_id, kf.first_frame_id, kf.last_frame_id,
                     kf.frames, kf.timestamp, poseText(kf.pose_in_anchor));
}

fusion::FusedKeyframe readMeta(const std::string& path, int64_t id) {
  std::ifstream in(path);
  fusion::FusedKeyframe kf;
  std::optional<Pose> pose;
  if (in >> kf.id >> kf.anchor_keyframe_id >> kf.first_frame_id >> kf.last_frame_id >> kf.frames >> kf.timestamp)
    pose = readPose(in);
  if (!pose || kf.id != id || kf.frames < 1)
    throw Error(path + " is damaged (not the metadata of keyframe " + std::to_string(id) +
                "); a keyframe's files are written whole, so it was edited or corrupted: restore it or remove both of its files");
  kf.pose_in_anchor = *pose;
  return kf;
}

}  // namespace

struct SessionWriter::Impl {
  std::string dir;
  SessionInfo info;
  std::ofstream frames;
};

void requireNoSession(const std::string& dir) {
  if (fs::exists(infoPath(dir)))
    throw Error(dir + " already holds a session; give a new folder to --session (rekon remesh and rekon export read this one)");
}

SessionWriter::SessionWriter(const std::string& dir, const SessionInfo& info, bool reopen)
    : impl_(std::make_unique<Impl>()) {
  impl_->dir = dir;
  impl_->info = info;
  const bool exists = fs::exists(infoPath(dir));
  if (!reopen) requireNoSession(dir);
  if (const Intrinsics old = exists ? readInfo(dir).camera : info.camera; !sameCamera(old, info.camera))
    throw Error(dir + " holds a session of another camera (" + describeCamera(old) + ", this run's: " +
                describeCamera(info.camera) + "); continue it with the camera it was made with, or give a new folder to --session");
  std::error_code ec;
  fs::create_directories(keyframeDir(dir), ec);
  if (ec) throw Error("cannot create the session folder " + dir + " (" + ec.message() + ")");
  if (!exists) writeFileAtomically(infoPath(dir), infoYaml(info));
  // A line cut short by a killed writer is ended, so that the next one stands alone.
  const std::string frames_path = join(dir, "frames.txt");
  if (std::ifstream old(frames_path, std::ios::ate | std::ios::binary); old && old.tellg() > 0) {
    old.seekg(-1, std::ios::end);
    if (old.get() != '\n') std::ofstream(frames_path, std::ios::app) << '\n';
  }
  impl_->frames.open(frames_path, std::ios::app);
  if (!impl_->frames) throw Error("cannot write " + join(dir, "frames.txt") + "; check the folder's permissions");
}

SessionWriter::~SessionWriter() { impl_->frames.flush(); }

void SessionWriter::addKeyframe(const fusion::FusedKeyframe& kf) {
  std::vector<uint8_t> images(keyframeImageBytes(kf.depth.cols, kf.depth.rows));
  packKeyframeImages(kf, images.data());
  writeSpillFile(imagesPath(impl_->dir, kf.id), kf.id, kf.depth.cols, kf.depth.rows, images.data(), images.size());
  writeFileAtomically(metaPath(impl_->dir, kf.id), metaText(kf));
  impl_->frames.flush();
}

bool SessionWriter::has(int64_t id) const { return fs::exists(metaPath(impl_->dir, id)); }

void SessionWriter::setAnchorPoses(const std::map<int64_t, Pose>& poses) {
  std::string text = "# DVO keyframe id, its newest world pose: tx ty tz qx qy qz qw\n";
  for (const auto& [id, pose] : poses) text += fmt::format("{} {}\n", id, poseText(pose));
  writeFileAtomically(join(impl_->dir, "anchors.txt"), text);
}

void SessionWriter::addFrame(const SessionFrame& f) {
  impl_->frames << fmt::format("{} {:.6f} {} {}\n", f.frame_id, f.timestamp, f.keyframe_id, poseText(f.pose_in_keyframe));
}

Session Session::open(const std::string& dir) {
  Session s;
  s.dir_ = dir;
  s.info_ = readInfo(dir);
  // Keyframes: both files, or neither. Images without metadata were in flight
  // when a run was killed (left out); metadata without images is damage.
  const std::regex meta_name(R"(kf_([0-9]+)\.txt)");
  std::map<int64_t, std::string> metas;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(keyframeDir(dir), ec)) {
    std::smatch m;
    const std::string name = e.path().filename().string();
    if (std::regex_match(name, m, meta_name)) metas[std::stoll(m[1])] = e.path().string();
  }
  for (const auto& [id, path] : metas) {
    if (!fs::exists(imagesPath(dir, id)))
      throw Error("session keyframe " + std::to_string(id) + " has no images (" + imagesPath(dir, id) +
                  " is missing); restore it, or remove " + path + " to open the session without it");
    s.keyframes_.push_back(readMeta(path, id));
  }
  std::ifstream anchors(join(dir, "anchors.txt"));
  std::string line;
  while (std::getline(anchors, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    int64_t id = 0;
    std::optional<Pose> pose;
    if (in >> id) pose = readPose(in);
    if (!pose) throw Error(join(dir, "anchors.txt") + " is damaged (line '" + line + "'); it is written whole, so it was edited or corrupted");
    s.anchors_[id] = *pose;
  }
  return s;
}

fusion::FusedKeyframe Session::load(size_t i) const {
  fusion::FusedKeyframe kf = keyframes_.at(i);
  const int w = info_.camera.width, h = info_.camera.height;
  std::vector<uint8_t> images(keyframeImageBytes(w, h));
  readSpillFile(imagesPath(dir_, kf.id), kf.id, w, h, images.data(), images.size(),
                "restore the file, or remove it and " + metaPath(dir_, kf.id) + " to open the session without it");
  unpackKeyframeImages(images.data(), w, h, kf);
  return kf;
}

std::optional<Pose> Session::worldPose(const fusion::FusedKeyframe& kf) const {
  const auto it = anchors_.find(kf.anchor_keyframe_id);
  if (it == anchors_.end()) return std::nullopt;
  return orthonormalised(it->second * kf.pose_in_anchor);
}

std::vector<SessionFrame> Session::frames() const {
  std::vector<SessionFrame> out;
  std::ifstream in(join(dir_, "frames.txt"));
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    SessionFrame f;
    std::optional<Pose> pose;
    if (s >> f.frame_id >> f.timestamp >> f.keyframe_id) pose = readPose(s);
    if (!pose) continue;  // the last line of a killed writer
    f.pose_in_keyframe = *pose;
    out.push_back(f);
  }
  return out;
}

}  // namespace rekon::store
