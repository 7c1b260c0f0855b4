#include "mesh_publisher.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <string>
#include <thread>
#include <tuple>

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

}  // namespace

MeshPublisherSettings MeshPublisherSettings::fromConfig(const Config& config) {
  MeshPublisherSettings s;
  s.enabled = config.getBool("mapper.mesh_publish");
  s.rate_hz = config.getDouble("mapper.mesh_rate_hz");
  s.max_bytes_per_s = config.getDouble("mapper.mesh_max_bytes_per_s");
  const int max_message = config.getInt("mapper.mesh_max_message_bytes");
  s.full_every_s = config.getDouble("mapper.mesh_full_every_s");
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

void MeshPublisher::subscribe() {
  if (!settings_.enabled) return;
  ctx_.bus().subscribe<rekon_msgs::mesh_request_t>(channel::kMeshRequest, [this](const rekon_msgs::mesh_request_t& m) {
    spdlog::info("mapper: {} asks for the whole mesh", m.requester.empty() ? std::string("a subscriber") : m.requester);
    full_requested_ = true;
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
  const double cpu0 = threadCpuMs();
  try {
    noteChanges(mapper, cause);
    if (full_requested_) {
      publishFull(mapper);
    } else {
      publishDelta(mapper, true);
    }
  } catch (const Error& e) {
    spdlog::error("mapper: the last mesh update failed: {}", e.what());
  }
  stats_.cpu_ms += threadCpuMs() - cpu0;
  spdlog::info("mapper: mesh on the bus: {} updates ({} full), {} blocks, {:.1f} MB, {:.0f} ms CPU", stats_.updates,
               stats_.full_snapshots, stats_.blocks_sent, static_cast<double>(stats_.bytes) / 1e6, stats_.cpu_ms);
}

int64_t MeshPublisher::newVersion() {
  last_version_ = std::max(last_version_ + 1, wallMicros());
  return last_version_;
}

void MeshPublisher::noteChanges(Mapper& mapper, BlockCause cause) {
  if (!settings_.enabled) return;
  const std::vector<volume::BlockCoord> changed = mapper.takeMeshChanges();
  if (changed.empty()) return;
  const int64_t version = newVersion();
  for (const volume::BlockCoord& c : changed) {
    Stamp& stamp = version_[c];
    // A correction not sent yet stays one when new data lands on the block too.
    const bool unsent = pending_.count(c) > 0;
    stamp = {version, unsent ? std::max(stamp.cause, cause) : cause};
    pending_[c] = version;
  }
  stats_.pending = static_cast<int64_t>(pending_.size());
}

// The oldest pending blocks first, as many as the budget is expected to carry.
void MeshPublisher::publishDelta(Mapper& mapper, bool unlimited) {
  const Clock::time_point now = Clock::now();
  const double elapsed = std::chrono::duration<double>(now - last_refill_).count();
  last_refill_ = now;
  tokens_ = std::min(tokens_ + elapsed * settings_.max_bytes_per_s, settings_.max_bytes_per_s);
  if (pending_.empty() || (!unlimited && tokens_ <= 0.0)) return;
  std::vector<std::pair<int64_t, volume::BlockCoord>> order;
  order.reserve(pending_.size());
  for (const auto& [coord, version] : pending_) order.emplace_back(version, coord);
  size_t n = order.size();
  if (!unlimited) n = std::min(n, static_cast<size_t>(std::max(1.0, tokens_ / bytes_per_block_)));
  // Oldest first, and within a version by coordinates: neighbouring blocks
  // go together, so meshing them computes few vertices of blocks not sent.
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(n), order.end(), [](const auto& a, const auto& b) {
    return std::tie(a.first, a.second.x, a.second.y, a.second.z) < std::tie(b.first, b.second.x, b.second.y, b.second.z);
  });
  std::vector<volume::BlockCoord> coords;
  coords.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    coords.push_back(order[i].second);
    pending_.erase(order[i].second);
  }
  const int64_t bytes = publish(mapper, coords, false);
  tokens_ -= static_cast<double>(bytes);
  if (!coords.empty()) bytes_per_block_ = 0.8 * bytes_per_block_ + 0.2 * static_cast<double>(bytes) / static_cast<double>(coords.size());
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

int64_t MeshPublisher::publish(Mapper& mapper, const std::vector<volume::BlockCoord>& coords, bool full) {
  std::vector<BlockMesh> meshes = mapper.volume().meshBlocks(coords);
  for (BlockMesh& m : meshes) {
    const Stamp& stamp = version_.at({m.x, m.y, m.z});
    m.version = stamp.version;
    m.cause = stamp.cause;
  }
  const std::vector<rekon_msgs::mesh_blocks_t> msgs = encodeMeshBlocks(meshes, codec_, ++sequence_, full);
  int64_t bytes = 0;
  for (size_t i = 0; i < msgs.size(); ++i) {
    // A pause between parts: one part nearly fills a receiver's default UDP
    // buffer (208 KB), and a subscriber inflating the last one must keep up.
    if (i > 0) std::this_thread::sleep_for(kPartGap);
    ctx_.bus().publish(channel::kMeshBlocks, msgs[i]);
    bytes += msgs[i].getEncodedSize();
  }
  last_update_ = Clock::now();
  ++stats_.updates;
  stats_.messages += static_cast<int64_t>(msgs.size());
  stats_.blocks_sent += static_cast<int64_t>(meshes.size());
  stats_.bytes += bytes;
  return bytes;
}

}  // namespace rekon::mapper
