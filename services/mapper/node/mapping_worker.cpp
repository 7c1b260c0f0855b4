#include "mapping_worker.hpp"

#include <spdlog/spdlog.h>

#include <exception>

#include "rekon/common/error.hpp"

namespace rekon::mapper {

MappingWorker::MappingWorker(ServiceContext& ctx, Mapper& mapper, Inbox& inbox, MeshPublisher& mesh)
    : ctx_(ctx), mapper_(mapper), inbox_(inbox), mesh_(mesh), tables_(ctx.outDir(), mapper.params().resume) {}

void MappingWorker::run() {
  while (true) {
    try {
      if (mapper_.rebuildPending() && !inbox_.waitForWork(std::chrono::milliseconds(0))) {
        mapper_.continueRebuild(true);  // idle: one restored keyframe into the volume again
        mesh_.tick(mapper_);
        continue;
      }
      if (mapper_.correctionPending() && !inbox_.waitForWork(std::chrono::milliseconds(0))) {
        correct(true);  // idle: one queued keyframe of the last graph update
        continue;
      }
      if (mesh_.enabled() && !inbox_.waitForWork(mesh_.idleWait())) {
        mesh_.tick(mapper_);
        continue;
      }
      std::optional<Work> w = inbox_.next();
      if (!w) return;
      const BlockCause cause = process(*w);
      inbox_.finished(std::holds_alternative<FrameWork>(*w), mapper_.counters());
      mesh_.tick(mapper_, cause);
    } catch (...) {  // rekon::Error, OpenCV's for a broken image, or any other: a std::terminate would lose the mesh
      inbox_.failed(currentExceptionLine());
      ctx_.requestStop();
      return;
    }
  }
}

BlockCause MappingWorker::process(const Work& w) {
  if (const auto* f = std::get_if<FrameWork>(&w)) {
    fuse(*f);
    // A restart's rebuild first, then corrections, from the frame's credit.
    if (mapper_.rebuildPending()) mapper_.continueRebuild(false);
    if (mapper_.correctionPending()) {
      mesh_.noteChanges(mapper_, BlockCause::kNewData);  // the frame's, before the correction's
      return correct(false);
    }
  } else if (const auto* kf = std::get_if<KeyframeWork>(&w)) {
    mapper_.setKeyframeEstimate(kf->id, kf->world);
  } else if (std::holds_alternative<BaselineWork>(w)) {
    mapper_.flush();  // no frame comes after the end of the stream: the last KF keyframe is complete
    writeUncorrectedMesh(mapper_, ctx_.outDir());
    baseline_written_ = true;
  } else {
    const GraphWork& g = std::get<GraphWork>(w);
    const ReintegrationRound round = mapper_.applyGraphUpdate(g.poses);
    last_graph_version_ = g.version;
    recordRound(g.version, round, RoundKind::kGraphUpdate);
    if (round.keyframes > 0) return BlockCause::kCorrection;
  }
  return BlockCause::kNewData;
}

BlockCause MappingWorker::correct(bool idle) {
  const ReintegrationRound piece = mapper_.continueCorrection(idle);
  if (piece.keyframes == 0) return BlockCause::kNewData;
  recordRound(last_graph_version_, piece, RoundKind::kPiece);
  if (idle) mesh_.tick(mapper_, BlockCause::kCorrection);
  return BlockCause::kCorrection;
}

void MappingWorker::fuse(const FrameWork& f) {
  const auto t0 = std::chrono::steady_clock::now();
  if (!first_frame_time_) first_frame_time_ = t0;
  const MapperCounters before = mapper_.counters();
  mapper_.addFrame(f.frame, f.k, f.tracked.keyframe_id, f.tracked.pose_in_keyframe, f.tracked.lost);
  const MapperCounters& after = mapper_.counters();
  tables_.add(FrameTiming{f.frame.id, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(),
                          after.fuse_ms_total - before.fuse_ms_total,
                          after.first_integration_ms_total - before.first_integration_ms_total});
}

void MappingWorker::finish(bool clean) {
  if (clean) {
    mapper_.flush();  // the last KF keyframe is new data; what the final pass changes after it is not
    mesh_.noteChanges(mapper_, BlockCause::kNewData);
    for (const ReintegrationRound& r : mapper_.finish()) recordRound(last_graph_version_, r, RoundKind::kFinalPass);
  } else {
    mapper_.flush();
    spdlog::warn("mapper stopped before the end: no final pass; the keyframe store is kept (mapper.resume=true continues from it)");
  }
}

void MappingWorker::recordRound(int64_t graph_version, const ReintegrationRound& round, RoundKind kind) {
  tables_.add(RoundRecord{secondsSinceFirstFrame(), graph_version, round, kind, mapper_.counters().frames});
}

double MappingWorker::secondsSinceFirstFrame() const {
  if (!first_frame_time_) return 0.0;
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - *first_frame_time_).count();
}

}  // namespace rekon::mapper
