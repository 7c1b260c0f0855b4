#include "rekon/viewer/viewer_state.hpp"

#include <fmt/format.h>

#include "rekon/common/json.hpp"
#include "rekon/viewer/protocol.hpp"

namespace rekon::viewer {
namespace {

std::shared_ptr<const std::string> shared(std::string s) { return std::make_shared<const std::string>(std::move(s)); }

Update text(const std::string& type, std::string json) { return {type, shared(std::move(json)), false}; }

// "[tx,ty,tz,qx,qy,qz,qw]": 0.1 mm and 1e-6 in the quaternion are below what the page can show.
std::string poseJson(const Pose& p) {
  const Eigen::Vector3d t = p.translation();
  const Eigen::Quaterniond q(p.rotation());
  return fmt::format("[{:.4f},{:.4f},{:.4f},{:.6f},{:.6f},{:.6f},{:.6f}]", t.x(), t.y(), t.z(), q.x(), q.y(), q.z(),
                     q.w());
}

// The sum of every vertex coordinate of a block, as the page sums its float32 copies.
double positionSum(const BlockMesh& block) {
  double sum = 0;
  for (const Eigen::Vector3f& v : block.vertices) sum += static_cast<double>(v.x()) + v.y() + v.z();
  return sum;
}

}  // namespace

void ViewerState::setListener(std::function<void(const Update&)> f) {
  std::lock_guard<std::mutex> lock(mutex_);
  listener_ = std::move(f);
}

void ViewerState::emit(const Update& u) const {
  if (listener_) listener_(u);
}

void ViewerState::applyBlocks(const std::vector<BlockMesh>& blocks) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const BlockMesh& b : blocks) applyLocked(b);
}

void ViewerState::applyLocked(const BlockMesh& block) {
  const BlockKey key{block.x, block.y, block.z};
  if (unconfirmed_) unconfirmed_->erase(key);
  auto& entry = blocks_[key];
  const bool known = entry.second || entry.first != 0;  // held, or removed at entry.first
  if (known && entry.first >= block.version) return;
  const bool coarse = isCoarse(block.version);
  coarse_blocks_ -= (entry.second && isCoarse(entry.first)) ? 1 : 0;
  coarse_blocks_ += (coarse && !block.vertices.empty()) ? 1 : 0;
  BlockSize& size = block_sizes_[key];
  vertices_ -= size.vertices;
  triangles_ -= size.triangles;
  position_sum_ -= size.position_sum;
  size = {block.vertices.size(), block.triangles.size(), positionSum(block)};
  vertices_ += size.vertices;
  triangles_ += size.triangles;
  position_sum_ += size.position_sum;
  ++block_updates_;
  // A coarse mesh's full one follows with the same cause: counted once, then.
  if (!coarse && block.cause == BlockCause::kCorrection) ++block_corrections_;
  if (!coarse && block.cause == BlockCause::kFinalPass) ++final_pass_blocks_;
  if (!unconfirmed_ && block.version >= kMinTimeVersion) {
    const auto now_us = std::chrono::duration_cast<std::chrono::microseconds>(
        std::chrono::system_clock::now().time_since_epoch()).count();
    receive_latency_.add(static_cast<double>(now_us - block.version) / 1000.0);
  }
  mesh_map_.apply(std::vector<BlockMesh>{block});
  auto message = shared(encodeBlockMessage(block));
  shown_blocks_ -= entry.second ? 1 : 0;
  entry = {block.version, size.vertices == 0 ? nullptr : message};
  shown_blocks_ += entry.second ? 1 : 0;
  emit({blockUpdateKey(key), message, true});
}

void ViewerState::startFullSnapshot() {
  std::lock_guard<std::mutex> lock(mutex_);
  unconfirmed_.emplace();
  for (const auto& [key, entry] : blocks_) {
    if (entry.second) unconfirmed_->insert(key);
  }
}

void ViewerState::endFullSnapshot() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!unconfirmed_) return;
  const std::set<BlockKey> gone = std::move(*unconfirmed_);
  unconfirmed_.reset();
  for (const BlockKey& k : gone) {
    BlockMesh removal;
    removal.x = k.x;
    removal.y = k.y;
    removal.z = k.z;
    removal.version = blocks_[k].first + 1;  // the mapper no longer has it: newer than what is held
    applyLocked(removal);
  }
}

void ViewerState::addKeyframe(int64_t id, const Pose& world) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!keyframes_.emplace(id, world).second) return;  // a keyframe sent again (recovery) keeps its graph pose
  emit(keyframesUpdate());
}

void ViewerState::applyGraph(const std::vector<std::pair<int64_t, Pose>>& poses) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [id, pose] : poses) keyframes_[id] = pose;
  if (camera_) {
    // The camera moves with its keyframe: re-place it through the newest tracked frame.
    for (auto it = trajectory_.rbegin(); it != trajectory_.rend(); ++it) {
      if (it->frame_id != camera_->frame_id) continue;
      if (auto kf = keyframes_.find(it->keyframe_id); kf != keyframes_.end()) camera_->world = kf->second * it->in_keyframe;
      break;
    }
  }
  emit(keyframesUpdate());
  emit(edgesUpdate());
  emit(trajectoryUpdate());
  if (auto c = cameraUpdate()) emit(*c);
}

void ViewerState::addTrackedFrame(int64_t frame_id, int64_t keyframe_id, const Pose& in_keyframe, bool lost) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto kf = keyframes_.find(keyframe_id);
  if (kf == keyframes_.end()) return;
  if (!lost) {
    trajectory_.push_back({frame_id, keyframe_id, in_keyframe});
    if (trajectory_.size() > kMaxTrajectory) {
      std::vector<TrackedFrame> thinned;
      for (size_t i = 0; i < trajectory_.size(); i += 2) thinned.push_back(trajectory_[i]);
      if (thinned.back().frame_id != frame_id) thinned.push_back(trajectory_.back());
      trajectory_ = std::move(thinned);
    }
  }
  camera_ = Camera{frame_id, kf->second * in_keyframe, lost};
  if (auto c = cameraUpdate()) emit(*c);
}

void ViewerState::addLoopEdge(int64_t from_id, int64_t to_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  loop_edges_.emplace_back(from_id, to_id);
  emit(edgesUpdate());
}

void ViewerState::heartbeat(const std::string& service, int pid, const std::string& host, const std::string& state,
                            int64_t last_frame) {
  std::lock_guard<std::mutex> lock(mutex_);
  Service& s = services_[service];
  if (pid != s.pid && s.pids.count(pid)) return;  // a replaced instance's last words
  s.pids.insert(pid);
  const auto now = std::chrono::steady_clock::now();
  if (s.pid != pid || s.rate_frame < 0 || last_frame < s.rate_frame) {
    s.rate_since = now;  // a new instance, or the first heartbeat: the rate starts again
    s.rate_frame = last_frame;
    s.frames_per_s = 0;
  } else if (const double dt = std::chrono::duration<double>(now - s.rate_since).count(); dt >= kRateWindowS) {
    s.frames_per_s = static_cast<double>(last_frame - s.rate_frame) / dt;
    s.rate_since = now;
    s.rate_frame = last_frame;
  }
  if (state == "exited") s.frames_per_s = 0;  // its last heartbeat: no rate any more
  s.pid = pid;
  s.host = host;
  s.state = state;
  s.last_frame = last_frame;
  s.last_heartbeat = now;
  emit(statusUpdate());
}

void ViewerState::markSilent(double silence_s) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto now = std::chrono::steady_clock::now();
  bool changed = false;
  for (auto& [name, s] : services_) {
    if (s.pid == 0 || s.state == "exited" || s.state == "silent") continue;  // stats only, or already marked
    if (std::chrono::duration<double>(now - s.last_heartbeat).count() <= silence_s) continue;
    const bool ending = s.state == "finishing" || s.state == "finished" || s.state == "lingering";
    s.state = ending ? "exited" : "silent";
    s.frames_per_s = 0;
    changed = true;
  }
  if (changed) emit(statusUpdate());
}

void ViewerState::stats(const std::string& service, const std::string& json) {
  std::lock_guard<std::mutex> lock(mutex_);
  services_[service].stats_json = json;
  emit(statusUpdate());
}

Update ViewerState::keyframesUpdate() const {
  std::string json = R"({"type":"keyframes","keyframes":[)";
  bool first = true;
  for (const auto& [id, pose] : keyframes_) {
    json += fmt::format(R"({}{{"id":{},"pose":{}}})", first ? "" : ",", id, poseJson(pose));
    first = false;
  }
  return text("keyframes", json + "]}");
}

Update ViewerState::edgesUpdate() const {
  std::string json = R"({"type":"edges","edges":[)";
  for (size_t i = 0; i < loop_edges_.size(); ++i) {
    json += fmt::format("{}[{},{}]", i ? "," : "", loop_edges_[i].first, loop_edges_[i].second);
  }
  return text("edges", json + "]}");
}

Update ViewerState::trajectoryUpdate() const {
  std::string json = R"({"type":"trajectory","points":[)";
  bool first = true;
  for (const TrackedFrame& f : trajectory_) {
    const auto kf = keyframes_.find(f.keyframe_id);
    if (kf == keyframes_.end()) continue;
    const Eigen::Vector3d p = (kf->second * f.in_keyframe).translation();
    json += fmt::format("{}{:.4f},{:.4f},{:.4f}", first ? "" : ",", p.x(), p.y(), p.z());
    first = false;
  }
  return text("trajectory", json + "]}");
}

Update ViewerState::statusUpdate() const {
  std::string json = R"({"type":"status","services":{)";
  bool first = true;
  for (const auto& [name, s] : services_) {
    const size_t restarts = s.pids.empty() ? 0 : s.pids.size() - 1;
    json += fmt::format(
        R"({}{}:{{"pid":{},"host":{},"state":{},"last_frame":{},"frames_per_s":{:.1f},"restarts":{},"stats":{}}})",
        first ? "" : ",", jsonString(name), s.pid, jsonString(s.host), jsonString(s.state), s.last_frame,
        s.frames_per_s, restarts, jsonString(s.stats_json));
    first = false;
  }
  return text("status", json + "}}");
}

std::optional<Update> ViewerState::cameraUpdate() const {
  if (!camera_) return std::nullopt;
  return text("camera", fmt::format(R"({{"type":"camera","frame":{},"pose":{},"lost":{}}})", camera_->frame_id,
                                    poseJson(camera_->world), camera_->lost ? "true" : "false"));
}

std::vector<Update> ViewerState::snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<Update> out = {statusUpdate(), keyframesUpdate(), edgesUpdate(), trajectoryUpdate()};
  if (auto c = cameraUpdate()) out.push_back(*c);
  for (const auto& [key, entry] : blocks_) {
    if (entry.second) out.push_back({blockUpdateKey(key), entry.second, true});
  }
  return out;
}

Mesh ViewerState::mesh() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return mesh_map_.toMesh();
}

ViewerState::Counts ViewerState::counts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  Counts c;
  c.blocks = shown_blocks_;  // counted as they change: the service reads it 10 times a second
  c.vertices = vertices_;
  c.triangles = triangles_;
  c.position_sum = position_sum_;
  c.keyframes = keyframes_.size();
  c.loop_edges = loop_edges_.size();
  c.trajectory = trajectory_.size();
  c.block_updates = block_updates_;
  c.block_corrections = block_corrections_;
  c.final_pass_blocks = final_pass_blocks_;
  c.coarse_blocks = coarse_blocks_;
  c.receive_latency_samples = receive_latency_.count();
  if (c.receive_latency_samples > 0) {
    c.receive_latency_ms_p50 = receive_latency_.quantile(0.5);
    c.receive_latency_ms_p95 = receive_latency_.quantile(0.95);
  }
  c.camera_frame = camera_ ? camera_->frame_id : -1;
  return c;
}

std::string ViewerState::stateJson() const {
  const Counts c = counts();
  std::string status;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    status = *statusUpdate().payload;
  }
  return fmt::format(R"({{"blocks":{},"vertices":{},"triangles":{},"block_updates":{},"block_corrections":{},)"
                     R"("final_pass_blocks":{},"coarse_blocks":{},"keyframes":{},)"
                     R"("loop_edges":{},"trajectory":{},"camera_frame":{},"receive_latency_samples":{},)"
                     R"("receive_latency_ms_p50":{},"receive_latency_ms_p95":{},"position_sum":{:.6f},"status":{}}})",
                     c.blocks, c.vertices, c.triangles, c.block_updates, c.block_corrections, c.final_pass_blocks, c.coarse_blocks,
                     c.keyframes, c.loop_edges, c.trajectory,
                     c.camera_frame, c.receive_latency_samples, c.receive_latency_ms_p50, c.receive_latency_ms_p95,
                     c.position_sum, status);
}

}  // namespace rekon::viewer
