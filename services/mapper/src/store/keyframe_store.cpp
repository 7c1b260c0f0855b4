#include "rekon/mapper/store/keyframe_store.hpp"

#include <boost/interprocess/allocators/allocator.hpp>
#include <boost/interprocess/containers/vector.hpp>
#include <boost/interprocess/managed_shared_memory.hpp>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/common/kill_point.hpp"
#include "shm_mutex.hpp"
#include "spill_file.hpp"

namespace rekon::store {
namespace bip = boost::interprocess;

namespace {

constexpr uint32_t kMagic = 0x524b4653;  // "RKFS"
constexpr uint32_t kLayoutVersion = 4;  // 2: spill folder, spilled flag; 3: the run's end; 4: robust lock
constexpr std::chrono::seconds kLockPatience{5};  // for a live holder (a read or a spill holds it for milliseconds)
constexpr size_t kMaxSpillDirChars = 1023;

struct ShmPose {
  double t[3];
  double q[4];
};
ShmPose toShm(const Pose& p) {
  const Eigen::Quaterniond q(p.linear());
  return {{p.translation().x(), p.translation().y(), p.translation().z()}, {q.x(), q.y(), q.z(), q.w()}};
}
Pose fromShm(const ShmPose& s) {
  return poseFromQuatTrans(Eigen::Quaterniond(s.q[3], s.q[0], s.q[1], s.q[2]).normalized(),
                           Eigen::Vector3d(s.t[0], s.t[1], s.t[2]));
}

// One keyframe: metadata, then depth (float), weight (float) and color (BGR) in one block.
struct ShmKeyframe {
  int64_t id, anchor, first_frame, last_frame;
  int32_t frames, integrated;
  double timestamp;
  ShmPose pose_in_anchor, integrated_pose;
  int32_t spilled, reserved;
  bip::offset_ptr<uint8_t> data;  // null when spilled
};
struct ShmAnchor {
  int64_t id;
  ShmPose pose;
  int32_t being_written;  // 1 while pose changes: a holder that died then left it torn (unknown)
  int32_t reserved;
};
using SegmentManager = bip::managed_shared_memory::segment_manager;
using KeyframeVector = bip::vector<ShmKeyframe, bip::allocator<ShmKeyframe, SegmentManager>>;
using AnchorVector = bip::vector<ShmAnchor, bip::allocator<ShmAnchor, SegmentManager>>;

struct Header {
  uint32_t magic = kMagic, version = kLayoutVersion;
  int32_t width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0, depth_scale = 0;
  char spill_dir[kMaxSpillDirChars + 1] = {};  // absolute; empty = spilling off
  uint64_t spilled_bytes = 0;
  int32_t run_finished = 0;  // 1 once the mapper's run finished (outputs written)
  int64_t run_end_frame = 0;  // then: the stream's last frame, as its done_t says it
  ShmMutex mutex;
  int32_t allocator_pid = 0;  // the holder while it is inside the segment's allocator, else 0
};

// Orders the stores before it before those after it, as a process killed
// between them leaves them (the compiler may not move stores across it).
void ordered() { std::atomic_signal_fence(std::memory_order_seq_cst); }

size_t imageBytes(int w, int h) { return keyframeImageBytes(w, h); }

std::string spillDirOf(const Header& h) { return std::string(h.spill_dir, strnlen(h.spill_dir, sizeof(h.spill_dir))); }

// The spill files of `segment` in `dir` (none when dir is empty or absent).
void removeSpillFiles(const std::string& dir, const std::string& segment) {
  if (dir.empty()) return;
  std::error_code ec;
  std::filesystem::directory_iterator it(dir, ec), end;
  if (ec) return;
  size_t removed = 0;
  for (; it != end; it.increment(ec)) {
    if (ec) break;
    if (isSpillFileOf(it->path().filename().string(), segment) && std::filesystem::remove(it->path(), ec)) ++removed;
  }
  if (removed > 0) spdlog::info("removed {} keyframe spill files of '{}' from {}", removed, segment, dir);
}

KeyframeInfo infoOf(const ShmKeyframe& k) {
  KeyframeInfo i;
  i.id = k.id;
  i.anchor_keyframe_id = k.anchor;
  i.first_frame_id = k.first_frame;
  i.last_frame_id = k.last_frame;
  i.frames = k.frames;
  i.timestamp = k.timestamp;
  i.pose_in_anchor = fromShm(k.pose_in_anchor);
  i.integrated_pose = fromShm(k.integrated_pose);
  i.integrated = k.integrated != 0;
  i.spilled = k.data == nullptr;
  return i;
}

fusion::FusedKeyframe unpack(const ShmKeyframe& k, const uint8_t* data, int width, int height) {
  fusion::FusedKeyframe kf = withoutImages(infoOf(k));
  unpackKeyframeImages(data, width, height, kf);
  return kf;
}

Intrinsics intrinsicsOf(const Header& h) {
  Intrinsics k;
  k.width = h.width;
  k.height = h.height;
  k.fx = h.fx;
  k.fy = h.fy;
  k.cx = h.cx;
  k.cy = h.cy;
  k.depth_scale = h.depth_scale;
  return k;
}

}  // namespace

std::string autoSpillDir(const std::string& segment) {
  return (std::filesystem::path(tempFolder()) / (segment + ".spill")).string();
}

StoreOptions StoreOptions::fromConfig(const Config& c) {
  StoreOptions o;
  o.segment = c.getString("mapper.store_segment");
  o.size_mb = c.getInt("mapper.store_mb");
  o.spill_dir = c.getString("mapper.store_spill_dir");
  return o;
}

struct KeyframeStore::Impl {
  std::string name;
  int size_mb = 0;
  bip::managed_shared_memory segment;
  Header* header = nullptr;
  KeyframeVector* keyframes = nullptr;
  AnchorVector* anchors = nullptr;

  // A process killed while holding the lock (a mapper under SIGKILL, a
  // reader) leaves nothing half-written: every change below is ordered so
  // that any prefix of it is a valid store. Only the segment's allocator is
  // not: a death inside it makes the store an error (it stays one for every
  // later process: the lock is left unrecoverable).
  ShmLock lock() const {
    ShmLock l(header->mutex, "keyframe store '" + name + "'", kLockPatience);
    if (!l.ownerDied()) return l;
    if (header->allocator_pid != 0)
      throw BrokenStore("keyframe store '" + name + "' is broken: process " + std::to_string(header->allocator_pid) +
                  " died inside its allocator; remove it (rekon keyframes --remove) and start without mapper.resume");
    spdlog::warn("keyframe store '{}': process {} died holding its lock; nothing was half-written, carrying on", name,
                 l.deadPid());
    l.markConsistent();
    return l;
  }
  // Runs f (a call into the segment's allocator) marked, so that a death inside it is known.
  template <typename F>
  auto inAllocator(F&& f) {
    struct Mark {
      Header* h;
      explicit Mark(Header* header) : h(header) {
        h->allocator_pid = getpid();
        ordered();
      }
      ~Mark() {
        ordered();
        h->allocator_pid = 0;
      }
    } mark(header);
    killPoint("store.allocator");  // a crash-only test dies here (rekon/common/kill_point.hpp)
    return f();
  }
  ShmKeyframe* find(int64_t id) const {
    for (ShmKeyframe& k : *keyframes)
      if (k.id == id) return &k;
    return nullptr;
  }
  [[noreturn]] void full(const std::string& what) const {
    const bool spilling = header->spill_dir[0] != '\0';
    throw Error("keyframe store '" + name + "' is full (" + std::to_string(size_mb) + " MiB) while adding " + what +
                (spilling ? " even with every other keyframe spilled; raise mapper.store_mb"
                          : "; raise mapper.store_mb or let it spill (mapper.store_spill_dir)"));
  }

  std::optional<Pose> anchorPose(int64_t id) const {
    for (const ShmAnchor& a : *anchors)
      if (a.id == id && a.being_written == 0) return fromShm(a.pose);
    return std::nullopt;
  }
  // Where a keyframe was seen from: its integrated pose, else its anchor's
  // pose times its pose in the anchor; unknown when neither is stored.
  std::optional<Eigen::Vector3d> position(const ShmKeyframe& k) const {
    if (k.integrated) return fromShm(k.integrated_pose).translation();
    if (const auto a = anchorPose(k.anchor)) return (*a * fromShm(k.pose_in_anchor)).translation();
    return std::nullopt;
  }
  // Where the camera is now, as far as the store knows: the newest keyframe with a position.
  std::optional<Eigen::Vector3d> newestPosition() const {
    std::optional<Eigen::Vector3d> at;
    int64_t newest = std::numeric_limits<int64_t>::min();
    for (const ShmKeyframe& k : *keyframes) {
      if (k.id <= newest) continue;
      if (const auto p = position(k)) {
        at = p;
        newest = k.id;
      }
    }
    return at;
  }

  // Moves one resident keyframe's images to a file: the farthest from
  // `camera` (unknown positions count as nearest: kept), ties the oldest.
  // False when spilling is off or nothing is resident.
  bool spillOne(const std::optional<Eigen::Vector3d>& camera) {
    const std::string dir = spillDirOf(*header);
    if (dir.empty()) return false;
    ShmKeyframe* victim = nullptr;
    double victim_distance = -1.0;
    for (ShmKeyframe& k : *keyframes) {
      if (k.data == nullptr) continue;
      double d = -0.5;
      if (camera)
        if (const auto p = position(k)) d = (*p - *camera).norm();
      if (!camera) d = 0.0;  // no reference at all: oldest first
      if (victim == nullptr || d > victim_distance || (d == victim_distance && k.id < victim->id)) {
        victim = &k;
        victim_distance = d;
      }
    }
    if (victim == nullptr) return false;
    const size_t bytes = imageBytes(header->width, header->height);
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);  // removed behind our back: recreate rather than fail
    writeSpillFile(spillFilePath(dir, name, victim->id), victim->id, header->width, header->height, victim->data.get(), bytes);
    uint8_t* images = victim->data.get();
    victim->spilled = 1;  // the file is whole (renamed into place): either state reads the same images
    ordered();
    victim->data = nullptr;
    header->spilled_bytes += spillFileBytes(bytes);
    ordered();
    inAllocator([&] { segment.deallocate(images); });  // a death before this only leaks the block
    spdlog::debug("keyframe store '{}': spilled keyframe {} ({:.1f} m from the camera) to {}", name, victim->id,
                  victim_distance, dir);
    return true;
  }

  uint8_t* allocate(size_t bytes, const std::string& what, const std::optional<Eigen::Vector3d>& camera) {
    for (;;) {
      try {
        return static_cast<uint8_t*>(inAllocator([&] { return segment.allocate(bytes); }));
      } catch (const bip::bad_alloc&) {
        if (!spillOne(camera)) full(what);
      }
    }
  }
  template <typename Vector, typename Value>
  void pushBack(Vector& v, const Value& value, const std::string& what, const std::optional<Eigen::Vector3d>& camera) {
    for (;;) {
      try {
        inAllocator([&] { v.push_back(value); });  // it may grow v
        return;
      } catch (const bip::bad_alloc&) {
        if (!spillOne(camera)) full(what);
      }
    }
  }

  fusion::FusedKeyframe load(const ShmKeyframe& k) const {
    const int w = header->width, h = header->height;
    if (k.data != nullptr) return unpack(k, k.data.get(), w, h);
    std::vector<uint8_t> buffer(imageBytes(w, h));
    readSpillFile(spillFilePath(spillDirOf(*header), name, k.id), k.id, w, h, buffer.data(), buffer.size());
    return unpack(k, buffer.data(), w, h);
  }
};

KeyframeStore::KeyframeStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
KeyframeStore::~KeyframeStore() = default;

namespace {

// "off" -> "", "auto" -> autoSpillDir, else the folder made absolute; created.
std::string prepareSpillDir(const StoreOptions& options) {
  if (options.spill_dir == StoreOptions::kNoSpilling) return "";
  if (options.spill_dir.empty())
    throw Error("mapper.store_spill_dir is empty; give a folder, auto or off");
  std::error_code ec;
  const std::string wanted = options.spill_dir == StoreOptions::kAutoSpillDir ? autoSpillDir(options.segment) : options.spill_dir;
  const std::filesystem::path dir = std::filesystem::absolute(wanted, ec);
  if (ec || dir.string().size() > kMaxSpillDirChars)
    throw Error("mapper.store_spill_dir '" + wanted + "' is not a usable path (at most " +
                std::to_string(kMaxSpillDirChars) + " characters)");
  std::filesystem::create_directories(dir, ec);
  if (ec || !std::filesystem::is_directory(dir))
    throw Error("keyframe spill folder " + dir.string() + " cannot be created (" +
                (ec ? ec.message() : std::string("not a folder")) + "); set mapper.store_spill_dir to a writable folder, or off");
  return dir.string();
}

}  // namespace

std::unique_ptr<KeyframeStore> KeyframeStore::openOrCreate(const StoreOptions& options, const Intrinsics& k) {
  if (options.segment.empty()) throw Error("mapper.store_segment is empty; name the shared-memory segment");
  if (options.size_mb < 1) throw Error("mapper.store_mb must be at least 1 (MiB of the keyframe store)");
  auto impl = std::make_unique<Impl>();
  impl->name = options.segment;
  impl->size_mb = options.size_mb;
  try {
    impl->segment = bip::managed_shared_memory(bip::open_or_create, options.segment.c_str(),
                                               static_cast<size_t>(options.size_mb) << 20);
    impl->header = impl->segment.find_or_construct<Header>("header")();
    impl->keyframes = impl->segment.find_or_construct<KeyframeVector>("keyframes")(impl->segment.get_segment_manager());
    impl->anchors = impl->segment.find_or_construct<AnchorVector>("anchors")(impl->segment.get_segment_manager());
  } catch (const bip::interprocess_exception& e) {
    throw Error("keyframe store '" + options.segment + "' cannot be opened or created (" + e.what() +
                "); check /dev/shm space or mapper.store_mb");
  }
  Header& h = *impl->header;
  if (h.magic != kMagic || h.version != kLayoutVersion)
    throw Error("keyframe store '" + options.segment + "' has another layout; remove it (rekon keyframes --remove)");
  impl->size_mb = static_cast<int>(impl->segment.get_size() >> 20);  // an existing segment keeps its size
  if (h.width == 0) {
    const std::string dir = prepareSpillDir(options);
    std::memcpy(h.spill_dir, dir.c_str(), dir.size() + 1);
    h.width = k.width;
    h.height = k.height;
    h.fx = k.fx;
    h.fy = k.fy;
    h.cx = k.cx;
    h.cy = k.cy;
    h.depth_scale = k.depth_scale;
  } else if (!sameCamera(intrinsicsOf(h), k)) {
    throw Error("keyframe store '" + options.segment + "' holds keyframes of another camera (" +
                std::to_string(h.width) + "x" + std::to_string(h.height) +
                "); remove it (rekon keyframes --remove) or set mapper.store_segment");
  } else {
    const std::string dir = spillDirOf(h);
    size_t spilled = 0;
    for (const ShmKeyframe& kf : *impl->keyframes) spilled += kf.spilled != 0;
    if (spilled > 0 && !std::filesystem::is_directory(dir))
      throw Error("keyframe store '" + options.segment + "' has " + std::to_string(spilled) +
                  " keyframes spilled to " + dir + ", which is missing; restore the folder or remove the store (rekon keyframes --remove)");
  }
  return std::unique_ptr<KeyframeStore>(new KeyframeStore(std::move(impl)));
}

std::unique_ptr<KeyframeStore> KeyframeStore::openExisting(const std::string& segment) {
  auto impl = std::make_unique<Impl>();
  impl->name = segment;
  try {
    impl->segment = bip::managed_shared_memory(bip::open_only, segment.c_str());
  } catch (const bip::interprocess_exception& e) {
    throw Error("keyframe store '" + segment + "' does not exist (" + e.what() +
                "); is a mapper running, or give --segment NAME");
  }
  impl->size_mb = static_cast<int>(impl->segment.get_size() >> 20);
  impl->header = impl->segment.find<Header>("header").first;
  impl->keyframes = impl->segment.find<KeyframeVector>("keyframes").first;
  impl->anchors = impl->segment.find<AnchorVector>("anchors").first;
  if (impl->header == nullptr || impl->keyframes == nullptr || impl->anchors == nullptr ||
      impl->header->magic != kMagic || impl->header->version != kLayoutVersion)
    throw Error("shared-memory segment '" + segment + "' is not a rekon keyframe store of this version");
  return std::unique_ptr<KeyframeStore>(new KeyframeStore(std::move(impl)));
}

bool KeyframeStore::remove(const std::string& segment) {
  std::string dir;
  try {
    bip::managed_shared_memory existing(bip::open_only, segment.c_str());
    const Header* h = existing.find<Header>("header").first;
    if (h != nullptr && h->magic == kMagic && h->version == kLayoutVersion) dir = spillDirOf(*h);
  } catch (const bip::interprocess_exception&) {
    // absent: its spill files, if a crash left any, can only be in the automatic folder
  }
  removeSpillFiles(dir, segment);
  const std::string automatic = autoSpillDir(segment);
  if (dir != automatic) removeSpillFiles(automatic, segment);
  std::error_code ec;
  std::filesystem::remove(automatic, ec);  // only when empty: never another store's or the user's files
  return bip::shared_memory_object::remove(segment.c_str());
}

const std::string& KeyframeStore::segment() const { return impl_->name; }

Intrinsics KeyframeStore::intrinsics() const { return intrinsicsOf(*impl_->header); }

size_t KeyframeStore::size() const {
  auto l = impl_->lock();
  return impl_->keyframes->size();
}
size_t KeyframeStore::freeBytes() const { return impl_->segment.get_free_memory(); }
size_t KeyframeStore::totalBytes() const { return impl_->segment.get_size(); }

StoreUsage KeyframeStore::usage() const {
  auto l = impl_->lock();
  StoreUsage u;
  u.keyframes = impl_->keyframes->size();
  for (const ShmKeyframe& k : *impl_->keyframes) (k.data != nullptr ? u.resident : u.spilled) += 1;
  u.shm_total_bytes = impl_->segment.get_size();
  u.shm_used_bytes = u.shm_total_bytes - impl_->segment.get_free_memory();
  u.spilled_bytes = impl_->header->spilled_bytes;
  u.spill_dir = spillDirOf(*impl_->header);
  return u;
}

void KeyframeStore::add(const fusion::FusedKeyframe& kf) {
  const Header& h = *impl_->header;
  if (kf.depth.cols != h.width || kf.depth.rows != h.height || kf.depth.type() != CV_32F ||
      kf.weight.size() != kf.depth.size() || kf.weight.type() != CV_32F || kf.color.size() != kf.depth.size() ||
      kf.color.type() != CV_8UC3)
    throw Error("keyframe store: keyframe " + std::to_string(kf.id) + " does not match the store's " +
                std::to_string(h.width) + "x" + std::to_string(h.height) + " camera");
  // The images are copied outside the lock: a writer killed while holding
  // it leaves the store locked for good, and the copy (3.3 MiB into fresh
  // pages) is nearly all of the time add() takes. An unindexed block is
  // reached by nobody; a writer killed during the copy only leaks it.
  std::optional<Eigen::Vector3d> camera;
  const std::string what = "keyframe " + std::to_string(kf.id);
  uint8_t* data = nullptr;
  {
    auto l = impl_->lock();
    if (impl_->find(kf.id) != nullptr) throw Error("keyframe store: keyframe " + std::to_string(kf.id) + " is stored already");
    if (const auto a = impl_->anchorPose(kf.anchor_keyframe_id)) camera = (*a * kf.pose_in_anchor).translation();
    else camera = impl_->newestPosition();
    data = impl_->allocate(imageBytes(h.width, h.height), what, camera);
  }
  packKeyframeImages(kf, data);
  ShmKeyframe rec{};
  rec.id = kf.id;
  rec.anchor = kf.anchor_keyframe_id;
  rec.first_frame = kf.first_frame_id;
  rec.last_frame = kf.last_frame_id;
  rec.frames = kf.frames;
  rec.integrated = 0;
  rec.timestamp = kf.timestamp;
  rec.pose_in_anchor = toShm(kf.pose_in_anchor);
  rec.integrated_pose = toShm(Pose::Identity());
  rec.spilled = 0;
  rec.data = data;
  auto l = impl_->lock();
  try {
    impl_->pushBack(*impl_->keyframes, rec, "the index entry of " + what, camera);
  } catch (...) {
    impl_->inAllocator([&] { impl_->segment.deallocate(data); });
    throw;
  }
}

void KeyframeStore::setIntegratedPose(int64_t id, const Pose& pose) {
  auto l = impl_->lock();
  ShmKeyframe* k = impl_->find(id);
  if (k == nullptr) throw Error("keyframe store: no keyframe " + std::to_string(id) + " to set the pose of");
  k->integrated = 0;  // a death while the pose is torn leaves "never integrated": integrated again at its pose
  ordered();
  k->integrated_pose = toShm(pose);
  ordered();
  k->integrated = 1;
}

void KeyframeStore::setAnchorPose(int64_t keyframe_id, const Pose& pose) {
  auto l = impl_->lock();
  for (ShmAnchor& a : *impl_->anchors) {
    if (a.id == keyframe_id) {
      a.being_written = 1;
      ordered();
      a.pose = toShm(pose);
      ordered();
      a.being_written = 0;
      return;
    }
  }
  impl_->pushBack(*impl_->anchors, ShmAnchor{keyframe_id, toShm(pose), 0, 0},
                  "the pose of DVO keyframe " + std::to_string(keyframe_id), pose.translation().eval());
}

void KeyframeStore::markRunFinished(int64_t end_frame) {
  auto l = impl_->lock();
  impl_->header->run_end_frame = end_frame;
  ordered();
  impl_->header->run_finished = 1;
}

std::optional<int64_t> KeyframeStore::runEndFrame() const {
  auto l = impl_->lock();
  if (impl_->header->run_finished == 0) return std::nullopt;
  return impl_->header->run_end_frame;
}

std::vector<std::pair<int64_t, Pose>> KeyframeStore::anchorPoses() const {
  auto l = impl_->lock();
  std::vector<std::pair<int64_t, Pose>> out;
  for (const ShmAnchor& a : *impl_->anchors)
    if (a.being_written == 0) out.emplace_back(a.id, fromShm(a.pose));
  return out;
}

fusion::FusedKeyframe withoutImages(const KeyframeInfo& info) {
  fusion::FusedKeyframe kf;
  kf.id = info.id;
  kf.anchor_keyframe_id = info.anchor_keyframe_id;
  kf.pose_in_anchor = info.pose_in_anchor;
  kf.first_frame_id = info.first_frame_id;
  kf.last_frame_id = info.last_frame_id;
  kf.frames = info.frames;
  kf.timestamp = info.timestamp;
  return kf;
}

std::vector<KeyframeInfo> KeyframeStore::list() const {
  auto l = impl_->lock();
  std::vector<KeyframeInfo> out;
  for (const ShmKeyframe& k : *impl_->keyframes) out.push_back(infoOf(k));
  return out;
}

fusion::FusedKeyframe KeyframeStore::load(size_t index) const {
  auto l = impl_->lock();
  if (index >= impl_->keyframes->size())
    throw Error("keyframe store: index " + std::to_string(index) + " beyond its " +
                std::to_string(impl_->keyframes->size()) + " keyframes");
  return impl_->load((*impl_->keyframes)[index]);
}

fusion::FusedKeyframe KeyframeStore::loadById(int64_t id) const {
  auto l = impl_->lock();
  const ShmKeyframe* k = impl_->find(id);
  if (k == nullptr) throw Error("keyframe store '" + impl_->name + "': no keyframe " + std::to_string(id));
  return impl_->load(*k);
}

}  // namespace rekon::store
