#pragma once
// The one thread that changes the Mapper: it takes the inbox's work in order
// (fuse a joined frame, place a new DVO keyframe, apply a graph update, write
// the uncorrected baseline), so a re-integration never stalls frame intake,
// and records the time of every frame and every re-integration round.
#include <chrono>
#include <cstdint>
#include <optional>

#include "inbox.hpp"
#include "mesh_publisher.hpp"
#include "outputs.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"

namespace rekon::mapper {

class MappingWorker {
 public:
  // BaselineWork (queued only with an output folder) writes mesh_uncorrected.ply into ctx.outDir().
  // The mesh publisher ticks after every piece of work and when idle.
  MappingWorker(ServiceContext& ctx, Mapper& mapper, Inbox& inbox, MeshPublisher& mesh);

  // The thread's body: until the inbox lets it stop, or until a piece of work
  // fails (the inbox then holds the error, and a stop is requested).
  void run();

  // After run() returned, on the calling thread: the final pass after a clean
  // end (its rounds recorded), else only the open KF keyframe integrated.
  void finish(bool clean);
  bool baselineWritten() const { return baseline_written_; }

 private:
  // What changed the blocks: a graph update that re-integrated is a correction.
  BlockCause process(const Work& w);
  void fuse(const FrameWork& f);
  // mapper.round_budget_ms: corrects queued keyframes (Mapper::continueCorrection), records the piece.
  BlockCause correct(bool idle);
  double secondsSinceFirstFrame() const;
  void recordRound(int64_t graph_version, const ReintegrationRound& round, RoundKind kind);  // a row of mapper_reintegration.csv

  ServiceContext& ctx_;
  Mapper& mapper_;
  Inbox& inbox_;
  MeshPublisher& mesh_;
  TimingTables tables_;
  std::optional<std::chrono::steady_clock::time_point> first_frame_time_;
  int64_t last_graph_version_ = 0;
  bool baseline_written_ = false;
};

}  // namespace rekon::mapper
