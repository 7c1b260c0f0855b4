// `rekon remesh` and `rekon export` (commands.hpp): a session folder
// (services/mapper/src/store/SESSION.md) read back without the frames.
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <filesystem>

#include "commands.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/mapper/store/session.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace rekon {
namespace {

namespace fs = std::filesystem;
using store::Session;
using volume::TsdfVolume;
using volume::VolumeParams;

struct Remeshed {
  int keyframes = 0, without_pose = 0;
  int64_t blocks = 0, vertices = 0, triangles = 0;
  double seconds = 0;
};

// Every keyframe of the session integrated at its newest pose (its anchor's
// pose in anchors.txt) into a fresh volume of `params`, its mesh written to
// `ply_path` in pieces (a long session's mesh is never held whole).
Remeshed remesh(const Session& session, const VolumeParams& params, const std::string& ply_path) {
  const auto start = std::chrono::steady_clock::now();
  TsdfVolume volume(params);
  Remeshed r;
  const size_t n = session.keyframes().size();
  for (size_t i = 0; i < n; ++i) {
    const auto pose = session.worldPose(session.keyframes()[i]);
    if (!pose) {
      ++r.without_pose;
      continue;
    }
    const fusion::FusedKeyframe kf = session.load(i);
    volume.streamAround(pose->translation());
    volume.integrate(kf.depth, kf.color, kf.weight, session.info().camera, *pose);
    ++r.keyframes;
    if ((i + 1) % 20 == 0) spdlog::info("integrated {} of {} keyframes", i + 1, n);
  }
  if (r.without_pose > 0)
    spdlog::warn("{} keyframe(s) have no anchor pose in {}/anchors.txt (in flight when the run ended); left out",
                 r.without_pose, session.dir());
  if (r.keyframes == 0) throw Error(session.dir() + " has no keyframe with a pose to integrate; was the run stopped before its first keyframe?");
  PlyWriter ply(ply_path, true);
  volume.extractMeshInPieces([&ply](const Mesh& piece) { ply.add(piece); });
  ply.finish();
  r.vertices = ply.vertices();
  r.triangles = ply.faces();
  r.blocks = volume.stats().blocks;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return r;
}

VolumeParams sessionVolume(const Session& session) {
  VolumeParams p;
  p.voxel_size = session.info().voxel_size;
  p.truncation = session.info().truncation;
  p.max_depth = session.info().max_depth;
  return p;
}

void writeTrajectories(const Session& session, const std::string& out) {
  Trajectory frames, keyframes;
  size_t without_pose = 0;
  for (const store::SessionFrame& f : session.frames()) {
    const auto anchor = session.anchors().find(f.keyframe_id);
    if (anchor == session.anchors().end()) {
      ++without_pose;
      continue;
    }
    frames.push_back({f.timestamp, orthonormalised(anchor->second * f.pose_in_keyframe)});
  }
  for (const auto& kf : session.keyframes()) {
    if (const auto pose = session.worldPose(kf)) keyframes.push_back({kf.timestamp, *pose});
  }
  if (without_pose > 0) spdlog::warn("{} frame(s) name a keyframe without a pose; left out of trajectory.txt", without_pose);
  writeTumTrajectory(frames, (fs::path(out) / "trajectory.txt").string());
  writeTumTrajectory(keyframes, (fs::path(out) / "keyframes.txt").string());
  spdlog::info("wrote {} frame poses (trajectory.txt) and {} KF keyframe poses (keyframes.txt)", frames.size(),
               keyframes.size());
}

}  // namespace

int remeshCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Rebuild a session's map at other settings from its keyframes, without re-tracking");
  args.positional("session", "a session folder (rekon run --session)")
      .option("out", "output mesh (binary PLY)")
      .option("voxel", "voxel size in metres (default: the session's)")
      .option("truncation", "truncation distance in metres (default: the session's)")
      .option("max-depth", "ignore depth beyond this many metres (default: the session's)")
      .option("backend", "auto, cpu or cuda", "auto")
      .examples("rekon remesh out/7s_session --out out/7s_5mm.ply --voxel 0.005   # the same scan at 5 mm\n"
                "rekon remesh out/7s_session --out out/7s_near.ply --max-depth 2  # only what was seen within 2 m\n"
                "  (a session comes from rekon run ... --session out/7s_session)");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("out")) throw Error("rekon remesh: --out is required (see --help)");
  const Session session = Session::open(args.get("session"));
  VolumeParams params = sessionVolume(session);
  if (args.has("voxel")) params.voxel_size = args.getDouble("voxel");
  if (args.has("truncation")) params.truncation = args.getDouble("truncation");
  if (args.has("max-depth")) params.max_depth = args.getDouble("max-depth");
  params.backend = args.get("backend");
  params.validate();
  const Remeshed r = remesh(session, params, args.get("out"));
  spdlog::info("remesh: {} keyframes at {} m voxels in {:.2f} s: {} vertices, {} triangles -> {}", r.keyframes,
               params.voxel_size, r.seconds, r.vertices, r.triangles, args.get("out"));
  std::printf("keyframes=%d seconds=%.3f blocks=%lld triangles=%lld\n", r.keyframes, r.seconds,
              static_cast<long long>(r.blocks), static_cast<long long>(r.triangles));
  return 0;
}

int exportCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Write a session's trajectory, pose graph and mesh in formats other tools read");
  args.positional("session", "a session folder (rekon run --session)")
      .option("out", "output folder (created; not the session itself)")
      .examples("rekon export out/7s_session --out out/7s_export   # trajectory.txt, keyframes.txt, graph.g2o, mesh.ply\n"
                "evo_traj tum out/7s_export/trajectory.txt --plot     # e.g. with evo");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("out")) throw Error("rekon export: --out is required (see --help)");
  const Session session = Session::open(args.get("session"));
  const fs::path out = fs::absolute(args.get("out"));
  std::error_code ec;
  if (fs::equivalent(out, fs::absolute(session.dir()), ec))
    throw Error("rekon export: --out is the session folder itself; give another folder (the session is never written to)");
  fs::create_directories(out, ec);
  if (ec) throw Error("rekon export: cannot create " + out.string() + " (" + ec.message() + ")");
  writeTrajectories(session, out.string());
  const fs::path graph = fs::path(session.dir()) / "graph.g2o";
  if (fs::exists(graph)) {
    fs::copy_file(graph, out / "graph.g2o", fs::copy_options::overwrite_existing);
    spdlog::info("wrote the pose graph (g2o) to {}", (out / "graph.g2o").string());
  } else {
    spdlog::warn("{} has no graph.g2o (a run without the optimiser, or stopped before its first optimisation)", session.dir());
  }
  const Remeshed r = remesh(session, sessionVolume(session), (out / "mesh.ply").string());
  spdlog::info("export: {} keyframes, mesh of {} triangles in {:.2f} s -> {}", r.keyframes, r.triangles,
               r.seconds, out.string());
  return 0;
}

}  // namespace rekon
