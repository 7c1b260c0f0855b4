#pragma once
// rekon's own ground truth: analytic scenes ray cast into RGB-D frames with
// optional Kinect-like noise, their exact colored surface, and their camera
// trajectories. Used by `rekon synth` and by tests of every other component.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "rekon/common/camera.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::synth {

enum class Noise { None, Kinect };

// The default camera of every synthetic sequence (640x480, f = 525, depth_scale 5000).
Intrinsics defaultIntrinsics();

class Scene {
 public:
  // "room", "corridor", "tabletop" or "building"; throws rekon::Error naming the choices otherwise.
  static std::unique_ptr<Scene> make(const std::string& name);
  virtual ~Scene() = default;

  virtual std::string name() const = 0;
  virtual int defaultFrames() const = 0;
  // Frames of `laps` walks round the scene's path (the corridor: out, back,
  // and again; the building: its three laps in turn; the other scenes are
  // walked once and throw for laps > 1).
  virtual int defaultFrames(int laps) const = 0;
  // Camera-to-world poses at 30 Hz (timestamps i / 30); deterministic for a seed.
  virtual Trajectory trajectory(int frames, uint64_t seed) const = 0;
  // The same over `laps` laps; the first lap's poses equal the one-lap
  // trajectory's until it slows down for its end. The building walks further
  // laps when `frames` asks for more than `laps` give.
  virtual Trajectory trajectory(int frames, uint64_t seed, int laps) const = 0;
  // The exact scene surface with colors: every surface a camera inside the
  // scene can see (faces resting on the floor or against a wall, and the floor
  // under objects, are left out), triangulated with vertices a scene-specific
  // spacing apart (tabletop and room 2 cm, corridor 3 cm, building 5 cm). Planar faces are
  // exact; curved ones are within 0.2 mm. Vertex colors are the texture of
  // render() (Noise::None) filtered at the vertex spacing.
  virtual Mesh groundTruthMesh() const = 0;
  virtual Mesh groundTruthMesh(double vertex_spacing_m) const = 0;

  // Ray casts one frame at `camera_to_world`. With Noise::None depth is exact up
  // to the 16-bit quantisation of depth_scale; `seed` makes the noise repeatable.
  // Uses every hardware thread; id and timestamp of the frame are left 0.
  virtual RgbdFrame render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed) const = 0;
  // The same with an explicit number of worker threads (1 = the calling thread only).
  virtual RgbdFrame render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed,
                           int threads) const = 0;
};

// The voxel blocks a TSDF map of `mesh` holds at most: every block within
// the truncation band of a triangle whose centroid lies at or below max_z_m
// (the building's walk never sees its ceiling within the depth range).
// Exact for axis-aligned faces; a slanted triangle counts its bounding box.
struct BandOptions {
  double voxel_m = 0.01;
  double truncation_m = 0.04;
  int block_voxels = 8;
  double max_z_m = 1e9;
};
int64_t surfaceBandBlocks(const Mesh& mesh, const BandOptions& options);

// The noise seed of frame `frame` of a sequence of seed `seed`: what
// writeSequence renders frame `frame` with, so a source that renders on the
// fly sends the frames a written sequence holds.
uint64_t frameSeed(uint64_t seed, int64_t frame);

// "none" or "kinect"; throws rekon::Error otherwise.
Noise parseNoise(const std::string& text);

// The ground truth perturbed by a random walk on SE(3): each frame-to-frame
// motion is composed with a random increment whose standard deviation grows
// with the distance travelled, so that the relative pose error over one metre
// has an rms of `translation_per_m` metres (per axis / sqrt(3)) and
// `rotation_deg_per_m` degrees. The first pose is kept.
Trajectory driftedTrajectory(const Trajectory& ground_truth, double translation_per_m, double rotation_deg_per_m,
                             uint64_t seed);

struct SequenceOptions {
  std::string scene = "room";
  int frames = 0;  // 0 = the scene's default for `laps`
  int laps = 1;    // corridor only: times round the out-and-back path
  uint64_t seed = 1;
  Noise noise = Noise::Kinect;
  // 0: color as PNG (lossless). 1-100: color as JPEG of that quality, about a
  // fifth of the PNG's bytes, for a cache of a long scan (rekon bench longrun
  // --dataset); the depth stays PNG.
  int jpeg_quality = 0;
  // Random-walk drift for drifted_trajectory.txt; both 0 = not written.
  double drift_translation_per_m = 0.0;
  double drift_rotation_deg_per_m = 0.0;
  // Called after each frame written (from any worker thread): frames done, frames in all.
  std::function<void(int, int)> on_frame;
};

// The truth of a walk through `scene` seen by camera `k`, beside the frames
// that render it (writeSequence) or the run that fused them (rekon bench
// longrun): groundtruth.txt (TUM), camera.yaml and mesh_gt.ply,
// for rekon eval traj and rekon eval surface. Returns the mesh's vertices.
size_t writeGroundTruth(const Scene& scene, const Trajectory& trajectory, const Intrinsics& k, const std::string& out_dir);

// What writeSequence did, for the caller to report.
struct SequenceReport {
  int frames = 0;
  double seconds = 0.0;  // wall time
  size_t mesh_vertices = 0;
};
// Writes a TUM-layout sequence (rgb/, depth/, rgb.txt, depth.txt,
// groundtruth.txt, camera.yaml, mesh_gt.ply, and drifted_trajectory.txt when
// drift is set) into `out_dir`.
SequenceReport writeSequence(const SequenceOptions& options, const std::string& out_dir);
// The same with its progress on the terminal (rekon synth, rekon demo).
SequenceReport writeSequenceShowingProgress(SequenceOptions options, const std::string& out_dir);

// `rekon synth`: the command-line front end of writeSequence.
int synthCommand(int argc, char** argv);

}  // namespace rekon::synth
