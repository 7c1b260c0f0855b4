#include "analytic_scene.hpp"

#include <fmt/format.h>

#include <thread>

#include "raycast.hpp"
#include "rekon/common/error.hpp"
#include "sensor_noise.hpp"

namespace rekon::synth {

Intrinsics defaultIntrinsics() { return Intrinsics{}; }

uint64_t frameSeed(uint64_t seed, int64_t frame) { return mixSeed(seed, static_cast<uint64_t>(frame) + 1); }

Noise parseNoise(const std::string& text) {
  if (text == "none") return Noise::None;
  if (text == "kinect") return Noise::Kinect;
  throw Error("unknown noise model '" + text + "'; choose kinect or none");
}

std::unique_ptr<Scene> Scene::make(const std::string& name) {
  if (name == "tabletop") return makeTabletopScene();
  if (name == "room") return makeRoomScene();
  if (name == "corridor") return makeCorridorScene();
  if (name == "building") return makeBuildingScene();
  throw Error("unknown scene '" + name + "'; choose room, corridor, tabletop or building");
}

AnalyticScene::AnalyticScene(std::string name, SceneModel model, std::vector<Material> materials, int default_frames,
                             double mesh_spacing_m, TrajectoryFn trajectory)
    : name_(std::move(name)),
      model_(std::move(model)),
      materials_(std::move(materials)),
      mesh_spacing_m_(mesh_spacing_m),
      default_frames_([default_frames](int) { return default_frames; }),
      trajectory_([fn = std::move(trajectory)](int frames, uint64_t seed, int) { return fn(frames, seed); }) {}

AnalyticScene::AnalyticScene(std::string name, SceneModel model, std::vector<Material> materials, double mesh_spacing_m,
                             LapFramesFn default_frames, LapTrajectoryFn trajectory)
    : name_(std::move(name)),
      model_(std::move(model)),
      materials_(std::move(materials)),
      mesh_spacing_m_(mesh_spacing_m),
      default_frames_(std::move(default_frames)),
      trajectory_(std::move(trajectory)),
      has_laps_(true) {}

void AnalyticScene::checkLaps(int laps) const {
  if (laps < 1) throw Error("scene " + name_ + ": " + std::to_string(laps) + " laps; give 1 or more");
  if (laps > 1 && !has_laps_) throw Error("scene " + name_ + " is walked once; --laps is for the corridor and the building");
  // The walk is integrated at 600 Hz in memory; 1000 laps (about 42 h) is far beyond any use.
  if (laps > 1000) throw Error("scene " + name_ + ": " + std::to_string(laps) + " laps is too many; give at most 1000");
}

int AnalyticScene::defaultFrames(int laps) const {
  checkLaps(laps);
  return default_frames_(laps);
}

Trajectory AnalyticScene::trajectory(int frames, uint64_t seed, int laps) const {
  if (frames < 0) throw Error("scene " + name_ + ": frame count " + std::to_string(frames) + " is negative; give 0 or more");
  checkLaps(laps);
  return trajectory_(frames, seed, laps);
}

Mesh AnalyticScene::groundTruthMesh(double vertex_spacing_m) const {
  if (!(vertex_spacing_m >= 1e-3 && vertex_spacing_m <= 1.0)) {
    throw Error("scene " + name_ + ": mesh vertex spacing " + fmt::format("{}", vertex_spacing_m) +
                " m is out of range; give 0.001 to 1 m");
  }
  return triangulate(model_, materials_, vertex_spacing_m);
}

RgbdFrame AnalyticScene::render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed) const {
  return render(k, camera_to_world, noise, seed, static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
}

RgbdFrame AnalyticScene::render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed,
                                int threads) const {
  k.validate("scene " + name_ + " render");
  requireValidPose(camera_to_world, "scene " + name_ + " render");
  const RayCastImage image = rayCast(model_, materials_, k, camera_to_world, threads);
  RgbdFrame frame;
  if (noise == Noise::None) {
    frame.depth = exactDepth(image, k.depth_scale);
    frame.color = exactColor(image);
  } else {
    frame.depth = kinectDepth(image, k.depth_scale, mixSeed(seed, 1), threads);
    frame.color = kinectColor(image, mixSeed(seed, 2), threads);
  }
  return frame;
}

}  // namespace rekon::synth
