#include "rekon/mapper/mapper.hpp"

#include <fmt/format.h>

#include <spdlog/spdlog.h>

#include <time.h>

#include <algorithm>
#include <chrono>

#include "rekon/common/cpu_time.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"
#include "rekon/mapper/volume/volume_config.hpp"

namespace rekon::mapper {
namespace {


int64_t streamedBlocks(const volume::TsdfVolume& v) {
  const volume::VolumeStats s = v.stats();
  return s.streamed_in + s.streamed_out;
}

int64_t matBytes(const cv::Mat& m) { return static_cast<int64_t>(m.total() * m.elemSize()); }

}  // namespace

double Mapper::clockMs() const {
  if (!params_.cpu_time_counters)
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
  return processCpuMs();
}

MapperParams MapperParams::fromConfig(const Config& c) {
  MapperParams p;
  p.fusion = fusion::fusionParamsFromConfig(c);
  p.volume = volume::volumeParamsFromConfig(c);
  p.volume.streaming_radius = c.getDouble("mapper.streaming_radius");
  const double active_mb = c.getDouble("mapper.active_mb");
  if (!(active_mb >= 0.0 && active_mb <= 1.0e6))
    throw Error("mapper.active_mb = " + fmt::format("{}", active_mb) + " is invalid; it must be in [0, 1e6] MiB (0 = only the streaming sphere stays active)");
  const double block_bytes = volume::kBlockVoxels * sizeof(volume::Voxel);
  p.volume.active_max_blocks = static_cast<int64_t>(active_mb * 1048576.0 / block_bytes);
  const double host_mb = c.getDouble("mapper.host_mb");
  if (!(host_mb >= 0.0 && host_mb <= 1.0e7))
    throw Error("mapper.host_mb = " + fmt::format("{}", host_mb) + " is invalid; it must be in [0, 1e7] MiB (0 = no budget)");
  p.volume.host_max_blocks = static_cast<int64_t>(host_mb * 1048576.0 / block_bytes);
  p.volume.spill_dir = c.getString("mapper.voxel_spill_dir");
  if (p.volume.spill_dir.empty()) throw Error("mapper.voxel_spill_dir is empty; give a folder or auto ($TMPDIR or /tmp)");
  if (p.volume.spill_dir == "auto") p.volume.spill_dir = tempFolder();
  p.volume.validate();
  p.mode = parseReintegrationMode(c.getString("mapper.reintegration"));
  p.m = c.getInt("mapper.m");
  if (p.m < 1) throw Error("mapper.m must be at least 1 (keyframes re-integrated per graph update)");
  p.min_movement = c.getDouble("mapper.min_movement");
  if (!(p.min_movement >= 0)) throw Error("mapper.min_movement must not be negative");
  p.near_window_slack = c.getDouble("mapper.near_window_slack");
  if (!(p.near_window_slack >= 0.0 && p.near_window_slack < 1.0))
    throw Error("mapper.near_window_slack = " + fmt::format("{}", p.near_window_slack) + " is invalid; it must be in [0, 1)");
  p.round_budget_ms = c.getDouble("mapper.round_budget_ms");
  if (!(p.round_budget_ms >= 0.0 && p.round_budget_ms <= 1.0e6))
    throw Error("mapper.round_budget_ms = " + std::to_string(p.round_budget_ms) +
                " is invalid; it must be >= 0 ms per frame (0 = each graph update's round at once)");
  p.final_pass_s = c.getDouble("mapper.final_pass_s");
  if (!(p.final_pass_s >= 0.0 && p.final_pass_s <= 1.0e6))
    throw Error("mapper.final_pass_s = " + fmt::format("{}", p.final_pass_s) +
                " is invalid; it must be >= 0 seconds (0 = every KF keyframe that still moved)");
  p.uncorrected_mesh_max_keyframes = c.getInt("mapper.uncorrected_mesh_max_keyframes");
  if (p.uncorrected_mesh_max_keyframes < 0)
    throw Error("mapper.uncorrected_mesh_max_keyframes must not be negative (0 = no limit)");
  p.use_store = c.getBool("mapper.use_store");
  p.resume = c.getBool("mapper.resume");
  p.store = store::StoreOptions::fromConfig(c);  // segment, size and spill folder (mapper.store_*)
  p.session_dir = c.getString("session.dir");
  p.continue_session = c.getBool("session.continue");
  if (p.continue_session && p.session_dir.empty())
    throw Error("session.continue needs session.dir (rekon run --continue DIR sets both)");
  return p;
}

Mapper::Mapper(const MapperParams& params) : params_(params) {
  params_.fusion.validate();
  if (params_.m < 1) throw Error("mapper.m must be at least 1 (keyframes re-integrated per graph update)");
  volume_ = std::make_unique<volume::TsdfVolume>(params_.volume);
  if (params_.use_store && !params_.resume && store::KeyframeStore::remove(params_.store.segment)) {
    spdlog::warn("removed the stale keyframe store '{}' of an earlier run (set mapper.resume=true to continue from it)",
                 params_.store.segment);
  }
  if (params_.continue_session) {
    continueSession();
  } else if (params_.use_store && params_.resume) {
    try {
      store_ = store::KeyframeStore::openExisting(params_.store.segment);
    } catch (const Error&) {
      return;  // no store yet: created with the first frame's camera
    }
    try {
      finished_run_end_ = store_->runEndFrame();
      if (finished_run_end_) return;  // nothing to rebuild: the run's outputs are written
      restoreFromStore();
    } catch (const store::BrokenStore& e) {
      startAgainWithoutTheStore(e);
    }
  }
}

// The killed instance died inside the store's allocator: what the store
// holds cannot be trusted. It is removed and this restart starts empty, at
// frame 0 (its resume point), as one killed before its first KF keyframe does:
// from a file every frame comes again; live, the frames before are lost.
void Mapper::startAgainWithoutTheStore(const Error& why) {
  spdlog::warn("{}: removing it; this restart rebuilds the map from frame 0", why.what());
  store_.reset();
  store::KeyframeStore::remove(params_.store.segment);
  camera_.reset();  // the first frame's camera creates a new store
  fuser_.reset();
  keyframes_.clear();
  graph_poses_.clear();
  rebuild_.clear();
  counters_.restored_keyframes = 0;
  volume_ = std::make_unique<volume::TsdfVolume>(params_.volume);
}

Mapper::~Mapper() = default;

int64_t Mapper::firstMissingFrame() const {
  int64_t newest = -1;
  for (const KeyframeRecord& rec : keyframes_)
    if (rec.kf.id >= run_first_kf_id_) newest = std::max(newest, rec.kf.last_frame_id);
  return newest < 0 ? -1 : newest + 1;
}

void Mapper::restoreFromStore() {
  const Intrinsics k = store_->intrinsics();
  ensureCamera(k);
  for (const auto& [id, pose] : store_->anchorPoses()) graph_poses_[id] = pose;
  const auto infos = store_->list();
  spdlog::info("keyframe store '{}' holds {} keyframes: the volume is rebuilt from them beside the new frames",
               params_.store.segment, infos.size());
  for (const store::KeyframeInfo& info : infos) {
    KeyframeRecord rec;  // the images stay in the store until the rebuild reaches it
    rec.home = ImagesHome::kStore;
    rec.kf = store::withoutImages(info);
    next_kf_id_ = std::max(next_kf_id_, info.id + 1);
    // The old instance died between the store and the session: the session gets it now.
    if (session_ && !session_->has(info.id)) {
      writeAnchorPoses();
      session_->addKeyframe(images(rec));
    }
    keyframes_.push_back(std::move(rec));
    rebuild_.emplace_back(keyframes_.size() - 1, info.integrated ? std::optional<Pose>(info.integrated_pose) : std::nullopt);
    ++counters_.restored_keyframes;
  }
}

int Mapper::continueRebuild(bool idle) {
  int done = 0;
  while (!rebuild_.empty() && (idle ? done == 0 : credit_ms_ > 0.0)) {
    const double t0 = clockMs();
    const auto [i, pose] = rebuild_.front();
    rebuild_.pop_front();
    KeyframeRecord& rec = keyframes_[i];
    if (pose) integrateRestored(rec, images(rec), *pose, false);
    else integrateStoredOnly(rec);
    if (!idle) credit_ms_ -= clockMs() - t0;
    ++done;
    ++counters_.rebuilt_keyframes;
    if (counters_.rebuilt_keyframes % 20 == 0 || rebuild_.empty())
      spdlog::info("rebuilt {} of {} restored keyframes ({} frames fused beside them)", counters_.rebuilt_keyframes,
                   counters_.restored_keyframes, counters_.frames);
  }
  if (done > 0) updateTierCounters();
  return done;
}

void Mapper::completeRebuild() {
  while (rebuildPending()) continueRebuild(true);
}

void Mapper::integrateStoredOnly(KeyframeRecord& rec) {
  // closeKeyframe() stores a KF keyframe before it integrates it: the old
  // instance died in between. Its frames are before the resume point and are
  // not sent again, so it is integrated here, at the pose the old instance
  // was about to use (its DVO keyframe's pose, in the store).
  const auto pose = currentPose(rec.kf);
  if (!pose) {
    spdlog::warn("keyframe store: KF keyframe {} (frames {}..{}) was never integrated and its DVO keyframe {} has no "
                 "pose; it is integrated once one comes", rec.kf.id, rec.kf.first_frame_id, rec.kf.last_frame_id,
                 rec.kf.anchor_keyframe_id);
    return;
  }
  spdlog::info("keyframe store: KF keyframe {} (frames {}..{}) was stored but not yet integrated when the mapper "
               "stopped; integrated now", rec.kf.id, rec.kf.first_frame_id, rec.kf.last_frame_id);
  integrateRestored(rec, images(rec), *pose, false);
  if (store_) store_->setIntegratedPose(rec.kf.id, *pose);
}

void Mapper::integratePendingRestored() {
  if (rebuildPending()) return;  // the rebuild takes each at its turn
  for (KeyframeRecord& rec : keyframes_)
    if (!rec.integrated && currentPose(rec.kf)) integrateStoredOnly(rec);
}

void Mapper::integrateRestored(KeyframeRecord& rec, const fusion::FusedKeyframe& images, const Pose& pose,
                               bool at_camera) {
  // Straight into the volume, not through integrateKeyframe: the store or the
  // session already records this pose, and the counters describe this run's work.
  if (at_camera) {
    volume_->streamAround(pose.translation());
    camera_position_ = pose.translation();
  }
  volume_->integrate(images.depth, images.color, images.weight, *camera_, pose);
  rec.integrated = true;
  rec.integrated_pose = pose;
  rec.first_pose = pose;  // no older pose is kept: the uncorrected baseline starts here
}

void Mapper::continueSession() {
  continued_ = std::make_unique<store::Session>(store::Session::open(params_.session_dir));
  const store::Session& session = *continued_;
  const store::SessionInfo& info = session.info();
  if (info.voxel_size != params_.volume.voxel_size || info.truncation != params_.volume.truncation)
    spdlog::warn("session {} was mapped with {} m voxels and {} m truncation, this run maps with {} and {}; its "
                 "session.yaml keeps the first", params_.session_dir, info.voxel_size, info.truncation,
                 params_.volume.voxel_size, params_.volume.truncation);
  ensureCamera(info.camera);  // the session writer reopens it; a frame of another camera is an error
  graph_poses_ = session.anchors();
  const size_t n = session.keyframes().size();
  for (size_t i = 0; i < n; ++i) next_kf_id_ = std::max(next_kf_id_, session.keyframes()[i].id + 1);
  // This run's keyframes are the store's (the session's are never put there):
  // a restarted mapper resumes after them, a first one after none.
  run_first_kf_id_ = next_kf_id_;
  if (store_)
    for (const store::KeyframeInfo& k : store_->list()) run_first_kf_id_ = std::min(run_first_kf_id_, k.id);
  int without_pose = 0;
  for (size_t i = 0; i < n; ++i) {
    const auto pose = session.worldPose(session.keyframes()[i]);
    if (!pose) {
      ++without_pose;  // its anchor's pose never reached the session: it cannot be placed
      continue;
    }
    KeyframeRecord rec;
    rec.kf = session.load(i);
    const fusion::FusedKeyframe images = leaveImagesAt(rec, ImagesHome::kSession);
    rec.session_index = i;
    keyframes_.push_back(std::move(rec));
    integrateRestored(keyframes_.back(), images, *pose, true);
    ++counters_.restored_keyframes;
    if ((i + 1) % 20 == 0) spdlog::info("integrated {} of the session's {} keyframes", i + 1, n);
  }
  if (without_pose > 0) spdlog::warn("{} of the session's keyframes have no anchor pose; left out", without_pose);
  spdlog::info("session {}: {} KF keyframes integrated; this run's start with id {}", params_.session_dir,
               keyframes_.size(), run_first_kf_id_);
}

void Mapper::ensureCamera(const Intrinsics& k) {
  if (camera_) {
    if (!sameCamera(k, *camera_))
      throw Error("mapper: a frame's camera (" + describeCamera(k) + ") differs from the map's (" +
                  describeCamera(*camera_) + "); one camera per run and per session");
    return;
  }
  k.validate("mapper camera");
  camera_ = k;
  fuser_ = std::make_unique<fusion::KeyframeFuser>(params_.fusion, k);
  if (params_.use_store && !store_) {
    store_ = store::KeyframeStore::openOrCreate(params_.store, k);
    spdlog::info("keyframe store '{}' created ({} MiB)", params_.store.segment, params_.store.size_mb);
    // The DVO keyframes placed before the first frame (the first one's
    // keyframe_t comes before it): a restart needs their poses too.
    for (const auto& [id, pose] : estimates_)
      if (!graph_poses_.count(id)) store_->setAnchorPose(id, pose);
    for (const auto& [id, pose] : graph_poses_) store_->setAnchorPose(id, pose);
  }
  if (!params_.session_dir.empty() && !session_) {
    store::SessionInfo info;
    info.camera = k;
    info.voxel_size = params_.volume.voxel_size;
    info.truncation = params_.volume.truncation;
    info.max_depth = params_.volume.max_depth;
    session_ = std::make_unique<store::SessionWriter>(params_.session_dir, info,
                                                      params_.resume || params_.continue_session);
    spdlog::info("session {}: keyframes, poses and frames are written as the run goes", params_.session_dir);
  }
}

void Mapper::writeAnchorPoses() {
  if (!session_) return;
  std::map<int64_t, Pose> poses = graph_poses_;
  poses.insert(estimates_.begin(), estimates_.end());  // a graph pose wins over the odometry estimate
  session_->setAnchorPoses(poses);
}

void Mapper::setKeyframeEstimate(int64_t keyframe_id, const Pose& world) {
  estimates_[keyframe_id] = world;
  if (store_ && !graph_poses_.count(keyframe_id)) store_->setAnchorPose(keyframe_id, world);
}

std::optional<Pose> Mapper::keyframePose(int64_t keyframe_id) const {
  if (auto it = graph_poses_.find(keyframe_id); it != graph_poses_.end()) return it->second;
  const auto odometry = estimates_.find(keyframe_id);
  if (odometry == estimates_.end()) return std::nullopt;
  // Newer than the graph: its odometry from the newest earlier keyframe the
  // graph has, on top of that keyframe's graph pose (as the tracker's loop
  // checks estimate it). Its odometry pose alone would sit where the drift
  // the graph has since corrected put it: frames of one KF keyframe on both
  // sides of a DVO keyframe would be fused that far apart.
  auto earlier = graph_poses_.lower_bound(keyframe_id);
  if (earlier == graph_poses_.begin()) return odometry->second;
  --earlier;
  const auto earlier_odometry = estimates_.find(earlier->first);
  if (earlier_odometry == estimates_.end()) return odometry->second;
  return movedWithGraph(earlier->second, earlier_odometry->second, odometry->second);
}

std::optional<Pose> Mapper::currentPose(const fusion::FusedKeyframe& kf) const {
  const auto anchor = keyframePose(kf.anchor_keyframe_id);
  if (!anchor) return std::nullopt;
  return orthonormalised(*anchor * kf.pose_in_anchor);
}

std::vector<double> Mapper::movements() const {
  std::vector<double> out;
  for (const KeyframeRecord& r : keyframes_) {
    const auto now = r.integrated ? currentPose(r.kf) : std::nullopt;
    out.push_back(now ? poseMovement(r.integrated_pose, *now) : 0.0);
  }
  return out;
}

bool Mapper::addFrame(const RgbdFrame& frame, const Intrinsics& k, int64_t keyframe_id, const Pose& pose_in_keyframe,
                      bool lost) {
  ensureCamera(k);
  counters_.input_frame_bytes += matBytes(frame.depth) + matBytes(frame.color);
  const auto anchor = keyframePose(keyframe_id);
  if (lost || !anchor) {
    if (!lost) spdlog::warn("frame {}: DVO keyframe {} has no pose yet; frame skipped", frame.id, keyframe_id);
    ++counters_.skipped_frames;
    return false;
  }
  const Pose world = orthonormalised(*anchor * pose_in_keyframe);
  if (session_) session_->addFrame({frame.id, frame.timestamp, keyframe_id, pose_in_keyframe});
  double t0 = clockMs();
  // A graph update since the open KF keyframe's first frame moved it: its
  // frames are placed relative to it with the poses of one graph.
  if (fuser_->active()) {
    if (const auto open = currentPose(fuser_->openKeyframe())) fuser_->moveTo(*open);
  }
  if (fuser_->startsNewKeyframe(keyframe_id, world)) {
    counters_.fuse_ms_total += clockMs() - t0;
    closeKeyframe();
    t0 = clockMs();
    fuser_->begin(next_kf_id_++, keyframe_id, pose_in_keyframe, world);
  }
  fuser_->add(frame, world);
  counters_.fuse_ms_total += clockMs() - t0;
  camera_position_ = world.translation();
  // Credit for corrections: a frame's share, at most one round's worth saved up.
  credit_ms_ = std::min(credit_ms_ + params_.round_budget_ms, params_.round_budget_ms * params_.m);
  ++counters_.frames;
  updateTierCounters();
  return true;
}

void Mapper::closeKeyframe() {
  if (!fuser_ || !fuser_->active()) return;
  KeyframeRecord rec;
  const double t0 = clockMs();
  rec.kf = fuser_->finish();  // the color fusion
  counters_.fuse_ms_total += clockMs() - t0;
  ++counters_.kf_keyframes;
  if (store_) store_->add(rec.kf);
  if (session_) {
    writeAnchorPoses();  // first: a keyframe in the session always finds its anchor
    session_->addKeyframe(rec.kf);
  }
  const fusion::FusedKeyframe images = store_ ? leaveImagesAt(rec, ImagesHome::kStore) : rec.kf;
  keyframes_.push_back(std::move(rec));
  const auto pose = currentPose(keyframes_.back().kf);
  if (!pose) throw Error("mapper: KF keyframe's DVO keyframe lost its pose");  // anchors are never forgotten
  const double t1 = clockMs();
  integrateKeyframe(keyframes_.back(), images, *pose, true);
  keyframes_.back().first_pose = *pose;
  counters_.first_integration_ms_total += clockMs() - t1;
  ++counters_.integrations;
}

fusion::FusedKeyframe Mapper::images(const KeyframeRecord& rec) const {
  switch (rec.home) {
    case ImagesHome::kHere: return rec.kf;
    case ImagesHome::kStore:
      if (!store_) break;  // removed at the end of the run
      return store_->loadById(rec.kf.id);
    case ImagesHome::kSession: return continued_->load(rec.session_index);
  }
  throw Error("mapper: KF keyframe " + std::to_string(rec.kf.id) +
              "'s images were in the keyframe store, which is removed; use the map before removeStore()");
}

fusion::FusedKeyframe Mapper::leaveImagesAt(KeyframeRecord& rec, ImagesHome home) {
  fusion::FusedKeyframe with_images = rec.kf;  // shares the pixels: releasing rec's leaves them here
  rec.home = home;
  rec.kf.depth.release();
  rec.kf.weight.release();
  rec.kf.color.release();
  return with_images;
}

void Mapper::integrateKeyframe(KeyframeRecord& rec, const fusion::FusedKeyframe& images, const Pose& pose,
                               bool at_camera) {
  const double t0 = clockMs();
  if (at_camera) volume_->streamAround(pose.translation());
  volume_->integrate(images.depth, images.color, images.weight, *camera_, pose);
  counters_.integrate_ms_total += clockMs() - t0;
  rec.integrated = true;
  rec.integrated_pose = pose;
  if (store_ && rec.kf.id >= run_first_kf_id_) store_->setIntegratedPose(rec.kf.id, pose);  // an earlier run's are not in it
}

ReintegrationRound Mapper::reintegrate(const std::vector<size_t>& chosen, bool back_to_camera) {
  ReintegrationRound round;
  if (chosen.empty()) return round;
  const double t0 = clockMs();
  const int64_t streamed_before = streamedBlocks(*volume_);
  std::vector<Pose> updated;
  std::vector<fusion::FusedKeyframe> loaded;  // m keyframes' images for the round, then released
  for (size_t i : chosen) {
    updated.push_back(*currentPose(keyframes_[i].kf));
    loaded.push_back(images(keyframes_[i]));
  }
  // De-integrate with the old poses, re-integrate with the new ones (paper
  // 4.3). The paper streams the sphere around each old and new pose in
  // first; here each (de-)integration brings in only the blocks it updates,
  // and the camera's sphere stays (TsdfVolume::streamAround), so a round
  // streams no more than it touches and the next integration nothing back.
  for (size_t n = 0; n < chosen.size(); ++n) {
    const KeyframeRecord& r = keyframes_[chosen[n]];
    volume_->deintegrate(loaded[n].depth, loaded[n].color, loaded[n].weight, *camera_, r.integrated_pose);
    ++counters_.deintegrations;
  }
  for (size_t n = 0; n < chosen.size(); ++n) {
    integrateKeyframe(keyframes_[chosen[n]], loaded[n], updated[n], false);
    ++counters_.reintegrations;
  }
  if (back_to_camera) volume_->streamAround(camera_position_);
  round.keyframes = static_cast<int>(chosen.size());
  round.ms = clockMs() - t0;
  round.blocks_streamed = streamedBlocks(*volume_) - streamed_before;
  return round;
}

ReintegrationRound Mapper::applyGraphUpdate(const std::vector<std::pair<int64_t, Pose>>& poses) {
  for (const auto& [id, pose] : poses) {
    graph_poses_[id] = pose;
    if (store_) store_->setAnchorPose(id, pose);
  }
  ++counters_.graph_updates;
  integratePendingRestored();  // a restored keyframe whose DVO keyframe had no pose yet
  // Before this run's first KF keyframe the session's files stay as they were
  // (a continued run that stops early leaves its session untouched).
  if (firstMissingFrame() >= 0) writeAnchorPoses();
  const std::vector<double> moved = movements();
  std::vector<double> distance;  // from the camera, only where the nearer-window rule uses it
  if (params_.near_window_slack > 0.0)
    for (const KeyframeRecord& r : keyframes_) distance.push_back((r.integrated_pose.translation() - camera_position_).norm());
  const auto chosen =
      selectForReintegration(params_.mode, moved, params_.m, params_.min_movement, distance, params_.near_window_slack);
  if (params_.round_budget_ms > 0.0) {
    // The newest selection replaces what the last one left: keyframes it
    // did not correct still count their movement in this one.
    pending_.assign(chosen.begin(), chosen.end());
    return {};
  }
  const ReintegrationRound round = reintegrate(chosen);
  countRound(round);
  if (round.keyframes > 0)
    spdlog::debug("graph update {}: re-integrated {} KF keyframes from {} in {:.1f} ms", counters_.graph_updates,
                  round.keyframes, keyframes_[chosen.front()].kf.id, round.ms);
  return round;
}

void Mapper::countRound(const ReintegrationRound& round) {
  counters_.reintegration_ms_total += round.ms;
  counters_.reintegration_blocks_streamed += round.blocks_streamed;
  updateTierCounters();
}

void Mapper::updateTierCounters() {
  const volume::VolumeStats vs = volume_->stats();
  counters_.active_blocks = vs.active_blocks;
  counters_.host_blocks_on_disk = vs.host_blocks_on_disk;
  counters_.host_blocks_in_memory = vs.host_blocks - vs.host_blocks_on_disk;
}

ReintegrationRound Mapper::continueCorrection(bool idle) {
  ReintegrationRound done;
  while (!pending_.empty() && (idle ? done.keyframes == 0 : credit_ms_ > 0.0)) {
    const size_t i = pending_.front();
    pending_.pop_front();
    // One keyframe is exact on its own (de-integrated at its old pose,
    // re-integrated at its new one); its blocks stay for the next one.
    const ReintegrationRound r = reintegrate({i}, false);
    if (!idle) credit_ms_ -= r.ms;
    done.keyframes += r.keyframes;
    done.ms += r.ms;
    done.blocks_streamed += r.blocks_streamed;
  }
  countRound(done);
  return done;
}

void Mapper::flush() {
  completeRebuild();
  closeKeyframe();
}

std::vector<ReintegrationRound> Mapper::finish() {
  flush();
  pending_.clear();  // the final pass corrects every keyframe that still moved
  integratePendingRestored();
  std::vector<ReintegrationRound> rounds;
  if (params_.mode == ReintegrationMode::kNone) {
    spdlog::info("final pass skipped (mapper.reintegration: none)");
    return rounds;
  }
  const std::vector<size_t> chosen = finalPassChoice();
  const auto start = std::chrono::steady_clock::now();
  const auto spent_s = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
  // In runs of m so that the streaming sphere follows the trajectory.
  for (size_t begin = 0; begin < chosen.size(); begin += static_cast<size_t>(params_.m)) {
    if (params_.final_pass_s > 0 && spent_s() > params_.final_pass_s) {
      spdlog::warn("final pass: stopped after {:.1f} s (mapper.final_pass_s {}), {} of {} chosen KF keyframes left as they are",
                   spent_s(), params_.final_pass_s, chosen.size() - begin, chosen.size());
      break;
    }
    const size_t end = std::min(chosen.size(), begin + static_cast<size_t>(params_.m));
    rounds.push_back(reintegrate(std::vector<size_t>(chosen.begin() + static_cast<std::ptrdiff_t>(begin),
                                                     chosen.begin() + static_cast<std::ptrdiff_t>(end))));
    counters_.final_pass_reintegrations += rounds.back().keyframes;
    counters_.final_pass_ms_total += rounds.back().ms;
  }
  return rounds;
}

std::vector<size_t> Mapper::finalPassChoice() const {
  const std::vector<double> moved = movements();
  const auto still = static_cast<size_t>(
      std::count_if(moved.begin(), moved.end(), [&](double d) { return d > params_.min_movement; }));
  const double ms_each = counters_.reintegrations > 0
                             ? counters_.reintegration_ms_total / static_cast<double>(counters_.reintegrations)
                             : 0.0;
  size_t most = still;
  if (params_.final_pass_s > 0 && ms_each > 0)
    most = std::min(still, static_cast<size_t>(params_.final_pass_s * 1000.0 / ms_each));
  std::vector<size_t> chosen;
  if (most > 0) chosen = selectMostMoved(moved, static_cast<int>(most), params_.min_movement);
  std::sort(chosen.begin(), chosen.end());  // back in the order of the scan
  if (most < still)
    spdlog::info("final pass: the {} most moved of {} KF keyframes that still moved (of {}): mapper.final_pass_s {} "
                 "at {:.0f} ms each",
                 most, still, keyframes_.size(), params_.final_pass_s, ms_each);
  else
    spdlog::info("final pass: {} of {} KF keyframes still moved", still, keyframes_.size());
  return chosen;
}

Mesh Mapper::extractUncorrectedMesh() const {
  Mesh mesh;
  extractUncorrectedMeshInPieces([&mesh](const Mesh& piece) { appendMesh(mesh, piece); });
  return mesh;
}

void Mapper::extractUncorrectedMeshInPieces(const std::function<void(const Mesh&)>& sink) const {
  if (!camera_) return;
  // Same settings and order as the first integrations, so that an unmoved run
  // gives the same voxels; in less memory beside the map: only the streaming
  // sphere active and a quarter of the host budget, the rest on disk.
  volume::VolumeParams p = params_.volume;
  p.active_max_blocks = 0;
  if (p.host_max_blocks > 0) p.host_max_blocks = std::max<int64_t>(1, p.host_max_blocks / 4);
  volume::TsdfVolume baseline(p);
  for (const KeyframeRecord& r : keyframes_) {
    if (!r.integrated) continue;
    const fusion::FusedKeyframe kf = images(r);
    baseline.streamAround(r.first_pose.translation());
    baseline.integrate(kf.depth, kf.color, kf.weight, *camera_, r.first_pose);
  }
  baseline.extractMeshInPieces(sink);
}

MemoryUse Mapper::memoryUse() const {
  MemoryUse m;
  m.input_frame_bytes = counters_.input_frame_bytes;
  const int64_t pixels = camera_ ? int64_t{camera_->width} * camera_->height : 0;
  for (const KeyframeRecord& r : keyframes_) {
    m.keyframe_bytes += pixels * static_cast<int64_t>(2 * sizeof(float) + 3);
    m.keyframe_bytes_in_mapper += matBytes(r.kf.depth) + matBytes(r.kf.weight) + matBytes(r.kf.color);
  }
  if (store_) m.keyframe_store_bytes = static_cast<int64_t>(store_->totalBytes() - store_->freeBytes());
  const volume::VolumeStats vs = volume_->stats();
  const int64_t block_bytes = static_cast<int64_t>(volume::kBlockVoxels) * vs.bytes_per_voxel;
  m.voxel_bytes = vs.blocks * block_bytes;
  m.active_voxel_bytes_peak = vs.peak_active_blocks * block_bytes;
  m.active_voxel_bytes = vs.active_blocks * block_bytes;
  m.host_voxel_bytes_in_memory = (vs.host_blocks - vs.host_blocks_on_disk) * block_bytes;
  m.voxel_bytes_on_disk = vs.host_blocks_on_disk * block_bytes;
  return m;
}

void Mapper::markRunFinished(int64_t end_frame) {
  if (store_) store_->markRunFinished(end_frame);
}

void Mapper::removeStore() {
  if (!params_.use_store) return;
  store_.reset();
  if (store::KeyframeStore::remove(params_.store.segment))
    spdlog::info("keyframe store '{}' removed", params_.store.segment);
}

}  // namespace rekon::mapper
