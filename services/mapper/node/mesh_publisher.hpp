#pragma once
// The map on the bus (issue 17): after each piece of mapping work, the
// meshes of the voxel blocks that changed go out on MESH_BLOCKS, at most
// mapper.mesh_rate_hz times a second and within mapper.mesh_max_bytes_per_s
// (blocks not sent stay pending; their newest mesh goes out later). A
// MESH_REQUEST (a viewer started late) or mapper.mesh_full_every_s brings a
// full snapshot. Runs on the mapping worker's thread (it meshes the live
// volume), except the request handler, which only raises a flag.
//
// What goes first (issue 27): when every pending block fits the update's
// budget in full, all go in full. Otherwise, with mapper.mesh_coarse_first,
//   1. blocks no subscriber has seen, as coarse meshes (half resolution,
//      about a quarter of the bytes), nearest the camera first;
//   2. then, with what the budget has left, full meshes of the blocks seen
//      before (shown coarse, or changed since), nearest the camera first.
// "The camera" is the newest integrated KF keyframe's current pose. A coarse
// mesh's version is one below the full mesh of the same change (versions of
// changes are even, coarse ones odd: messages/mesh.lcm), so the full mesh
// always replaces it, and finish() sends every block in full.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <thread>
#include <unordered_map>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"

namespace rekon::mapper {

struct MeshPublisherSettings {
  static constexpr double kDefaultRateHz = 2.0;
  static constexpr double kDefaultMaxBytesPerS = 5e5;
  static constexpr double kFullMinIntervalS = 1.0;  // requests from many viewers at once share one snapshot

  bool enabled = true;
  double rate_hz = kDefaultRateHz;
  double max_bytes_per_s = kDefaultMaxBytesPerS;
  size_t max_message_bytes = MeshBlocksParams::kDefaultMaxMessageBytes;
  double full_every_s = 0.0;  // 0: full snapshots only on request
  bool coarse_first = true;   // blocks never sent go first as coarse meshes when the budget is short
  // false: nothing is meshed or sent until a subscriber's MESH_REQUEST, which
  // the whole map then answers (a run nobody watches spends nothing on it).
  bool publish_unasked = true;

  // Throws rekon::Error naming a key out of range.
  static MeshPublisherSettings fromConfig(const Config& config);
};

struct MeshPublisherStats {
  int64_t updates = 0;  // updates published (each one or more messages)
  int64_t messages = 0;
  int64_t full_snapshots = 0;
  int64_t blocks_sent = 0;  // full meshes and removals
  int64_t coarse_sent = 0;  // coarse meshes (each followed by its block's full mesh later)
  int64_t bytes = 0;     // encoded LCM bytes
  double cpu_ms = 0.0;   // thread CPU time of change tracking, meshing, encoding, publishing
  int64_t pending = 0;   // blocks waiting for budget when the stats were taken
};

class MeshPublisher {
 public:
  MeshPublisher(ServiceContext& ctx, const MeshPublisherSettings& settings, const volume::VolumeParams& volume);
  ~MeshPublisher();
  MeshPublisher(const MeshPublisher&) = delete;
  MeshPublisher& operator=(const MeshPublisher&) = delete;
  // MESH_REQUEST: before the bus threads start.
  void subscribe();

  // On the mapping worker, after each piece of work and when idle: notes the
  // blocks that changed (`cause`: what that work was) and publishes when an
  // update (or a snapshot) is due.
  void tick(Mapper& mapper, BlockCause cause = BlockCause::kNewData);
  // Notes the blocks that changed since the last note, without publishing.
  void noteChanges(Mapper& mapper, BlockCause cause);
  // How long the worker may sleep before tick() has something to do.
  std::chrono::milliseconds idleWait() const;
  // After the final pass (`cause` of the changes not yet noted): every
  // pending block, regardless of rate and budget, so that a subscriber's map
  // equals mesh.ply. Meshed and encoded before it returns; its messages go
  // out on a thread of their own (their gaps are idle time: the caller
  // writes mesh.ply meanwhile) until waitUntilSent().
  void finish(Mapper& mapper, BlockCause cause);
  void waitUntilSent();

  const MeshPublisherStats& stats() const { return stats_; }
  bool enabled() const { return settings_.enabled; }

 private:
  using Clock = std::chrono::steady_clock;
  struct CoordHash {
    size_t operator()(const volume::BlockCoord& c) const { return volume::hashBlock(c); }
  };
  // Updates go out: from the start (publish_unasked), else once a subscriber asked.
  bool publishing() const { return settings_.publish_unasked || asked_; }
  void update(Mapper& mapper, BlockCause cause);
  void publishDelta(Mapper& mapper, bool unlimited);
  void publishFull(Mapper& mapper);
  // Pending blocks in the order they go (the rule above), as many as `tokens` bytes are expected to carry
  // (all when unlimited); those that go coarse in *coarse, the others in *full.
  void choose(const Mapper& mapper, bool unlimited, std::vector<volume::BlockCoord>* coarse,
              std::vector<volume::BlockCoord>* full) const;
  // Meshes coords (full, or coarse: those whose coarse mesh is empty are left
  // out, into *empty_coarse), stamps their versions, encodes and publishes one
  // update; returns its bytes.
  int64_t publish(Mapper& mapper, const std::vector<volume::BlockCoord>& coords, bool full_snapshot, bool coarse = false,
                  std::vector<volume::BlockCoord>* empty_coarse = nullptr);
  std::vector<BlockMesh> coarseMeshes(const Mapper& mapper, const std::vector<volume::BlockCoord>& coords) const;
  // One update's messages, kPartGap apart, after the previous update's; on
  // last_sender_ during finish(), else before it returns.
  void send(std::vector<rekon_msgs::mesh_blocks_t> msgs);

  ServiceContext& ctx_;
  MeshPublisherSettings settings_;
  MeshBlocksParams codec_;
  std::atomic<bool> full_requested_{false};
  std::atomic<bool> asked_{false};  // a MESH_REQUEST came (publish_unasked false: the updates start)
  struct Stamp {
    int64_t version = 0;  // even (newVersion); its coarse mesh goes as version - 1
    BlockCause cause = BlockCause::kNewData;
    bool seen = false;  // a version of it went out (or its coarse mesh was empty): no coarse mesh again
  };
  std::unordered_map<volume::BlockCoord, Stamp, CoordHash> version_;  // every block ever meshed or changed
  std::unordered_map<volume::BlockCoord, int64_t, CoordHash> pending_;  // changed, not yet sent: its version
  // Versions are the wall-clock microseconds of the change (strictly
  // growing): a viewer measures the latency from the change to its screen,
  // and a restarted mapper's blocks are newer than what viewers hold.
  int64_t newVersion();
  int64_t last_version_ = 0;
  int64_t sequence_ = 0;
  bool every_core_ = false;  // meshing and encoding on the calling thread only until finish()
  bool send_behind_ = false;  // during finish(): its messages go out on last_sender_
  std::thread last_sender_;
  double tokens_ = 0.0;  // bytes the budget allows now (negative after a large update)
  double bytes_per_block_ = 300.0;  // running estimates, to mesh only what the budget can send
  double bytes_per_coarse_block_ = 100.0;
  Clock::time_point last_refill_ = Clock::now();
  Clock::time_point last_update_ = Clock::time_point{};
  Clock::time_point last_full_ = Clock::time_point{};
  MeshPublisherStats stats_;
};

}  // namespace rekon::mapper
