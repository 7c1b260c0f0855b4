#include "rekon/store/keyframe_store.hpp"

#include <boost/interprocess/allocators/allocator.hpp>
#include <boost/interprocess/containers/vector.hpp>
#include <boost/interprocess/managed_shared_memory.hpp>
#include <boost/interprocess/sync/interprocess_mutex.hpp>
#include <boost/interprocess/sync/scoped_lock.hpp>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstring>
#include <thread>

#include "rekon/common/error.hpp"

namespace rekon::store {
namespace bip = boost::interprocess;

namespace {

constexpr uint32_t kMagic = 0x524b4653;  // "RKFS"
constexpr uint32_t kLayoutVersion = 1;

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
  bip::offset_ptr<uint8_t> data;
};
struct ShmAnchor {
  int64_t id;
  ShmPose pose;
};
using SegmentManager = bip::managed_shared_memory::segment_manager;
using KeyframeVector = bip::vector<ShmKeyframe, bip::allocator<ShmKeyframe, SegmentManager>>;
using AnchorVector = bip::vector<ShmAnchor, bip::allocator<ShmAnchor, SegmentManager>>;

struct Header {
  uint32_t magic = kMagic, version = kLayoutVersion;
  int32_t width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0, depth_scale = 0;
  bip::interprocess_mutex mutex;
};

size_t imageBytes(int w, int h) { return static_cast<size_t>(w) * h * (4 + 4 + 3); }

}  // namespace

struct KeyframeStore::Impl {
  std::string name;
  int size_mb = 0;
  bip::managed_shared_memory segment;
  Header* header = nullptr;
  KeyframeVector* keyframes = nullptr;
  AnchorVector* anchors = nullptr;

  // A crashed writer could leave the mutex locked; waiting forever would hang
  // the restart that is supposed to recover, so give up with an error.
  bip::scoped_lock<bip::interprocess_mutex> lock() const {
    bip::scoped_lock<bip::interprocess_mutex> l(header->mutex, bip::defer_lock);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (!l.try_lock()) {
      if (std::chrono::steady_clock::now() > deadline)
        throw Error("keyframe store '" + name + "' stays locked (a writer died holding it?); remove it with rekon keyframes --remove");
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return l;
  }
  ShmKeyframe* find(int64_t id) const {
    for (ShmKeyframe& k : *keyframes)
      if (k.id == id) return &k;
    return nullptr;
  }
  [[noreturn]] void full(const std::string& what) const {
    throw Error("keyframe store '" + name + "' is full (" + std::to_string(size_mb) + " MiB) while adding " + what +
                "; raise mapper.store_mb");
  }
};

KeyframeStore::KeyframeStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
KeyframeStore::~KeyframeStore() = default;

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
  if (h.width == 0) {
    h.width = k.width;
    h.height = k.height;
    h.fx = k.fx;
    h.fy = k.fy;
    h.cx = k.cx;
    h.cy = k.cy;
    h.depth_scale = k.depth_scale;
  } else if (h.width != k.width || h.height != k.height || h.fx != k.fx || h.fy != k.fy || h.cx != k.cx ||
             h.cy != k.cy) {
    throw Error("keyframe store '" + options.segment + "' holds keyframes of another camera (" +
                std::to_string(h.width) + "x" + std::to_string(h.height) +
                "); remove it (rekon keyframes --remove) or set mapper.store_segment");
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

bool KeyframeStore::remove(const std::string& segment) { return bip::shared_memory_object::remove(segment.c_str()); }

const std::string& KeyframeStore::segment() const { return impl_->name; }

Intrinsics KeyframeStore::intrinsics() const {
  const Header& h = *impl_->header;
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

size_t KeyframeStore::size() const {
  auto l = impl_->lock();
  return impl_->keyframes->size();
}
size_t KeyframeStore::freeBytes() const { return impl_->segment.get_free_memory(); }
size_t KeyframeStore::totalBytes() const { return impl_->segment.get_size(); }

void KeyframeStore::add(const fusion::FusedKeyframe& kf) {
  const Header& h = *impl_->header;
  if (kf.depth.cols != h.width || kf.depth.rows != h.height || kf.depth.type() != CV_32F ||
      kf.weight.size() != kf.depth.size() || kf.weight.type() != CV_32F || kf.color.size() != kf.depth.size() ||
      kf.color.type() != CV_8UC3)
    throw Error("keyframe store: keyframe " + std::to_string(kf.id) + " does not match the store's " +
                std::to_string(h.width) + "x" + std::to_string(h.height) + " camera");
  auto l = impl_->lock();
  if (impl_->find(kf.id) != nullptr) throw Error("keyframe store: keyframe " + std::to_string(kf.id) + " is stored already");
  const size_t pixels = static_cast<size_t>(h.width) * h.height;
  uint8_t* data = nullptr;
  try {
    data = static_cast<uint8_t*>(impl_->segment.allocate(imageBytes(h.width, h.height)));
  } catch (const bip::bad_alloc&) {
    impl_->full("keyframe " + std::to_string(kf.id));
  }
  kf.depth.copyTo(cv::Mat(h.height, h.width, CV_32F, data));
  kf.weight.copyTo(cv::Mat(h.height, h.width, CV_32F, data + 4 * pixels));
  kf.color.copyTo(cv::Mat(h.height, h.width, CV_8UC3, data + 8 * pixels));
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
  rec.data = data;
  try {
    impl_->keyframes->push_back(rec);
  } catch (const bip::bad_alloc&) {
    impl_->segment.deallocate(data);
    impl_->full("the index entry of keyframe " + std::to_string(kf.id));
  }
}

void KeyframeStore::setIntegratedPose(int64_t id, const Pose& pose) {
  auto l = impl_->lock();
  ShmKeyframe* k = impl_->find(id);
  if (k == nullptr) throw Error("keyframe store: no keyframe " + std::to_string(id) + " to set the pose of");
  k->integrated_pose = toShm(pose);
  k->integrated = 1;
}

void KeyframeStore::setAnchorPose(int64_t keyframe_id, const Pose& pose) {
  auto l = impl_->lock();
  for (ShmAnchor& a : *impl_->anchors) {
    if (a.id == keyframe_id) {
      a.pose = toShm(pose);
      return;
    }
  }
  try {
    impl_->anchors->push_back({keyframe_id, toShm(pose)});
  } catch (const bip::bad_alloc&) {
    impl_->full("the pose of DVO keyframe " + std::to_string(keyframe_id));
  }
}

std::vector<std::pair<int64_t, Pose>> KeyframeStore::anchorPoses() const {
  auto l = impl_->lock();
  std::vector<std::pair<int64_t, Pose>> out;
  for (const ShmAnchor& a : *impl_->anchors) out.emplace_back(a.id, fromShm(a.pose));
  return out;
}

std::vector<KeyframeInfo> KeyframeStore::list() const {
  auto l = impl_->lock();
  std::vector<KeyframeInfo> out;
  for (const ShmKeyframe& k : *impl_->keyframes) {
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
    out.push_back(i);
  }
  return out;
}

fusion::FusedKeyframe KeyframeStore::load(size_t index) const {
  auto l = impl_->lock();
  if (index >= impl_->keyframes->size())
    throw Error("keyframe store: index " + std::to_string(index) + " beyond its " +
                std::to_string(impl_->keyframes->size()) + " keyframes");
  const ShmKeyframe& k = (*impl_->keyframes)[index];
  const Header& h = *impl_->header;
  const size_t pixels = static_cast<size_t>(h.width) * h.height;
  uint8_t* data = k.data.get();
  fusion::FusedKeyframe kf;
  kf.id = k.id;
  kf.anchor_keyframe_id = k.anchor;
  kf.pose_in_anchor = fromShm(k.pose_in_anchor);
  kf.first_frame_id = k.first_frame;
  kf.last_frame_id = k.last_frame;
  kf.frames = k.frames;
  kf.timestamp = k.timestamp;
  kf.depth = cv::Mat(h.height, h.width, CV_32F, data).clone();
  kf.weight = cv::Mat(h.height, h.width, CV_32F, data + 4 * pixels).clone();
  kf.color = cv::Mat(h.height, h.width, CV_8UC3, data + 8 * pixels).clone();
  return kf;
}

}  // namespace rekon::store
