#include "rekon/tracker/keyframe_archive.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <type_traits>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/common/pose.hpp"

namespace rekon::tracker {
namespace {

namespace fs = std::filesystem;

constexpr char kMagic[8] = {'R', 'K', 'D', 'V', 'O', 'K', 'F', '1'};
constexpr int32_t kVersion = 1;

fs::path archiveDir(const std::string& session_dir) { return fs::path(session_dir) / "tracker"; }

// Appends plain values to a byte string in the host's layout (a session is
// read on the machine kind that wrote it, as the mapper's keyframe files).
class Writer {
 public:
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    bytes_.append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void putPose(const Pose& p) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) put(p.matrix()(r, c));
  }
  void putFloats(const std::vector<float>& v) {
    bytes_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(float));
  }
  std::string& bytes() { return bytes_; }

 private:
  std::string bytes_;
};

// Reads them back; every read past the end is a damaged file.
class Reader {
 public:
  Reader(const std::string& bytes, const std::string& path) : bytes_(bytes), path_(path) {}
  template <class T>
  T get() {
    T v;
    std::memcpy(&v, take(sizeof(T)), sizeof(T));
    return v;
  }
  Pose getPose() {
    Pose p = Pose::Identity();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) p.matrix()(r, c) = get<double>();
    if (!p.matrix().allFinite()) damaged("a pose that is not finite");
    return orthonormalised(p);
  }
  std::vector<float> getFloats(size_t n) {
    std::vector<float> v(n);
    std::memcpy(v.data(), take(n * sizeof(float)), n * sizeof(float));
    return v;
  }
  size_t offset() const { return offset_; }
  [[noreturn]] void damaged(const std::string& what) const {
    throw Error(path_ + ": " + what + "; the session's tracker keyframe is damaged (remove this file to continue without it)");
  }

 private:
  const char* take(size_t n) {
    if (bytes_.size() - offset_ < n) damaged("cut short");
    const char* p = bytes_.data() + offset_;
    offset_ += n;
    return p;
  }
  const std::string& bytes_;
  const std::string& path_;
  size_t offset_ = 0;
};

void putCamera(Writer& w, const Intrinsics& k) {
  w.put<int32_t>(k.width);
  w.put<int32_t>(k.height);
  for (double v : {k.fx, k.fy, k.cx, k.cy, k.depth_scale}) w.put(v);
}

Intrinsics getCamera(Reader& r) {
  Intrinsics k;
  k.width = r.get<int32_t>();
  k.height = r.get<int32_t>();
  for (double* v : {&k.fx, &k.fy, &k.cx, &k.cy, &k.depth_scale}) *v = r.get<double>();
  try {
    k.validate("camera");
  } catch (const Error& e) {
    r.damaged(e.what());
  }
  return k;
}

void putIncoming(Writer& w, const std::optional<OdometryConstraint>& c) {
  w.put<uint8_t>(c.has_value());
  if (!c) return;
  w.put(c->from_id);
  w.put(c->to_id);
  w.putPose(c->relative);
  for (int i = 0; i < 36; ++i) w.put(c->information(i / 6, i % 6));
  w.put(c->entropy);
  w.put<int32_t>(c->valid_pixels);
}

std::optional<OdometryConstraint> getIncoming(Reader& r) {
  if (r.get<uint8_t>() == 0) return std::nullopt;
  OdometryConstraint c;
  c.from_id = r.get<int64_t>();
  c.to_id = r.get<int64_t>();
  c.relative = r.getPose();
  for (int i = 0; i < 36; ++i) c.information(i / 6, i % 6) = r.get<double>();
  c.entropy = r.get<double>();
  c.valid_pixels = r.get<int32_t>();
  if (!c.information.allFinite()) r.damaged("an information matrix that is not finite");
  return c;
}

std::string fileName(int64_t id) { return fmt::format("dvo_{:06d}.rkd", id); }

std::string readWhole(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (!in.eof() && in.fail()) throw Error("cannot read " + path.string() + "; check its permissions");
  return bytes;
}

StoredKeyframe readKeyframe(const fs::path& path, const AlignerParams& params) {
  const std::string bytes = readWhole(path);
  const std::string name = path.string();
  Reader r(bytes, name);
  char magic[8];
  for (char& c : magic) c = r.get<char>();
  if (std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) r.damaged("not a rekon tracker keyframe (wrong magic)");
  if (const int32_t version = r.get<int32_t>(); version != kVersion)
    throw Error(name + ": tracker keyframe format " + std::to_string(version) + ", this build reads " +
                std::to_string(kVersion) + "; continue the session with the rekon that made it");
  const Intrinsics k = getCamera(r);
  const int32_t level = r.get<int32_t>();
  if (level < 0 || level > params.finest_level)
    throw Error(name + ": stored at pyramid level " + std::to_string(level) + ", coarser than tracker.finest_level " +
                std::to_string(params.finest_level) + "; continue with tracker.finest_level >= " + std::to_string(level));
  auto kf = std::make_shared<Keyframe>();
  kf->id = r.get<int64_t>();
  kf->frame_id = r.get<int64_t>();
  kf->timestamp = r.get<double>();
  kf->pose_world = r.getPose();
  StoredKeyframe out;
  out.camera = k;
  out.incoming = getIncoming(r);
  const Intrinsics kl = k.atLevel(level);
  const size_t n = static_cast<size_t>(kl.width) * static_cast<size_t>(kl.height);
  std::vector<float> intensity = r.getFloats(n), depth = r.getFloats(n);
  const size_t checked = r.offset();
  if (r.get<uint64_t>() != fnv1a64(bytes.data(), checked)) r.damaged("checksum mismatch");
  if (r.offset() != bytes.size()) r.damaged("trailing bytes");
  kf->pyramid.restore(k, level, params.builtCoarsestLevel(k.width, k.height), std::move(intensity), std::move(depth));
  kf->reference = KeyframeReference(kf->pyramid, params);
  out.keyframe = std::move(kf);
  return out;
}

}  // namespace

void saveKeyframe(const std::string& session_dir, const Keyframe& kf, const std::optional<OdometryConstraint>& incoming,
                  const Intrinsics& camera) {
  const int level = kf.pyramid.finestLevel();
  const PyramidLevel& finest = kf.pyramid.level(level);
  Writer w;
  for (char c : kMagic) w.put(c);
  w.put(kVersion);
  putCamera(w, camera);
  w.put<int32_t>(level);
  w.put(kf.id);
  w.put(kf.frame_id);
  w.put(kf.timestamp);
  w.putPose(kf.pose_world);
  putIncoming(w, incoming);
  w.putFloats(finest.intensity);
  w.putFloats(finest.depth);
  w.put(fnv1a64(w.bytes().data(), w.bytes().size()));
  const fs::path dir = archiveDir(session_dir);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw Error("cannot create " + dir.string() + " (" + ec.message() + "); check the session folder's permissions");
  writeFileAtomically((dir / fileName(kf.id)).string(), w.bytes());
}

std::string keyframeFile(const std::string& session_dir, int64_t id) {
  return (archiveDir(session_dir) / fileName(id)).string();
}

StoredKeyframe loadKeyframe(const std::string& session_dir, int64_t id, const AlignerParams& params) {
  const fs::path path = keyframeFile(session_dir, id);
  if (!fs::exists(path)) throw Error(path.string() + " is missing; the keyframe's file was removed while in use");
  return readKeyframe(path, params);
}

std::vector<StoredKeyframe> loadKeyframes(const std::string& session_dir, const AlignerParams& params) {
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(archiveDir(session_dir), ec))
    if (e.path().extension() == ".rkd") files.push_back(e.path());
  std::vector<StoredKeyframe> out;
  for (const fs::path& f : files) {
    out.push_back(readKeyframe(f, params));
    if (!sameCamera(out.back().camera, out.front().camera))
      throw Error(f.string() + ": made with another camera (" + describeCamera(out.back().camera) + ") than " +
                  files.front().string() + " (" + describeCamera(out.front().camera) + "); the session is damaged");
  }
  if (out.empty())
    throw Error(session_dir + " has no tracker keyframes (tracker/dvo_*.rkd): made by an older rekon, or its run "
                "stopped before the first keyframe; there is nothing to relocalise against, start a new session instead");
  std::sort(out.begin(), out.end(), [](const StoredKeyframe& a, const StoredKeyframe& b) { return a.keyframe->id < b.keyframe->id; });
  return out;
}

std::unordered_map<int64_t, Pose> loadMapPoses(const std::string& session_dir) {
  const fs::path path = fs::path(session_dir) / "anchors.txt";
  if (!fs::exists(path))
    throw Error(path.string() + " is missing: localising needs the map's keyframe poses, which the mapper writes "
                "there; localise in a session that a run with the mapper made");
  // Its lines are TUM's ("id tx ty tz qx qy qz qw", the id where TUM has the time): one reader for both.
  std::unordered_map<int64_t, Pose> poses;
  for (const StampedPose& p : readTumTrajectory(path.string())) poses[static_cast<int64_t>(p.timestamp)] = p.pose;
  return poses;
}

}  // namespace rekon::tracker
