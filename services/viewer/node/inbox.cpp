#include "inbox.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <memory>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/messages.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/mesh_blocks_t.hpp"
#include "rekon_msgs/mesh_request_t.hpp"
#include "rekon_msgs/service_stats_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace rekon::viewer {
namespace {

void subscribePoses(Bus& bus, ViewerState& state) {
  bus.subscribe<rekon_msgs::keyframe_t>(channel::kKeyframes, [&state](const rekon_msgs::keyframe_t& m) {
    if (const auto pose = fromMsg(m.pose_world)) state.addKeyframe(m.keyframe_id, *pose);
    else spdlog::warn("viewer: keyframe {} has an invalid pose; not shown", m.keyframe_id);
  });
  bus.subscribe<rekon_msgs::tracked_frame_t>(channel::kTrackedFrames, [&state](const rekon_msgs::tracked_frame_t& m) {
    if (const auto pose = fromMsg(m.pose_in_keyframe)) {
      state.addTrackedFrame(m.frame_id, m.keyframe_id, *pose, m.state == rekon_msgs::tracked_frame_t::STATE_LOST);
    }
  });
  auto filter = std::make_shared<GraphUpdateFilter>();
  bus.subscribe<rekon_msgs::graph_update_t>(channel::kGraphUpdates, [&state, filter](const rekon_msgs::graph_update_t& m) {
    if (!filter->accept(m.version)) return;
    try {
      state.applyGraph(graphPoses(m));
    } catch (const Error& e) {
      spdlog::warn("viewer: {}", e.what());
    }
  });
  bus.subscribe<rekon_msgs::constraint_t>(channel::kConstraints, [&state](const rekon_msgs::constraint_t& m) {
    if (m.kind == rekon_msgs::constraint_t::KIND_LOOP) state.addLoopEdge(m.from_id, m.to_id);
  });
}

// The viewer's ask for the whole mesh, until a snapshot answers it: the
// mapper publishes only once asked (mapper.mesh_publish_unasked false, the
// default), and an ask can be lost (dropped by UDP).
// Touched only by the bus thread's handlers.
struct MeshAsk {
  static constexpr std::chrono::seconds kAgainAfter{2};
  std::string service;
  int mapper_pid = 0;
  bool answered = false;
  std::chrono::steady_clock::time_point last{};

  void send(Bus& bus) {
    rekon_msgs::mesh_request_t r{};
    r.requester = service;
    bus.publish(channel::kMeshRequest, r);
    last = std::chrono::steady_clock::now();
  }
};

// A full snapshot's first part starts it, its last part ends it (blocks it
// lacks are then removed); parts lost on the way only delay that.
void subscribeMesh(Bus& bus, ViewerState& state, const std::shared_ptr<MeshAsk>& ask) {
  bus.subscribe<rekon_msgs::mesh_blocks_t>(channel::kMeshBlocks, [&state, ask](const rekon_msgs::mesh_blocks_t& m) {
    if (m.full) ask->answered = true;
    std::vector<BlockMesh> blocks;
    try {
      blocks = decodeMeshBlocks(m);
    } catch (const Error& e) {
      spdlog::warn("viewer: {}", e.what());
      return;
    }
    if (m.full && m.part == 0) state.startFullSnapshot();
    state.applyBlocks(blocks);
    if (m.full && m.part == m.parts - 1) state.endFullSnapshot();
  });
}

void subscribeStatus(Bus& bus, ViewerState& state, const std::shared_ptr<MeshAsk>& ask) {
  // A mapper seen under a new pid (started after this viewer, or restarted)
  // is asked for its whole mesh, as is the one running when the viewer
  // starts: once it is past "starting" (before that it has not subscribed
  // and the ask would be lost; its heartbeat comes at once when its state
  // changes), and again at its heartbeats until a snapshot comes.
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&bus, &state, ask](const rekon_msgs::heartbeat_t& m) {
    state.heartbeat(m.service, m.pid, m.host, m.state, m.last_frame_id);
    if (m.service != "mapper") return;
    if (m.pid != ask->mapper_pid) {
      ask->mapper_pid = m.pid;
      ask->answered = false;
      ask->last = {};
    }
    if (!ask->answered && m.state != "starting" && std::chrono::steady_clock::now() - ask->last >= MeshAsk::kAgainAfter)
      ask->send(bus);
  });
  bus.subscribe<rekon_msgs::service_stats_t>(channel::kStats, [&state](const rekon_msgs::service_stats_t& m) {
    state.stats(m.service, m.json);
  });
}

}  // namespace

void subscribeViewer(Bus& bus, ViewerState& state, const std::string& service) {
  auto ask = std::make_shared<MeshAsk>();
  ask->service = service;
  subscribeMesh(bus, state, ask);
  subscribePoses(bus, state);
  subscribeStatus(bus, state, ask);
  ask->send(bus);  // a mapper already running sends everything it has
}

}  // namespace rekon::viewer
