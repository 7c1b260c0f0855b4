#include "mesh_publisher.hpp"

#include <spdlog/spdlog.h>

#include <Eigen/Core>
#include <algorithm>
#include <optional>
#include <string>
#include <thread>
#include <tuple>

#include "../src/volume/marching_cubes.hpp"
#include "rekon/common/bus.hpp"
#include "rekon/common/cpu_time.hpp"
#include "rekon/common/error.hpp"
#include "rekon_msgs/mesh_request_t.hpp"

namespace rekon::mapper {
namespace {

// Messages below this cannot hold a full block (8^3 voxels: up to ~40 KB raw, mostly less).
constexpr size_t kMinMessageBytes = 16 * 1024;
constexpr std::chrono::milliseconds kPartGap{3};

std::chrono::duration<double> seconds(double s) { return std::chrono::duration<double>(s); }

int64_t wallMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch()).count();
}

// Where the newest integrated KF keyframe's camera is now (none yet: the origin).
Eigen::Vector3d cameraPosition(const Mapper& mapper) {
  const std::vector<KeyframeRecord>& kfs = mapper.keyframes();
  for (auto it = kfs.rbegin(); it != kfs.rend(); ++it) {
    if (!it->integrated) continue;
    if (const std::optional<Pose> pose = mapper.currentPose(it->kf)) return pose->translation();
  }
  return Eigen::Vector3d::Zero();
}

}  // namespace

MeshPublisherSettings MeshPublisherSettings::fromConfig(const Config& config) {
  MeshPublisherSettings s;
  s.enabled = config.getBool("mapper.mesh_publish");
  s.rate_hz = config.getDouble("mapper.mesh_rate_hz");
  s.max_bytes_per_s = config.getDouble("mapper.mesh_max_bytes_per_s");
  const int max_message = config.getInt("mapper.mesh_max_message_bytes");
  s.full_every_s = config.getDouble("mapper.mesh_full_every_s");
  s.coarse_first = config.getBool("mapper.mesh_coarse_first");
  s.publish_unasked = config.getBool("mapper.mesh_publish_unasked");
  auto bad = [](const std::string& key, double value, const std::string& want) {
    throw Error("mapper." + key + " = " + std::to_string(value) + " is invalid; it must be " + want);
  };
  if (!(s.rate_hz > 0.0 && s.rate_hz <= 100.0)) bad("mesh_rate_hz", s.rate_hz, "in (0, 100]");
  if (!(s.max_bytes_per_s >= 1e4)) bad("mesh_max_bytes_per_s", s.max_bytes_per_s, "at least 10000");
  if (max_message < static_cast<int>(kMinMessageBytes) || max_message > (16 << 20)) {
    bad("mesh_max_message_bytes", max_message, "in [16384, 16777216] (UDP multicast fragments larger LCM messages)");
  }
  if (!(s.full_every_s >= 0.0)) bad("mesh_full_every_s", s.full_every_s, ">= 0 (0 = only on request)");
  s.max_message_bytes = static_cast<size_t>(max_message);
  return s;
}

MeshPublisher::MeshPublisher(ServiceContext& ctx, const MeshPublisherSettings& settings, const volume::VolumeParams& volume)
    : ctx_(ctx), settings_(settings) {
  codec_.voxel_size = volume.voxel_size;
  codec_.block_voxels = volume::kBlockSide;
  codec_.max_message_bytes = settings.max_message_bytes;
  tokens_ = settings.max_bytes_per_s / settings.rate_hz;
}

MeshPublisher::~MeshPublisher() { waitUntilSent(); }

void MeshPublisher::subscribe() {
  if (!settings_.enabled) return;
  ctx_.bus().subscribe<rekon_msgs::mesh_request_t>(channel::kMeshRequest, [this](const rekon_msgs::mesh_request_t& m) {
    spdlog::info("mapper: {} asks for the whole mesh", m.requester.empty() ? std::string("a subscriber") : m.requester);
    full_requested_ = true;
    asked_ = true;
  });
}

std::chrono::milliseconds MeshPublisher::idleWait() const {
  return std::chrono::milliseconds(static_cast<int64_t>(1000.0 / settings_.rate_hz));
}

void MeshPublisher::tick(Mapper& mapper, BlockCause cause) {
  if (!settings_.enabled) return;
  try {
    update(mapper, cause);
  } catch (const Error& e) {  // the map on the bus is an extra: mapping goes on without it
    spdlog::error("mapper: mesh publishing stops: {}", e.what());
    settings_.enabled = false;
  }
}

void MeshPublisher::update(Mapper& mapper, BlockCause cause) {
  const double cpu0 = threadCpuMs();
  noteChanges(mapper, cause);
  if (!publishing()) return;
  const Clock::time_point now = Clock::now();
  const bool periodic_full = settings_.full_every_s > 0.0 && now - last_full_ >= seconds(settings_.full_every_s);
  if ((full_requested_ || periodic_full) && now - last_full_ >= seconds(MeshPublisherSettings::kFullMinIntervalS)) {
    full_requested_ = false;
    publishFull(mapper);
  } else if (!pending_.empty() && now - last_update_ >= seconds(1.0 / settings_.rate_hz)) {
    publishDelta(mapper, false);
  }
  stats_.cpu_ms += threadCpuMs() - cpu0;
}

void MeshPublisher::finish(Mapper& mapper, BlockCause cause) {
  if (!settings_.enabled) return;
  // The mapping is over: the last update meshes and encodes on every core
  // (the whole map after the final pass; it is the run's tail), and its CPU
  // is the process's.
  every_core_ = true;
  const double cpu0 = processCpuMs();
  send_behind_ = true;
  try {
    noteChanges(mapper, cause);
    if (full_requested_) {
      publishFull(mapper);
    } else if (publishing()) {
      publishDelta(mapper, true);
    }
  } catch (const Error& e) {
    spdlog::error("mapper: the last mesh update failed: {}", e.what());
  }
  send_behind_ = false;  // later updates (a test's) go out before they return, after this one
  stats_.cpu_ms += processCpuMs() - cpu0;  // its sending apart (a few ms of the gaps' time)
  spdlog::info("mapper: mesh on the bus: {} updates ({} full), {} blocks and {} coarse ones first, {:.1f} MB, {:.0f} ms CPU",
               stats_.updates, stats_.full_snapshots, stats_.blocks_sent, stats_.coarse_sent,
               static_cast<double>(stats_.bytes) / 1e6, stats_.cpu_ms);
}

int64_t MeshPublisher::newVersion() {
  last_version_ = std::max(last_version_ + 2, wallMicros());
  last_version_ += last_version_ & 1;  // even: version - 1, its coarse mesh's, is newer than any before
  return last_version_;
}

void MeshPublisher::noteChanges(Mapper& mapper, BlockCause cause) {
  if (!settings_.enabled) return;
  const std::vector<volume::BlockCoord> changed = mapper.takeMeshChanges();
  // Unasked, nobody has seen a block: the first request's snapshot sends them all.
  if (changed.empty() || !publishing()) return;
  const int64_t version = newVersion();
  for (const volume::BlockCoord& c : changed) {
    Stamp& stamp = version_[c];
    // A correction not sent yet stays one when new data lands on the block too.
    const bool unsent = pending_.count(c) > 0;
    stamp = {version, unsent ? std::max(stamp.cause, cause) : cause, stamp.seen};
    pending_[c] = version;
  }
  stats_.pending = static_cast<int64_t>(pending_.size());
}

void MeshPublisher::choose(const Mapper& mapper, bool unlimited, std::vector<volume::BlockCoord>* coarse,
                           std::vector<volume::BlockCoord>* full) const {
  const Eigen::Vector3d eye = cameraPosition(mapper);
  const double block_metres = codec_.voxel_size * codec_.block_voxels;
  struct Candidate {
    bool seen;
    double distance;  // from the camera to the block's centre, metres
    volume::BlockCoord coord;
  };
  std::vector<Candidate> order;
  order.reserve(pending_.size());
  for (const auto& [c, version] : pending_) {
    const Eigen::Vector3d centre = (Eigen::Vector3d(c.x, c.y, c.z) + Eigen::Vector3d::Constant(0.5)) * block_metres;
    order.push_back({version_.at(c).seen, (centre - eye).norm(), c});
  }
  const bool all_fit = unlimited || static_cast<double>(order.size()) * bytes_per_block_ <= tokens_;
  const bool coarse_first = settings_.coarse_first && !all_fit;
  // New blocks first (when they go coarse), then by distance; ties by coordinates.
  std::sort(order.begin(), order.end(), [coarse_first](const Candidate& a, const Candidate& b) {
    return std::make_tuple(coarse_first && a.seen, a.distance, a.coord.x, a.coord.y, a.coord.z) <
           std::make_tuple(coarse_first && b.seen, b.distance, b.coord.x, b.coord.y, b.coord.z);
  });
  double bytes = 0.0;
  for (const Candidate& c : order) {
    if (!unlimited && bytes >= tokens_ && !(coarse->empty() && full->empty())) break;
    const bool as_coarse = coarse_first && !c.seen;
    (as_coarse ? coarse : full)->push_back(c.coord);
    bytes += as_coarse ? bytes_per_coarse_block_ : bytes_per_block_;
  }
}

void MeshPublisher::publishDelta(Mapper& mapper, bool unlimited) {
  const Clock::time_point now = Clock::now();
  const double elapsed = std::chrono::duration<double>(now - last_refill_).count();
  last_refill_ = now;
  tokens_ = std::min(tokens_ + elapsed * settings_.max_bytes_per_s, settings_.max_bytes_per_s);
  if (pending_.empty() || (!unlimited && tokens_ <= 0.0)) return;
  std::vector<volume::BlockCoord> coarse, full;
  choose(mapper, unlimited, &coarse, &full);
  auto estimate = [](double& per_block, int64_t bytes, size_t blocks) {
    if (blocks > 0) per_block = 0.8 * per_block + 0.2 * static_cast<double>(bytes) / static_cast<double>(blocks);
  };
  if (!coarse.empty()) {
    // They stay pending for their full mesh; a block whose coarse mesh shows
    // nothing (a thin or half-observed surface) goes in full at once.
    std::vector<volume::BlockCoord> empty;
    const int64_t bytes = publish(mapper, coarse, false, true, &empty);
    tokens_ -= static_cast<double>(bytes);
    estimate(bytes_per_coarse_block_, bytes, coarse.size() - empty.size());
    full.insert(full.begin(), empty.begin(), empty.end());
  }
  if (!full.empty()) {
    for (const volume::BlockCoord& c : full) pending_.erase(c);
    const int64_t bytes = publish(mapper, full, false);
    tokens_ -= static_cast<double>(bytes);
    estimate(bytes_per_block_, bytes, full.size());
  }
  stats_.pending = static_cast<int64_t>(pending_.size());
}

void MeshPublisher::publishFull(Mapper& mapper) {
  std::vector<volume::BlockCoord> coords = mapper.volume().blockCoords();
  pending_.clear();  // the snapshot carries every block's newest mesh
  const int64_t version = newVersion();  // for blocks never changed here (restored from the store)
  for (const volume::BlockCoord& c : coords) version_.try_emplace(c, Stamp{version, BlockCause::kNewData});
  tokens_ -= static_cast<double>(publish(mapper, coords, true));
  last_full_ = Clock::now();
  ++stats_.full_snapshots;
  stats_.pending = 0;
}

int64_t MeshPublisher::publish(Mapper& mapper, const std::vector<volume::BlockCoord>& coords, bool full_snapshot,
                               bool coarse, std::vector<volume::BlockCoord>* empty_coarse) {
  std::vector<BlockMesh> meshes = coarse ? coarseMeshes(mapper, coords) : mapper.volume().meshBlocks(coords, every_core_ ? 0 : 1);
  if (coarse) {
    const auto empty = std::stable_partition(meshes.begin(), meshes.end(), [](const BlockMesh& m) { return !m.triangles.empty(); });
    for (auto it = empty; it != meshes.end(); ++it) empty_coarse->push_back({it->x, it->y, it->z});
    meshes.erase(empty, meshes.end());
  }
  for (BlockMesh& m : meshes) {
    Stamp& stamp = version_.at({m.x, m.y, m.z});
    m.version = coarse ? stamp.version - 1 : stamp.version;
    m.cause = stamp.cause;
    stamp.seen = true;
  }
  if (coarse && meshes.empty()) return 0;
  const int threads = every_core_ ? static_cast<int>(std::max(1u, std::thread::hardware_concurrency())) : 1;
  std::vector<rekon_msgs::mesh_blocks_t> msgs = encodeMeshBlocks(meshes, codec_, ++sequence_, full_snapshot, threads);
  int64_t bytes = 0;
  for (const rekon_msgs::mesh_blocks_t& m : msgs) bytes += m.getEncodedSize();
  ++stats_.updates;
  stats_.messages += static_cast<int64_t>(msgs.size());
  send(std::move(msgs));
  last_update_ = Clock::now();
  (coarse ? stats_.coarse_sent : stats_.blocks_sent) += static_cast<int64_t>(meshes.size());
  stats_.bytes += bytes;
  return bytes;
}

void MeshPublisher::send(std::vector<rekon_msgs::mesh_blocks_t> msgs) {
  auto send_all = [this](const std::vector<rekon_msgs::mesh_blocks_t>& parts) {
    for (size_t i = 0; i < parts.size(); ++i) {
      // A pause between parts: one part nearly fills a receiver's default UDP
      // buffer (208 KB), and a subscriber inflating the last one must keep up.
      if (i > 0) std::this_thread::sleep_for(kPartGap);
      ctx_.bus().publish(channel::kMeshBlocks, parts[i]);
    }
  };
  waitUntilSent();  // updates go out in order
  if (!send_behind_) return send_all(msgs);
  last_sender_ = std::thread([send_all, parts = std::move(msgs)] { send_all(parts); });
}

void MeshPublisher::waitUntilSent() {
  if (last_sender_.joinable()) last_sender_.join();
}

std::vector<BlockMesh> MeshPublisher::coarseMeshes(const Mapper& mapper, const std::vector<volume::BlockCoord>& wanted) const {
  // The wanted blocks that exist, then their +x/+y/+z neighbours (the cubes reach into their first layer).
  const volume::TsdfVolume& volume = mapper.volume();
  std::vector<volume::BlockCoord> coords;
  std::vector<std::vector<volume::Voxel>> voxels;
  std::unordered_map<volume::BlockCoord, bool, CoordHash> exists;  // every block tried
  auto read = [&](const volume::BlockCoord& c) {
    const auto [it, fresh] = exists.try_emplace(c, false);
    if (!fresh) return;
    std::vector<volume::Voxel> v;
    if (!volume.readBlock(c, v)) return;
    it->second = true;
    coords.push_back(c);
    voxels.push_back(std::move(v));
  };
  for (const volume::BlockCoord& c : wanted) read(c);
  const size_t present = coords.size();
  for (size_t i = 0; i < present; ++i) {
    const volume::BlockCoord c = coords[i];
    for (int n = 1; n < 8; ++n) read({c.x + (n & 1), c.y + ((n >> 1) & 1), c.z + ((n >> 2) & 1)});
  }
  std::vector<const volume::Voxel*> data;
  data.reserve(voxels.size());
  for (const auto& v : voxels) data.push_back(v.data());
  const volume::VolumeParams& p = volume.params();
  std::vector<BlockMesh> meshes = volume::marchingCubesCoarse(coords, data, static_cast<int>(present),
                                                              static_cast<float>(p.voxel_size), static_cast<float>(p.truncation));
  for (const volume::BlockCoord& c : wanted) {  // not allocated (freed): nothing to show
    if (!exists.at(c)) meshes.push_back(BlockMesh{c.x, c.y, c.z, 0, {}, {}, {}});
  }
  return meshes;
}

}  // namespace rekon::mapper
