#pragma once
// The table of `rekon` subcommands.
#include <vector>

namespace rekon {

struct Command {
  const char* name;
  const char* summary;
  int (*main)(int argc, char** argv);  // argv[0] is "rekon NAME"
};

const std::vector<Command>& commands();

// `rekon fuse`: integrates a TUM-layout dataset at given poses into the TSDF
// volume and writes its mesh (e.g. the reference mesh from ground truth).
int fuseCommand(int argc, char** argv);
// `rekon odometry`: the DVO tracker in-process on a TUM-layout dataset; writes
// every frame's world pose as a TUM trajectory.
int odometryCommand(int argc, char** argv);
// `rekon keyframes --list | --export DIR | --remove [--segment NAME]`: the
// mapper's shared-memory keyframe store, read from another process.
int keyframesCommand(int argc, char** argv);
// `rekon cameras`: the connected RGB-D cameras (driver, URI, serial, modes);
// exit 1 when there is none.
int camerasCommand(int argc, char** argv);
// `rekon view [--port N] [--bind ADDR] [--config FILE] [--set key=value]`:
// rekon-viewer (the live web page of whatever runs on the bus) in the foreground.
int viewCommand(int argc, char** argv);
// `rekon remesh SESSION --out MESH [--voxel V] [--truncation T] [--max-depth D]`:
// a session's keyframes at their final poses into a fresh volume.
int remeshCommand(int argc, char** argv);
// `rekon export SESSION --out DIR`: trajectory.txt, keyframes.txt, graph.g2o and mesh.ply.
int exportCommand(int argc, char** argv);
// `rekon import bag FILE --out DATASET | --list`: python/rekon/bag.py in the project's .venv.
int importCommand(int argc, char** argv);
// `rekon spy [--lcm-url URL]`: lcm-spy with build/java/rekon_msgs.jar on the run's bus.
int spyCommand(int argc, char** argv);

}  // namespace rekon
