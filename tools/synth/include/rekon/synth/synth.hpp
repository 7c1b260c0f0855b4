#pragma once
// rekon's own ground truth: analytic scenes ray cast into RGB-D frames with
// optional Kinect-like noise, their exact colored surface, and their camera
// trajectories. Used by `rekon synth` and by tests of every other component.
#include <cstdint>
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
  // "room", "corridor" or "tabletop"; throws rekon::Error naming the choices otherwise.
  static std::unique_ptr<Scene> make(const std::string& name);
  virtual ~Scene() = default;

  virtual std::string name() const = 0;
  virtual int defaultFrames() const = 0;
  // Camera-to-world poses at 30 Hz (timestamps i / 30); deterministic for a seed.
  virtual Trajectory trajectory(int frames, uint64_t seed) const = 0;
  // The exact scene surface with colors.
  virtual Mesh groundTruthMesh() const = 0;

  // Ray casts one frame at `camera_to_world`. With Noise::None depth is exact up
  // to the 16-bit quantisation of depth_scale; `seed` makes the noise repeatable.
  virtual RgbdFrame render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed) const = 0;
};

struct SequenceOptions {
  std::string scene = "room";
  int frames = 0;  // 0 = the scene's default
  uint64_t seed = 1;
  Noise noise = Noise::Kinect;
  // Random-walk drift for drifted_trajectory.txt; both 0 = not written.
  double drift_translation_per_m = 0.0;
  double drift_rotation_deg_per_m = 0.0;
};

// Writes a TUM-layout sequence (rgb/, depth/, rgb.txt, depth.txt,
// groundtruth.txt, camera.yaml, mesh_gt.ply, and drifted_trajectory.txt when
// drift is set) into `out_dir`.
void writeSequence(const SequenceOptions& options, const std::string& out_dir);

}  // namespace rekon::synth
