#pragma once
// Keyframe fusion (paper section 3, after Meilland & Comport 2013): input
// frames are fused into a KF keyframe, depth by the weighted average of
// eq. (1) with weights w_z = cos(theta) / Z^2, color by the weighted median of
// the unsharp-masked input colors seen from the fused depth, weighted by
// w_b * w_z (w_b: one minus the Crete-Roffet 2007 blur of the frame).
// The color median is by luma (0.114 B + 0.587 G + 0.299 R of the bilinear
// sample): of a pixel's observations in luma order (ties: the earlier input),
// the first whose cumulative weight reaches half the total gives its whole
// color (the sample rounded to 8 bits; no mixed hues). Float sums: the same
// result as sorting up to rounding (measured on 7-Scenes, TUM teddy and the
// synthetic room against the sorting version: 15-54 of 3.07 M pixels differ,
// by at most 10 levels; tests/mapper/test_fusion.cpp).
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon::fusion {

// When a new KF keyframe starts (paper section 4.2).
enum class KeyframeStrategy {
  kConst,    // KF_CONST: a constant number kappa of frames per KF keyframe
  kDvo,      // KF_DVO: with every new DVO keyframe
  kDist,     // KF_DIST: translation or rotation from the KF keyframe beyond a threshold
  kOverlap,  // KF_OVRLP: fraction of KF keyframe pixels visible in the frame below a threshold
};
KeyframeStrategy parseStrategy(const std::string& text);  // "const" | "dvo" | "dist" | "overlap"
std::string toString(KeyframeStrategy s);

struct FusionParams {
  static constexpr int kDefaultKappa = 20;
  // Every strategy closes a KF keyframe after this many frames: each open
  // frame keeps ~3.4 MB of color input (640x480) until the color fusion, so a
  // still camera under dvo, dist or overlap would otherwise grow without bound.
  // 50 frames: 1.7 s at 30 Hz, ~170 MB at 640x480.
  static constexpr int kDefaultMaxFramesPerKeyframe = 50;
  static constexpr double kDefaultDistTranslation = 0.1;   // metres
  static constexpr double kDefaultDistRotationDeg = 10.0;
  static constexpr double kDefaultMinOverlap = 0.7;
  static constexpr double kDefaultMinDepth = 0.1;           // metres
  static constexpr double kDefaultMaxDepth = 4.0;
  // A pixel whose 4-neighbour differs by more than this fraction of its depth
  // sits on a discontinuity and is dropped (mixed foreground/background depth).
  static constexpr double kDefaultMaxDepthStep = 0.03;
  // A warped pixel more than this fraction of depth behind or in front of the
  // keyframe's depth is another surface: behind is occluded and skipped, in
  // front replaces what the keyframe had.
  static constexpr double kDefaultDepthAgreement = 0.04;
  static constexpr double kDefaultUnsharpSigma = 1.0;   // pixels, Gaussian of the unsharp mask
  static constexpr double kDefaultUnsharpAmount = 0.5;  // sharp = I + amount (I - blur(I))

  KeyframeStrategy strategy = KeyframeStrategy::kConst;
  int kappa = kDefaultKappa;
  int max_frames_per_keyframe = kDefaultMaxFramesPerKeyframe;
  double dist_translation = kDefaultDistTranslation;
  double dist_rotation_deg = kDefaultDistRotationDeg;
  double min_overlap = kDefaultMinOverlap;
  double min_depth = kDefaultMinDepth;
  double max_depth = kDefaultMaxDepth;
  double max_depth_step = kDefaultMaxDepthStep;
  double depth_agreement = kDefaultDepthAgreement;
  double unsharp_sigma = kDefaultUnsharpSigma;
  double unsharp_amount = kDefaultUnsharpAmount;

  void validate() const;  // rekon::Error naming the key
};

// Reads mapper.strategy, kappa, dist_*, min_overlap, max_depth_step, ...
FusionParams fusionParamsFromConfig(const Config& config);

// One fused KF keyframe: images in the KF keyframe's camera, and its pose
// relative to the DVO keyframe it is anchored to.
struct FusedKeyframe {
  int64_t id = -1;
  int64_t anchor_keyframe_id = -1;  // DVO keyframe
  Pose pose_in_anchor = Pose::Identity();
  int64_t first_frame_id = -1, last_frame_id = -1;
  double timestamp = 0.0;
  int frames = 0;
  cv::Mat depth;   // CV_32F metres, 0 = none
  cv::Mat weight;  // CV_32F, W* of eq. (1)
  cv::Mat color;   // CV_8UC3 BGR
};

// w_z = cos(theta) / Z^2 per pixel (0 where depth is missing, out of range or
// on a discontinuity). depth_m: CV_32F metres.
cv::Mat depthWeights(const cv::Mat& depth_m, const Intrinsics& k, const FusionParams& p);
// Crete-Roffet et al. 2007 no-reference blur in [0, 1] (0 sharp, 1 blurred) of a BGR image.
double blurriness(const cv::Mat& color_bgr);
// I + amount (I - Gaussian(I, sigma)), saturated to 8 bits.
cv::Mat unsharpMask(const cv::Mat& color_bgr, double sigma, double amount);
// Fraction of the keyframe's valid pixels (sampled every 4th) that land in the
// frame's image at camera_from_keyframe.
double overlapRatio(const cv::Mat& keyframe_depth, const Intrinsics& k, const Pose& frame_from_keyframe);

class KeyframeFuser {
 public:
  KeyframeFuser(const FusionParams& params, const Intrinsics& k);

  bool active() const { return open_; }
  int frames() const { return frames_; }
  // Bytes of color input held for the open KF keyframe's color fusion.
  size_t heldInputBytes() const;
  // Whether `frame` should start a new KF keyframe (strategy of the params,
  // or max_frames_per_keyframe reached); true when none is open.
  bool startsNewKeyframe(int64_t dvo_keyframe_id, const Pose& camera_to_world) const;
  // Opens a KF keyframe at this frame; its pose is the frame's pose.
  void begin(int64_t kf_id, int64_t anchor_keyframe_id, const Pose& pose_in_anchor, const Pose& camera_to_world);
  // The open KF keyframe as fused so far (its anchor and pose in it set by begin()).
  const FusedKeyframe& openKeyframe() const { return kf_; }
  // The open KF keyframe's world pose now (a graph update moved its DVO
  // keyframe): the next frames' world poses are taken relative to it.
  void moveTo(const Pose& camera_to_world) { kf_world_ = camera_to_world; }
  // Fuses the frame's depth now (eq. 1); keeps its color for the color fusion.
  void add(const RgbdFrame& frame, const Pose& camera_to_world);
  // Color fusion, then returns the keyframe and closes it.
  FusedKeyframe finish();

 private:
  struct ColorInput {
    cv::Mat sharp;         // unsharp-masked BGR
    cv::Mat depth_weight;  // CV_32FC2: depth in metres (occlusion test) and w_b * w_z, side by side (one cache line)
    Pose keyframe_to_camera;
  };
  FusionParams params_;
  Intrinsics k_;
  FusedKeyframe kf_;
  Pose kf_world_ = Pose::Identity();
  int64_t dvo_keyframe_id_ = -1;
  int frames_ = 0;
  bool open_ = false;
  std::vector<ColorInput> inputs_;
};

}  // namespace rekon::fusion
