#pragma once
// Frames of rekon_synth's `room` for the tracker's tests: exact poses, and
// ways to corrupt a frame (missing depth, black image, a painted patch).
#include <opencv2/core.hpp>

#include <algorithm>
#include <cstdlib>
#include <memory>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"
#include "rekon/synth/synth.hpp"

namespace rekon::tracker::test {

class RoomViews {
 public:
  RoomViews() : scene_(synth::Scene::make("room")), k_(synth::defaultIntrinsics()) {}

  const Intrinsics& intrinsics() const { return k_; }
  // Ground truth of the room's default loop (600 frames, 30 Hz), camera to world.
  Trajectory trajectory(int frames) const { return scene_->trajectory(frames, 1); }
  RgbdFrame render(const Pose& camera_to_world, synth::Noise noise = synth::Noise::None, int64_t id = 0) const {
    RgbdFrame f = scene_->render(k_, camera_to_world, noise, static_cast<uint64_t>(id) + 1);
    f.id = id;
    f.timestamp = static_cast<double>(id) / 30.0;
    return f;
  }

 private:
  std::unique_ptr<synth::Scene> scene_;
  Intrinsics k_;
};

inline RgbdFrame withoutDepth(RgbdFrame f) {
  f.depth = cv::Mat::zeros(f.depth.size(), f.depth.type());
  return f;
}

// Color moved `dx` pixels right and `dy` down against depth (edges
// replicated), as when color is not registered to depth (7-Scenes).
inline RgbdFrame colorShifted(RgbdFrame f, int dx, int dy) {
  cv::Mat shifted;
  const cv::Rect from(std::max(-dx, 0), std::max(-dy, 0), f.color.cols - std::abs(dx), f.color.rows - std::abs(dy));
  cv::copyMakeBorder(f.color(from), shifted, std::max(dy, 0), std::max(-dy, 0), std::max(dx, 0), std::max(-dx, 0),
                     cv::BORDER_REPLICATE);
  f.color = shifted;
  return f;
}

inline RgbdFrame blackImage(RgbdFrame f) {
  f.color = cv::Mat::zeros(f.color.size(), f.color.type());
  return f;
}

}  // namespace rekon::tracker::test
