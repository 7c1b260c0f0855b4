#pragma once
// The one implementation of Scene: an analytic SceneModel, its materials and a
// trajectory generator. The named scenes (scenes.cpp) are instances of it.
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "geometry.hpp"
#include "rekon/synth/synth.hpp"
#include "texture.hpp"

namespace rekon::synth {

class AnalyticScene : public Scene {
 public:
  using TrajectoryFn = std::function<Trajectory(int frames, uint64_t seed)>;
  using LapTrajectoryFn = std::function<Trajectory(int frames, uint64_t seed, int laps)>;
  using LapFramesFn = std::function<int(int laps)>;
  // A scene walked once.
  AnalyticScene(std::string name, SceneModel model, std::vector<Material> materials, int default_frames,
                double mesh_spacing_m, TrajectoryFn trajectory);
  // A scene whose trajectory can be walked any number of laps.
  AnalyticScene(std::string name, SceneModel model, std::vector<Material> materials, double mesh_spacing_m,
                LapFramesFn default_frames, LapTrajectoryFn trajectory);

  std::string name() const override { return name_; }
  int defaultFrames() const override { return defaultFrames(1); }
  int defaultFrames(int laps) const override;
  Trajectory trajectory(int frames, uint64_t seed) const override { return trajectory(frames, seed, 1); }
  Trajectory trajectory(int frames, uint64_t seed, int laps) const override;
  Mesh groundTruthMesh() const override { return groundTruthMesh(mesh_spacing_m_); }
  Mesh groundTruthMesh(double vertex_spacing_m) const override;
  RgbdFrame render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed) const override;
  RgbdFrame render(const Intrinsics& k, const Pose& camera_to_world, Noise noise, uint64_t seed,
                   int threads) const override;

  const SceneModel& model() const { return model_; }
  const std::vector<Material>& materials() const { return materials_; }

 private:
  std::string name_;
  SceneModel model_;
  std::vector<Material> materials_;
  double mesh_spacing_m_;
  LapFramesFn default_frames_;
  LapTrajectoryFn trajectory_;
  bool has_laps_ = false;

  void checkLaps(int laps) const;
};

std::unique_ptr<AnalyticScene> makeTabletopScene();
std::unique_ptr<AnalyticScene> makeRoomScene();
std::unique_ptr<AnalyticScene> makeCorridorScene();
std::unique_ptr<AnalyticScene> makeBuildingScene();

// Triangulates every visible surface of the model with vertices about
// `spacing_m` apart, colored by the texture filtered at that spacing.
Mesh triangulate(const SceneModel& model, const std::vector<Material>& materials, double spacing_m);

}  // namespace rekon::synth
