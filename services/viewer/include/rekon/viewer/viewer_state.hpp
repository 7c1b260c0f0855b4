#pragma once
// What the viewer knows of a run, from the bus but in plain types: the newest
// mesh of every voxel block (world coordinates), the camera, its trajectory,
// the DVO keyframes as the newest graph update places them, loop-closure edges
// and every service's status. Each change becomes an Update for the browsers:
// a message with a coalescing key, so a client that is behind keeps only the
// newest message per key (a block updated five times is sent once).
#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "rekon/common/latency_histogram.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/pose.hpp"

namespace rekon::viewer {

struct BlockKey {
  int32_t x = 0, y = 0, z = 0;
  auto operator<=>(const BlockKey&) const = default;
};

// One message to the browsers: binary (a block, protocol.hpp) or JSON text.
// A newer Update with the same key replaces an unsent older one.
struct Update {
  std::string key;  // "b X Y Z" for a block, else the JSON message's type
  std::shared_ptr<const std::string> payload;
  bool binary = false;
};

class ViewerState {
 public:
  // More trajectory points than this are thinned (every second one dropped):
  // a long live session stays bounded, the path's shape stays.
  static constexpr size_t kMaxTrajectory = 20000;
  // A mapper's block versions are wall-clock microseconds of the change;
  // smaller ones (a test's 1, 2, 3) carry no time.
  static constexpr int64_t kMinTimeVersion = 1'000'000'000'000'000;
  // A coarse mesh (half resolution, sent first for a block no subscriber had):
  // an odd time version, one below its change's full mesh (messages/mesh.lcm).
  static bool isCoarse(int64_t version) { return version >= kMinTimeVersion && version % 2 != 0; }

  // `f` hears every Update, on the thread that caused it (the bus thread).
  void setListener(std::function<void(const Update&)> f);

  // A block's newer version replaces the old one; an older or equal one is
  // ignored; a block without vertices is removed (rekon::BlockMesh, as
  // decodeMeshBlocks gives it).
  void applyBlocks(const std::vector<BlockMesh>& blocks);
  void applyBlock(const BlockMesh& block) { applyBlocks({block}); }
  // A full snapshot from the mapper (every block it has) arrives between
  // these two; blocks it did not contain are then removed.
  void startFullSnapshot();
  void endFullSnapshot();
  void addKeyframe(int64_t id, const Pose& world);
  // Every keyframe's pose from a graph update (the caller filters old versions).
  void applyGraph(const std::vector<std::pair<int64_t, Pose>>& poses);
  // A tracked frame: placed through its keyframe's pose (skipped while that keyframe is unknown).
  void addTrackedFrame(int64_t frame_id, int64_t keyframe_id, const Pose& in_keyframe, bool lost);
  void addLoopEdge(int64_t from_id, int64_t to_id);
  // A heartbeat of a new pid is a restart of `service` (counted in the
  // status); a late one of an instance it replaced is ignored.
  void heartbeat(const std::string& service, int pid, const std::string& host, const std::string& state,
                 int64_t last_frame);
  // Services without a heartbeat for `silence_s` are shown as "exited"
  // (their last state was finishing, finished or lingering) or "silent".
  void markSilent(double silence_s);
  // `json`: the service's stats object as it sent it (the page parses it defensively).
  void stats(const std::string& service, const std::string& json);

  // Everything a newly connected browser needs, blocks last.
  std::vector<Update> snapshot() const;
  // The current surface (for /mesh.ply; shared vertices merged as MeshMap::toMesh does).
  Mesh mesh() const;

  struct Counts {
    size_t blocks = 0, vertices = 0, triangles = 0, keyframes = 0, loop_edges = 0, trajectory = 0;
    uint64_t block_updates = 0;  // block versions applied (removals and coarse meshes included)
    // Of those, the full meshes a graph update's re-integration made
    // (corrections) and the ones the final pass made: what the page highlights.
    uint64_t block_corrections = 0, final_pass_blocks = 0;
    size_t coarse_blocks = 0;  // blocks held as a coarse mesh (their full mesh has not come yet)
    // Every vertex coordinate of every block added up: the page adds up the
    // same, so equal sums mean it holds the same versions of the blocks.
    double position_sum = 0;
    // From a block's change in the mapper (its version: wall-clock us) to
    // its arrival here, for changes outside full snapshots.
    int64_t receive_latency_samples = 0;
    double receive_latency_ms_p50 = 0, receive_latency_ms_p95 = 0;
    int64_t camera_frame = -1;
  };
  Counts counts() const;
  // /state.json: the counts and every service's status.
  std::string stateJson() const;

 private:
  struct Service {
    int pid = 0;
    std::string host, state, stats_json;
    int64_t last_frame = -1;
    double frames_per_s = 0;  // from the last frames of heartbeats at least kRateWindowS apart
    std::chrono::steady_clock::time_point rate_since{}, last_heartbeat{};
    int64_t rate_frame = -1;
    std::set<int> pids;  // every instance seen: a restart adds one
  };
  static constexpr double kRateWindowS = 1.0;
  struct TrackedFrame {
    int64_t frame_id, keyframe_id;
    Pose in_keyframe;
  };
  struct Camera {
    int64_t frame_id;
    Pose world;
    bool lost;
  };

  void emit(const Update& u) const;
  void applyLocked(const BlockMesh& block);
  Update keyframesUpdate() const;
  Update edgesUpdate() const;
  Update trajectoryUpdate() const;
  Update statusUpdate() const;
  std::optional<Update> cameraUpdate() const;

  mutable std::mutex mutex_;
  std::function<void(const Update&)> listener_;
  std::map<BlockKey, std::pair<int64_t, std::shared_ptr<const std::string>>> blocks_;  // version, message
  struct BlockSize {
    size_t vertices = 0, triangles = 0;
    double position_sum = 0;
  };
  std::map<BlockKey, BlockSize> block_sizes_;
  size_t vertices_ = 0, triangles_ = 0, coarse_blocks_ = 0, shown_blocks_ = 0;  // shown: blocks_ with a message
  double position_sum_ = 0;
  MeshMap mesh_map_;  // the same blocks, for the PLY download
  std::optional<std::set<BlockKey>> unconfirmed_;  // during a full snapshot: held blocks it has not named yet
  uint64_t block_updates_ = 0, block_corrections_ = 0, final_pass_blocks_ = 0;
  LatencyHistogram receive_latency_;
  std::map<int64_t, Pose> keyframes_;
  std::vector<std::pair<int64_t, int64_t>> loop_edges_;
  std::vector<TrackedFrame> trajectory_;
  std::optional<Camera> camera_;
  std::map<std::string, Service> services_;
};

}  // namespace rekon::viewer
