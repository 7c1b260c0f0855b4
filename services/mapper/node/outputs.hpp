#pragma once
// What the mapper leaves in the output folder: mapper_timing.csv and
// mapper_reintegration.csv as the run goes (tools/report/README.md reads
// them); at the end mesh.ply and mesh_uncorrected.ply (the paper's
// baseline), done_t for the services downstream, its stats and a summary
// line in the log.
#include <cstdint>
#include <optional>
#include <string>

#include "inbox.hpp"
#include "mesh_publisher.hpp"
#include "rekon/common/csv_log.hpp"
#include "rekon/common/service.hpp"
#include "rekon/mapper/mapper.hpp"

namespace rekon::mapper {

// One row of mapper_timing.csv: the wall time of a frame, split into keyframe
// fusion and the integration of a KF keyframe it closed.
struct FrameTiming {
  int64_t frame_id;
  double ms, fuse_ms, integrate_ms;
};
// What a row of mapper_reintegration.csv records: a graph update applied (its
// round at once, or with mapper.round_budget_ms only queued), a piece of the
// queued round corrected later, or a run of the final pass.
enum class RoundKind { kGraphUpdate, kPiece, kFinalPass };
// One row of mapper_reintegration.csv.
struct RoundRecord {
  double time_s;
  int64_t graph_version;
  ReintegrationRound round;
  RoundKind kind;
  int64_t frames_fused;  // by then: rounds against the scan's length
};

// mapper_timing.csv and mapper_reintegration.csv, a row as each frame or
// round is done (common/csv_log.hpp: a killed mapper keeps its rows). Each
// file is created at its first row, so a mapper restarted after its run
// finished, which does no work, leaves that run's tables as they are.
class TimingTables {
 public:
  // "" = no files; `append`: a restarted mapper (mapper.resume) adds to its killed instance's rows.
  TimingTables(std::string out_dir, bool append) : dir_(std::move(out_dir)), append_(append) {}
  void add(const FrameTiming& r);
  void add(const RoundRecord& r);

 private:
  std::string dir_;
  bool append_;
  std::optional<CsvLog> frames_, rounds_;
};

// mesh_uncorrected.ply: every KF keyframe at the pose of its first integration.
void writeUncorrectedMesh(const Mapper& mapper, const std::string& out_dir);
// mesh.ply, in pieces.
void writeMesh(const Mapper& mapper, const std::string& out_dir);
// done_t after a clean end, so that the services downstream may finish.
void publishDone(ServiceContext& ctx, int64_t last_frame_id);
// ctx.stats() (written to <out>/mapper_stats.json at exit) and a summary in the log.
void recordStats(ServiceContext& ctx, const Mapper& mapper, const MapperParams& params, const InboxCounts& inbox,
                 const MeshPublisherStats& mesh);

}  // namespace rekon::mapper
