#include "mapper_service.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "inbox.hpp"
#include "mapping_worker.hpp"
#include "mesh_publisher.hpp"
#include "outputs.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/priority.hpp"
#include "rekon/mapper/mapper.hpp"
#include "rekon_msgs/resume_point_t.hpp"

namespace rekon::mapper {
namespace {

struct Settings {
  MapperParams params;
  size_t max_queued_frames;
  bool drop_when_full;
  std::chrono::duration<double> progress_every;
  bool wait_for_optimiser;  // the final pass after the optimiser's done_t, not after the last frame
  // mesh_uncorrected.ply: every KF keyframe at the pose of its first
  // integration. With reintegration none mesh.ply already is that baseline.
  bool baseline_wanted;
  MeshPublisherSettings mesh;
  // False: whoever started this mapper removes the store once the process
  // has exited (rekon run does), so that one restarted after its done_t
  // finds the store marked finished and only says done again.
  bool remove_store_at_end;
  // The mapping threads' nice value (mapper.nice): above 0 they yield to
  // tracking and to the frame source on a busy machine.
  int nice;
  // How long a restarted mapper drops frames past its resume point waiting
  // for the source to rewind (mapper.rewind_wait_s; 0: a live source).
  double rewind_wait_s;
};

bool contains(const std::vector<std::string>& list, const std::string& s) {
  return std::find(list.begin(), list.end(), s) != list.end();
}

Settings readSettings(const ServiceContext& ctx) {
  const Config& config = ctx.config();
  const MapperParams params = MapperParams::fromConfig(config);
  const size_t max_queued = static_cast<size_t>(std::max(1, config.getInt("mapper.max_queued_frames")));
  const std::string when_full = config.getString("mapper.when_full");
  if (when_full != "hold" && when_full != "drop") throw Error("mapper.when_full '" + when_full + "' must be hold or drop");
  const bool write_uncorrected = config.getBool("mapper.write_uncorrected_mesh");
  const auto progress_every = std::chrono::duration<double>(config.getDouble("mapper.progress_interval_s"));
  const bool wait_for_optimiser =
      config.getBool("mapper.wait_for_optimiser") && contains(config.getStringList("run.services"), "optimiser");
  const int nice = config.getInt("mapper.nice");
  requireNice(nice, "mapper.nice");
  const double rewind_wait_s = config.getDouble("mapper.rewind_wait_s");
  if (!(rewind_wait_s >= 0)) throw Error("mapper.rewind_wait_s must be 0 or more seconds");
  return {params, max_queued, when_full == "drop", progress_every, wait_for_optimiser,
          write_uncorrected && params.mode != ReintegrationMode::kNone && !ctx.outDir().empty(),
          MeshPublisherSettings::fromConfig(config), config.getBool("mapper.remove_store_at_end"), nice, rewind_wait_s};
}

// Where the frame source resumes for this instance: after the frames of the
// keyframes it restored from its store (a restart), or from the first.
// A restart (mapper.resume) whose store holds no KF keyframe yet resumes at
// frame 0: the frames its killed instance was fusing died with it (a chaos
// run once lost frames 0-25 of the room's first KF keyframe this way).
rekon_msgs::resume_point_t resumePoint(const ServiceContext& ctx, const Mapper& mapper, bool resume) {
  rekon_msgs::resume_point_t resume_point{};
  resume_point.service = ctx.name();
  resume_point.pid = static_cast<int32_t>(getpid());
  resume_point.first_missing_frame = mapper.firstMissingFrame();
  if (resume && resume_point.first_missing_frame < 0) resume_point.first_missing_frame = 0;
  return resume_point;
}

void announceStart(ServiceContext& ctx, const Settings& settings, const rekon_msgs::resume_point_t& resume_point) {
  // Running first (setState publishes it at once): the tracker must know this
  // instance before the frames its resume point brings again, or it takes
  // them for repeats already answered (History::republishResult).
  ctx.setState("running");
  ctx.bus().publish(channel::kResumePoint, resume_point);
  if (resume_point.first_missing_frame == 0)
    spdlog::info("mapper: resuming at frame 0 (no KF keyframe in the keyframe store yet)");
  else if (resume_point.first_missing_frame > 0)
    spdlog::info("mapper: resuming after frame {} (the newest in the keyframe store)", resume_point.first_missing_frame - 1);
  const MapperParams& params = settings.params;
  spdlog::info("mapper: KF strategy {} (kappa {}), re-integration {} (m = {}), streaming radius {} m, {}",
               fusion::toString(params.fusion.strategy), params.fusion.kappa, toString(params.mode), params.m,
               params.volume.streaming_radius,
               settings.wait_for_optimiser ? "final pass after the optimiser's done" : "final pass after the last frame");
}

// Until the stream is over or a stop is requested: the resume point and the
// live numbers again once a second (a frame source that missed the point
// still finds it) and the progress log every mapper.progress_interval_s.
void serveTheStream(ServiceContext& ctx, Inbox& inbox, const Settings& settings,
                    const rekon_msgs::resume_point_t& resume_point) {
  auto last_resume_point = std::chrono::steady_clock::now();
  auto last_progress = std::chrono::steady_clock::now();
  while (!ctx.stopRequested()) {
    if (inbox.streamOver(settings.wait_for_optimiser, settings.baseline_wanted)) break;
    if (std::chrono::steady_clock::now() - last_resume_point > std::chrono::seconds(1)) {
      last_resume_point = std::chrono::steady_clock::now();
      ctx.bus().publish(channel::kResumePoint, resume_point);
      inbox.publishLive();
    }
    if (std::chrono::steady_clock::now() - last_progress > settings.progress_every) {
      last_progress = std::chrono::steady_clock::now();
      inbox.logProgress();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

// The final pass (after a clean end), the last mesh update, the files in the
// output folder and the stats.
void finishAndWrite(ServiceContext& ctx, const Settings& settings, Mapper& mapper, MappingWorker& worker,
                    MeshPublisher& mesh, const Inbox& inbox, bool clean) {
  worker.finish(clean);
  mesh.finish(mapper, clean ? BlockCause::kFinalPass : BlockCause::kNewData);  // the last update: a subscriber's map now equals mesh.ply
  if (!ctx.outDir().empty()) {
    writeMesh(mapper, ctx.outDir());
    if (settings.baseline_wanted && !worker.baselineWritten()) writeUncorrectedMesh(mapper, ctx.outDir());
  }
  mesh.waitUntilSent();
  recordStats(ctx, mapper, settings.params, inbox.counts(), mesh.stats());
}

// The clean end, once the outputs are written: the store is marked finished
// before done_t, so an instance killed from here on and restarted finds its
// work done (sayTheEndAgain) instead of waiting for a stream that has ended.
void endTheRun(ServiceContext& ctx, const Settings& settings, Mapper& mapper, int64_t end_frame) {
  mapper.markRunFinished(end_frame);
  publishDone(ctx, end_frame);
  if (settings.remove_store_at_end) mapper.removeStore();
}

// A restart of a mapper whose run had finished: its outputs and stats file
// stay as they are; the resume point past the end and done_t go out again
// for the watchers, which count this new instance as unfinished.
void sayTheEndAgain(ServiceContext& ctx, const Settings& settings, Mapper& mapper, int64_t end_frame) {
  spdlog::info("keyframe store '{}': its run finished at frame {} and its outputs are written; saying done again",
               settings.params.store.segment, end_frame);
  ctx.keepEarlierStatsFile();
  rekon_msgs::resume_point_t resume_point = resumePoint(ctx, mapper, true);
  resume_point.first_missing_frame = end_frame + 1;
  ctx.bus().publish(channel::kResumePoint, resume_point);
  ctx.setState("finishing");
  endTheRun(ctx, settings, mapper, end_frame);
}

}  // namespace

void runMapperService(ServiceContext& ctx) {
  const Settings settings = readSettings(ctx);
  // This thread and every thread it starts (the bus thread, started before, keeps its priority).
  applyNice(settings.nice, "mapper.nice");
  Mapper mapper(settings.params);
  if (const auto end = mapper.finishedRunEnd()) return sayTheEndAgain(ctx, settings, mapper, *end);
  Inbox inbox(ctx, settings.max_queued_frames, settings.drop_when_full);
  MeshPublisher mesh(ctx, settings.mesh, settings.params.volume);
  MappingWorker worker(ctx, mapper, inbox, mesh);
  StopThreadsOnExit stop_threads(ctx);  // before the state above dies: the bus handlers use it
  const rekon_msgs::resume_point_t resume_point = resumePoint(ctx, mapper, settings.params.resume);
  inbox.resumeFrom(resume_point.first_missing_frame, settings.rewind_wait_s);
  inbox.subscribe();
  mesh.subscribe();
  std::thread worker_thread([&] { worker.run(); });

  announceStart(ctx, settings, resume_point);
  serveTheStream(ctx, inbox, settings, resume_point);
  const bool clean = !ctx.stopRequested();
  ctx.setState("finishing");
  inbox.drain();
  worker_thread.join();
  ctx.stopThreads();  // no handler runs after this
  inbox.dropUnjoinedFrames();

  const std::string worker_error = inbox.workerError();
  if (!worker_error.empty()) {
    // As the tracker: the outputs first, so that what was fused is kept; then
    // the worker's error, which a second failure while writing must not hide.
    try {
      finishAndWrite(ctx, settings, mapper, worker, mesh, inbox, false);
    } catch (...) {
      spdlog::error("{}", currentExceptionLine());
    }
    throw Error(worker_error);
  }
  finishAndWrite(ctx, settings, mapper, worker, mesh, inbox, clean);
  if (clean) endTheRun(ctx, settings, mapper, inbox.endFrame());
}

}  // namespace rekon::mapper
