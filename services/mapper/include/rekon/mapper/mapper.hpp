#pragma once
// The mapping core, free of the bus: frames with their tracked poses are
// fused into KF keyframes, KF keyframes are integrated into the TSDF volume,
// and every pose-graph update de-integrates and re-integrates the m keyframes
// chosen by the re-integration mode (paper sections 3-4). The node
// (node/mapper_service.cpp) feeds it from the bus on a worker thread; tests
// drive it directly.
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <vector>

#include "rekon/common/config.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/mapper/fusion/keyframe_fusion.hpp"
#include "rekon/mapper/reintegration.hpp"
#include "rekon/mapper/store/keyframe_store.hpp"
#include "rekon/mapper/store/session.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace rekon::mapper {

struct MapperParams {
  static constexpr int kDefaultM = 10;
  // Movements below this (in the units of ||s t - s t'||: radians x2 and
  // metres) are rounding, not corrections, and are never re-integrated.
  static constexpr double kDefaultMinMovement = 1e-6;

  fusion::FusionParams fusion;
  volume::VolumeParams volume;
  ReintegrationMode mode = ReintegrationMode::kConsecutive;
  int m = kDefaultM;
  double min_movement = kDefaultMinMovement;
  // mapper.near_window_slack: a consecutive window nearer the camera wins when
  // its movement is within this fraction of the largest (0: eq. 3 as is).
  double near_window_slack = 0.0;
  // mapper.round_budget_ms: 0 = a graph update's keyframes are corrected at
  // once (the paper's round); else they queue and are corrected one at a time
  // in the frames' spare time: on average at most this many ms per fused
  // frame, plus whatever time the mapper is idle (continueCorrection).
  double round_budget_ms = 0.0;
  // mapper.final_pass_s: 0 = the final pass corrects every KF keyframe that
  // still moved; else the most moved that fit this many seconds at the run's
  // mean re-integration time, and it stops once they are spent (an hour's scan
  // has thousands of KF keyframes; its end of run must not grow with them).
  double final_pass_s = 0.0;
  // mapper.uncorrected_mesh_max_keyframes: mesh_uncorrected.ply integrates
  // every KF keyframe again (39-64 ms each on the corridor), so a run with more
  // is not given it (0 = no limit).
  int64_t uncorrected_mesh_max_keyframes = 0;
  // The *_ms counters in CPU time of the whole process instead of wall time:
  // benchmarks on a shared machine, where other processes inflate wall time.
  bool cpu_time_counters = false;
  bool use_store = false;
  // With the store: continue from a store left by a stopped or crashed
  // mapper (true), or discard it as stale (false).
  bool resume = false;
  store::StoreOptions store;
  // session.dir: the session folder written as the run goes ("" = none;
  // store/session.hpp). With `resume` an existing one is written on.
  std::string session_dir;
  // session.continue: the session's KF keyframes are integrated at their
  // newest poses first, and the run extends that map (issue 18).
  bool continue_session = false;

  static MapperParams fromConfig(const Config& config);
};

struct MapperCounters {
  int64_t frames = 0;              // fused into KF keyframes
  int64_t skipped_frames = 0;      // lost, or their DVO keyframe's pose unknown
  int64_t kf_keyframes = 0;
  int64_t integrations = 0;        // first integrations of KF keyframes
  int64_t deintegrations = 0;
  int64_t reintegrations = 0;      // integrations with a corrected pose
  int64_t graph_updates = 0;
  int64_t final_pass_reintegrations = 0;
  int64_t restored_keyframes = 0;  // restored from the store at start (rebuilt into the volume as frames allow)
  int64_t rebuilt_keyframes = 0;   // of those, integrated into the volume so far
  int64_t input_frame_bytes = 0;   // depth + color of every frame handed to addFrame, as received
  double integrate_ms_total = 0.0;            // every integration, first and corrected
  double fuse_ms_total = 0.0;                 // keyframe fusion (depth and color) of all frames
  double first_integration_ms_total = 0.0;    // KF keyframes integrated when they close
  double reintegration_ms_total = 0.0;        // graph-update rounds: de-integration, re-integration, streaming
  double final_pass_ms_total = 0.0;
  int64_t reintegration_blocks_streamed = 0;  // blocks streamed in or out during graph-update rounds
  // The voxel tiers after the last piece of work (blocks now, not totals).
  int64_t active_blocks = 0, host_blocks_in_memory = 0, host_blocks_on_disk = 0;
};

// What one graph update (or one run of the final pass) cost.
struct ReintegrationRound {
  int keyframes = 0;  // KF keyframes de-integrated and re-integrated
  double ms = 0.0;    // wall time of the whole round
  int64_t blocks_streamed = 0;  // voxel blocks streamed in or out during it
};

// Bytes the mapper holds, for comparing keyframe fusion's memory with the input's.
struct MemoryUse {
  int64_t input_frame_bytes = 0;  // every frame as received (16-bit depth + 8-bit BGR)
  int64_t keyframe_bytes = 0;     // KF keyframes' images (float depth, float weight, BGR color), wherever kept
  int64_t keyframe_bytes_in_mapper = 0;  // of those, in the mapper's own memory (ImagesHome::kHere)
  int64_t keyframe_store_bytes = -1;  // used bytes of the shared-memory store; -1 without one
  int64_t voxel_bytes = 0;            // every allocated block, active and host
  int64_t active_voxel_bytes_peak = 0;
  int64_t active_voxel_bytes = 0, host_voxel_bytes_in_memory = 0, voxel_bytes_on_disk = 0;  // the tiers now
};

// Where a KF keyframe's images (depth, weight, color) are kept while the
// mapper is not using them: one copy, never two. With a store they live
// there (shared memory, spilled to disk by distance: bounded by
// mapper.store_mb); a continued session's in its files; only a mapper
// without either keeps them in its own memory.
enum class ImagesHome { kHere, kStore, kSession };

// One KF keyframe the mapper holds.
struct KeyframeRecord {
  // Metadata always; the images only while `home` is kHere (Mapper::images
  // reads them from wherever they are).
  fusion::FusedKeyframe kf;
  ImagesHome home = ImagesHome::kHere;
  size_t session_index = 0;  // home kSession: its index in the session
  bool integrated = false;
  Pose integrated_pose = Pose::Identity();
  // The pose of its first integration (never corrected): the uncorrected baseline.
  Pose first_pose = Pose::Identity();
};

class Mapper {
 public:
  // With params.use_store and params.resume, an existing store is opened and
  // its keyframes restored (a restart): each is integrated again, with the
  // pose it had, by continueRebuild, so that a restarted mapper fuses new
  // frames from its first moment instead of losing them while it rebuilds;
  // without resume an existing store is removed as stale. With
  // params.continue_session the session's keyframes are integrated instead
  // (a restarted mapper of a continued run finds its own there too).
  explicit Mapper(const MapperParams& params);
  ~Mapper();

  // A new DVO keyframe's odometry estimate (ignored once a graph update placed it).
  void setKeyframeEstimate(int64_t keyframe_id, const Pose& world);
  // Stores every keyframe's optimised pose; then re-integrates at most m KF keyframes.
  ReintegrationRound applyGraphUpdate(const std::vector<std::pair<int64_t, Pose>>& poses);
  // Fuses one tracked frame; false (and counted as skipped) when lost or its
  // DVO keyframe has no pose yet.
  bool addFrame(const RgbdFrame& frame, const Intrinsics& k, int64_t keyframe_id, const Pose& pose_in_keyframe,
                bool lost);
  // With mapper.round_budget_ms: keyframes of the last graph update not yet corrected.
  bool correctionPending() const { return !pending_.empty(); }
  // Corrects pending keyframes: one when `idle`, else as many as the credit
  // of round_budget_ms per fused frame pays for (a keyframe is never split).
  ReintegrationRound continueCorrection(bool idle);
  // Restored keyframes not yet integrated again (see the constructor).
  bool rebuildPending() const { return !rebuild_.empty(); }
  // Integrates restored keyframes again, in store order: one when `idle`, else
  // as many as the fused frames' credit (round_budget_ms) pays for. Returns how many.
  int continueRebuild(bool idle);
  // The rest of the rebuild at once (flush() and finish() begin with it).
  void completeRebuild();
  // Integrates the open KF keyframe, then re-integrates every keyframe whose
  // pose still differs from the one it was integrated with (the final pass,
  // in runs of m keyframes; one round each).
  std::vector<ReintegrationRound> finish();
  // Completes the rebuild and integrates the open KF keyframe (a stop before the end: no final pass).
  void flush();

  // The current world pose of a KF keyframe (its DVO keyframe's pose times its pose in it).
  std::optional<Pose> currentPose(const fusion::FusedKeyframe& kf) const;
  // Movement of every integrated KF keyframe since its integration, in keyframe order.
  std::vector<double> movements() const;
  // The KF keyframes the final pass corrects, in scan order (MapperParams::final_pass_s).
  std::vector<size_t> finalPassChoice() const;

  const MapperParams& params() const { return params_; }
  const volume::TsdfVolume& volume() const { return *volume_; }
  const std::vector<KeyframeRecord>& keyframes() const { return keyframes_; }
  // `rec` with its images, read back from the store or the session when they are not here.
  fusion::FusedKeyframe images(const KeyframeRecord& rec) const;
  // The frame after the newest one in a KF keyframe of this run held
  // (restored from the store or fused since), or -1 when none is held: where a restarted
  // mapper's frames must resume (the KF keyframe being fused, the queued
  // frames and those in flight died with the old instance).
  int64_t firstMissingFrame() const;
  const MapperCounters& counters() const { return counters_; }
  Mesh extractMesh() const { return volume_->extractMesh(); }
  // extractMesh() in pieces (TsdfVolume::extractMeshInPieces), for a map too large to mesh at once.
  void extractMeshInPieces(const std::function<void(const Mesh&)>& sink) const { volume_->extractMeshInPieces(sink); }
  // Blocks whose mesh changed since the last call (TsdfVolume::takeMeshChanges).
  std::vector<volume::BlockCoord> takeMeshChanges() { return volume_->takeMeshChanges(); }
  // The paper's baseline: every KF keyframe integrated once at its first
  // pose, never corrected, into a fresh volume of the same settings. Equals
  // extractMesh() when no keyframe moved.
  Mesh extractUncorrectedMesh() const;
  void extractUncorrectedMeshInPieces(const std::function<void(const Mesh&)>& sink) const;
  MemoryUse memoryUse() const;
  // Deletes the keyframe store (after a clean end of the run).
  void removeStore();
  // Marks the store's run finished (outputs written) before the end is said
  // on the bus, so that an instance restarted after that only says it again.
  void markRunFinished(int64_t end_frame);
  // With params.resume: the end frame of a finished run found in the store
  // (which was then not rebuilt from); nullopt otherwise.
  std::optional<int64_t> finishedRunEnd() const { return finished_run_end_; }

 private:
  std::optional<Pose> keyframePose(int64_t keyframe_id) const;
  void closeKeyframe();
  // `images`: rec's keyframe with its images (images(rec)).
  // at_camera: the volume streams around the pose first (a new keyframe; a round's stay where the camera is).
  void integrateKeyframe(KeyframeRecord& rec, const fusion::FusedKeyframe& images, const Pose& pose, bool at_camera);
  // Releases rec's images now that `home` keeps them; returns rec's keyframe
  // with them, for the integration under way.
  static fusion::FusedKeyframe leaveImagesAt(KeyframeRecord& rec, ImagesHome home);
  // De-integrates the chosen keyframes at their old poses, re-integrates them
  // at their current ones (paper 4.3's streaming order), then streams back
  // around the camera unless told not to; returns how many.
  ReintegrationRound reintegrate(const std::vector<size_t>& chosen, bool back_to_camera = true);
  void countRound(const ReintegrationRound& round);
  void updateTierCounters();  // counters_.active_blocks and the host tier's
  void ensureCamera(const Intrinsics& k);
  void restoreFromStore();
  void startAgainWithoutTheStore(const Error& why);
  void continueSession();
  // A keyframe restored from the store or the session, integrated at `pose`;
  // at_camera: the volume streams around it first and the camera is put there
  // (a session's, before any frame), else the camera's sphere stays (a rebuild beside new frames).
  void integrateRestored(KeyframeRecord& rec, const fusion::FusedKeyframe& images, const Pose& pose, bool at_camera);
  // A keyframe the store holds but the old instance never integrated (it
  // died between storing and integrating it): integrated at its current
  // pose, recorded in the store; left for later when its anchor has none.
  void integrateStoredOnly(KeyframeRecord& rec);
  void integratePendingRestored();

  MapperParams params_;
  std::unique_ptr<volume::TsdfVolume> volume_;
  std::unique_ptr<store::KeyframeStore> store_;
  std::unique_ptr<store::SessionWriter> session_;
  std::unique_ptr<store::Session> continued_;  // the session a continued run reads its keyframes' images from
  std::optional<int64_t> finished_run_end_;
  void writeAnchorPoses();  // to the session, when there is one
  std::optional<Intrinsics> camera_;
  std::unique_ptr<fusion::KeyframeFuser> fuser_;
  std::map<int64_t, Pose> estimates_;    // keyframe_t
  std::map<int64_t, Pose> graph_poses_;  // latest graph update
  std::vector<KeyframeRecord> keyframes_;
  std::deque<size_t> pending_;  // round_budget_ms: keyframes (indices) still to correct, in round order
  // Restored keyframes (indices) still to integrate again, each with the pose
  // the store recorded it integrated with (none: stored, never integrated).
  std::deque<std::pair<size_t, std::optional<Pose>>> rebuild_;
  double credit_ms_ = 0.0;      // round_budget_ms per fused frame, less what corrections spent
  int64_t next_kf_id_ = 0;
  int64_t run_first_kf_id_ = 0;  // KF keyframes before it are an earlier run's (a continued session)
  Eigen::Vector3d camera_position_ = Eigen::Vector3d::Zero();
  MapperCounters counters_;
  // Now on the clock the *_ms counters use (wall or process CPU), in ms.
  double clockMs() const;
};

}  // namespace rekon::mapper
