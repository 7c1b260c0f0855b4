#include "outputs.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <thread>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/messages.hpp"
#include "rekon_msgs/done_t.hpp"

namespace rekon::mapper {

void writeUncorrectedMesh(const Mapper& mapper, const std::string& out_dir) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::string path = (std::filesystem::path(out_dir) / "mesh_uncorrected.ply").string();
  const int64_t most = mapper.params().uncorrected_mesh_max_keyframes;
  if (most > 0 && static_cast<int64_t>(mapper.keyframes().size()) > most) {
    spdlog::info("{} not written: {} KF keyframes, more than mapper.uncorrected_mesh_max_keyframes ({}) would "
                 "integrate again (raise it to have it)", path, mapper.keyframes().size(), most);
    return;
  }
  PlyWriter ply(path, true);
  mapper.extractUncorrectedMeshInPieces([&ply](const Mesh& piece) { ply.add(piece); });
  ply.finish();
  spdlog::info("wrote {} ({} vertices, {:.1f} s: every KF keyframe at its first pose)", path, ply.vertices(),
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
}

void writeMesh(const Mapper& mapper, const std::string& out_dir) {
  const std::string path = (std::filesystem::path(out_dir) / "mesh.ply").string();
  PlyWriter ply(path, true);  // in pieces: neither the mesh nor the blocks on disk are held at once
  mapper.extractMeshInPieces([&ply](const Mesh& piece) { ply.add(piece); });
  ply.finish();
  spdlog::info("wrote {} ({} vertices)", path, ply.vertices());
}

void TimingTables::add(const FrameTiming& r) {
  if (dir_.empty()) return;
  if (!frames_)
    frames_.emplace((std::filesystem::path(dir_) / "mapper_timing.csv").string(), "frame_id,ms,fuse_ms,integrate_ms", append_);
  frames_->row(r.frame_id, r.ms, r.fuse_ms, r.integrate_ms);
}

void TimingTables::add(const RoundRecord& r) {
  if (dir_.empty()) return;
  if (!rounds_)
    rounds_.emplace((std::filesystem::path(dir_) / "mapper_reintegration.csv").string(),
                    "time_s,graph_version,keyframes_reintegrated,ms,blocks_streamed,final_pass,frames_fused,piece",
                    append_);
  rounds_->row(r.time_s, r.graph_version, r.round.keyframes, r.round.ms, r.round.blocks_streamed,
               r.kind == RoundKind::kFinalPass ? 1 : 0, r.frames_fused, r.kind == RoundKind::kPiece ? 1 : 0);
}

void publishDone(ServiceContext& ctx, int64_t last_frame_id) {
  const rekon_msgs::done_t done = doneMessage(ctx.name(), last_frame_id);
  for (int i = 0; i < 3; ++i) {  // UDP multicast may drop one
    ctx.bus().publish(channel::kDone, done);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

namespace {

// The map on the bus; its CPU share is of the whole mapper process so far.
void recordMeshStats(ServiceContext& ctx, const MeshPublisherStats& mesh) {
  const double process_ms = processCpuMs();
  ctx.stats()
      .set("mesh_updates", static_cast<long long>(mesh.updates))
      .set("mesh_messages", static_cast<long long>(mesh.messages))
      .set("mesh_full_snapshots", static_cast<long long>(mesh.full_snapshots))
      .set("mesh_blocks_sent", static_cast<long long>(mesh.blocks_sent))
      .set("mesh_bytes", static_cast<long long>(mesh.bytes))
      .set("mesh_pending_blocks", static_cast<long long>(mesh.pending))
      .set("mesh_cpu_ms", mesh.cpu_ms)
      .set("mesh_cpu_share", process_ms > 0.0 ? mesh.cpu_ms / process_ms : 0.0);
}

}  // namespace

void recordStats(ServiceContext& ctx, const Mapper& mapper, const MapperParams& params, const InboxCounts& inbox,
                 const MeshPublisherStats& mesh) {
  const MapperCounters& c = mapper.counters();
  const volume::VolumeStats vs = mapper.volume().stats();
  const MemoryUse mem = mapper.memoryUse();
  const double n_frames = static_cast<double>(std::max<int64_t>(1, c.frames + c.skipped_frames));
  ctx.stats()
      .set("frames_fused", static_cast<long long>(c.frames))
      .set("frames_skipped", static_cast<long long>(c.skipped_frames))
      .set("frames_dropped", static_cast<long long>(inbox.dropped_frames))
      .set("frames_dropped_when_full", static_cast<long long>(inbox.dropped_when_full))
      .set("frames_received_again", static_cast<long long>(inbox.frames_received_again))
      .set("frames_before_resume", static_cast<long long>(inbox.frames_before_resume))
      .set("kf_keyframes", static_cast<long long>(c.kf_keyframes))
      .set("integrations", static_cast<long long>(c.integrations))
      .set("deintegrations", static_cast<long long>(c.deintegrations))
      .set("reintegrations", static_cast<long long>(c.reintegrations))
      .set("final_pass_reintegrations", static_cast<long long>(c.final_pass_reintegrations))
      .set("graph_updates", static_cast<long long>(c.graph_updates))
      .set("graph_updates_coalesced", static_cast<long long>(inbox.coalesced_updates))
      .set("restored_keyframes", static_cast<long long>(c.restored_keyframes))
      .set("rebuilt_keyframes", static_cast<long long>(c.rebuilt_keyframes))
      .set("integrate_ms_mean", c.integrate_ms_total / static_cast<double>(std::max<int64_t>(1, c.integrations + c.reintegrations)))
      .set("voxel_blocks", static_cast<long long>(vs.blocks))
      .set("bytes_per_voxel", vs.bytes_per_voxel)
      .set("active_blocks_peak", static_cast<long long>(vs.peak_active_blocks))
      .set("streamed_out", static_cast<long long>(vs.streamed_out))
      .set("streamed_in", static_cast<long long>(vs.streamed_in))
      .set("fuse_ms_per_frame", c.fuse_ms_total / n_frames)
      .set("integration_ms_per_frame", c.first_integration_ms_total / n_frames)
      .set("reintegration_ms_per_frame", c.reintegration_ms_total / n_frames)
      .set("final_pass_ms", c.final_pass_ms_total)
      .set("reintegration_blocks_streamed", static_cast<long long>(c.reintegration_blocks_streamed))
      .set("input_frame_bytes", static_cast<long long>(mem.input_frame_bytes))
      .set("keyframe_bytes", static_cast<long long>(mem.keyframe_bytes))
      .set("keyframe_bytes_in_mapper", static_cast<long long>(mem.keyframe_bytes_in_mapper))
      .set("keyframe_over_input_bytes",
           static_cast<double>(mem.keyframe_bytes) / static_cast<double>(std::max<int64_t>(1, mem.input_frame_bytes)))
      .set("voxel_bytes", static_cast<long long>(mem.voxel_bytes))
      .set("active_voxel_bytes_peak", static_cast<long long>(mem.active_voxel_bytes_peak))
      .set("active_voxel_bytes", static_cast<long long>(mem.active_voxel_bytes))
      .set("host_voxel_bytes_in_memory", static_cast<long long>(mem.host_voxel_bytes_in_memory))
      .set("voxel_bytes_on_disk", static_cast<long long>(mem.voxel_bytes_on_disk))
      .set("voxel_blocks_spilled_to_disk", static_cast<long long>(vs.spilled_to_disk))
      .set("voxel_blocks_read_back_from_disk", static_cast<long long>(vs.read_back_from_disk))
      .set("reintegration", toString(params.mode))
      .set("m", params.m)
      .set("kappa", params.fusion.kappa);
  recordMeshStats(ctx, mesh);
  if (mem.keyframe_store_bytes >= 0) ctx.stats().set("keyframe_store_bytes", static_cast<long long>(mem.keyframe_store_bytes));
  spdlog::info("mapper: {} frames into {} KF keyframes; {} re-integrations ({} in the final pass); {} blocks",
               c.frames, c.kf_keyframes, c.reintegrations, c.final_pass_reintegrations, vs.blocks);
}

}  // namespace rekon::mapper
