#include "rekon/fusion/keyframe_fusion.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

#include "rekon/common/error.hpp"

namespace rekon::fusion {

KeyframeStrategy parseStrategy(const std::string& text) {
  if (text == "const") return KeyframeStrategy::kConst;
  if (text == "dvo") return KeyframeStrategy::kDvo;
  if (text == "dist") return KeyframeStrategy::kDist;
  if (text == "overlap") return KeyframeStrategy::kOverlap;
  throw Error("mapper.strategy '" + text + "' is unknown; use const, dvo, dist or overlap");
}

std::string toString(KeyframeStrategy s) {
  switch (s) {
    case KeyframeStrategy::kConst: return "const";
    case KeyframeStrategy::kDvo: return "dvo";
    case KeyframeStrategy::kDist: return "dist";
    case KeyframeStrategy::kOverlap: return "overlap";
  }
  return "?";
}

void FusionParams::validate() const {
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw Error("mapper." + what);
  };
  require(kappa >= 1, "kappa must be at least 1 (frames per KF keyframe)");
  require(dist_translation > 0 && dist_rotation_deg > 0, "dist_translation and dist_rotation_deg must be positive");
  require(min_overlap > 0 && min_overlap < 1, "min_overlap must lie in (0, 1)");
  require(min_depth > 0 && max_depth > min_depth, "min_depth must be positive and below max_depth");
  require(max_depth_step > 0, "max_depth_step must be positive");
  require(depth_agreement > 0, "depth_agreement must be positive");
  require(unsharp_sigma > 0 && unsharp_amount >= 0, "unsharp_sigma must be positive and unsharp_amount not negative");
}

FusionParams fusionParamsFromConfig(const Config& c) {
  FusionParams p;
  p.strategy = parseStrategy(c.getString("mapper.strategy"));
  p.kappa = c.getInt("mapper.kappa");
  p.dist_translation = c.getDouble("mapper.dist_translation");
  p.dist_rotation_deg = c.getDouble("mapper.dist_rotation_deg");
  p.min_overlap = c.getDouble("mapper.min_overlap");
  p.min_depth = c.getDouble("mapper.min_depth");
  p.max_depth = c.getDouble("volume.max_depth");
  p.max_depth_step = c.getDouble("mapper.max_depth_step");
  p.depth_agreement = c.getDouble("mapper.depth_agreement");
  p.unsharp_sigma = c.getDouble("mapper.unsharp_sigma");
  p.unsharp_amount = c.getDouble("mapper.unsharp_amount");
  p.validate();
  return p;
}

namespace {

Eigen::Vector3d backProject(const Intrinsics& k, double u, double v, double z) {
  return {(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z};
}

cv::Mat toMetres(const cv::Mat& raw, double depth_scale) {
  if (raw.type() != CV_16UC1) throw Error("keyframe fusion: depth must be 16-bit (CV_16UC1)");
  cv::Mat m;
  raw.convertTo(m, CV_32F, 1.0 / depth_scale);
  return m;
}

// Bilinear BGR sample; false outside the image.
bool sampleBilinear(const cv::Mat& img, double u, double v, double out[3]) {
  if (u < 0 || v < 0 || u > img.cols - 1 || v > img.rows - 1) return false;
  const int x0 = std::min(static_cast<int>(u), img.cols - 2), y0 = std::min(static_cast<int>(v), img.rows - 2);
  const double a = u - x0, b = v - y0;
  const auto* p00 = img.ptr<cv::Vec3b>(y0) + x0;
  const auto* p10 = img.ptr<cv::Vec3b>(y0 + 1) + x0;
  for (int c = 0; c < 3; ++c)
    out[c] = (1 - a) * (1 - b) * p00[0][c] + a * (1 - b) * p00[1][c] + (1 - a) * b * p10[0][c] + a * b * p10[1][c];
  return true;
}

struct Observation {
  float luma, w;
  cv::Vec3b bgr;
};

}  // namespace

cv::Mat depthWeights(const cv::Mat& depth, const Intrinsics& k, const FusionParams& p) {
  cv::Mat w(depth.size(), CV_32F, cv::Scalar(0));
  const float zmin = static_cast<float>(p.min_depth), zmax = static_cast<float>(p.max_depth);
  const float step = static_cast<float>(p.max_depth_step);
  for (int y = 1; y + 1 < depth.rows; ++y) {
    const float* up = depth.ptr<float>(y - 1);
    const float* row = depth.ptr<float>(y);
    const float* down = depth.ptr<float>(y + 1);
    float* out = w.ptr<float>(y);
    for (int x = 1; x + 1 < depth.cols; ++x) {
      const float z = row[x];
      if (!(z >= zmin && z <= zmax)) continue;
      const float n4[4] = {row[x - 1], row[x + 1], up[x], down[x]};
      bool edge = false;
      for (float zn : n4) edge |= !(zn > 0) || std::abs(zn - z) > step * z;
      if (edge) continue;
      // Depth normal from central differences of the back-projected points.
      const Eigen::Vector3d dx = backProject(k, x + 1, y, n4[1]) - backProject(k, x - 1, y, n4[0]);
      const Eigen::Vector3d dy = backProject(k, x, y + 1, n4[3]) - backProject(k, x, y - 1, n4[2]);
      const Eigen::Vector3d n = dx.cross(dy);
      const double norm = n.norm();
      if (norm <= 0) continue;
      const double cos_theta = std::abs(n.z()) / norm;
      out[x] = static_cast<float>(cos_theta / (static_cast<double>(z) * z));
    }
  }
  return w;
}

double blurriness(const cv::Mat& color_bgr) {
  cv::Mat gray;
  cv::cvtColor(color_bgr, gray, cv::COLOR_BGR2GRAY);
  gray.convertTo(gray, CV_32F);
  // The blur metric re-blurs with a 9-tap box filter along each direction and
  // measures how much neighbour variation the re-blur removes: a sharp image
  // loses much, a blurred one little.
  cv::Mat b_ver, b_hor;
  cv::blur(gray, b_ver, cv::Size(1, 9));
  cv::blur(gray, b_hor, cv::Size(9, 1));
  double s_f_ver = 0, s_v_ver = 0, s_f_hor = 0, s_v_hor = 0;
  for (int y = 1; y < gray.rows; ++y) {
    const float* f0 = gray.ptr<float>(y - 1);
    const float* f1 = gray.ptr<float>(y);
    const float* bv0 = b_ver.ptr<float>(y - 1);
    const float* bv1 = b_ver.ptr<float>(y);
    const float* bh = b_hor.ptr<float>(y);
    for (int x = 1; x < gray.cols; ++x) {
      const double d_f_ver = std::abs(f1[x] - f0[x]), d_b_ver = std::abs(bv1[x] - bv0[x]);
      const double d_f_hor = std::abs(f1[x] - f1[x - 1]), d_b_hor = std::abs(bh[x] - bh[x - 1]);
      s_f_ver += d_f_ver;
      s_v_ver += std::max(0.0, d_f_ver - d_b_ver);
      s_f_hor += d_f_hor;
      s_v_hor += std::max(0.0, d_f_hor - d_b_hor);
    }
  }
  if (s_f_ver <= 0 || s_f_hor <= 0) return 1.0;  // a flat image carries no sharpness
  return std::max((s_f_ver - s_v_ver) / s_f_ver, (s_f_hor - s_v_hor) / s_f_hor);
}

cv::Mat unsharpMask(const cv::Mat& color_bgr, double sigma, double amount) {
  cv::Mat blurred, sharp;
  cv::GaussianBlur(color_bgr, blurred, cv::Size(0, 0), sigma);
  cv::addWeighted(color_bgr, 1.0 + amount, blurred, -amount, 0.0, sharp);
  return sharp;
}

double overlapRatio(const cv::Mat& kd, const Intrinsics& k, const Pose& frame_from_keyframe) {
  int valid = 0, seen = 0;
  for (int y = 0; y < kd.rows; y += 4) {
    const float* row = kd.ptr<float>(y);
    for (int x = 0; x < kd.cols; x += 4) {
      if (!(row[x] > 0)) continue;
      ++valid;
      const Eigen::Vector3d p = frame_from_keyframe * backProject(k, x, y, row[x]);
      if (p.z() <= 0) continue;
      const double u = k.fx * p.x() / p.z() + k.cx, v = k.fy * p.y() / p.z() + k.cy;
      seen += u >= 0 && v >= 0 && u <= k.width - 1 && v <= k.height - 1;
    }
  }
  return valid == 0 ? 0.0 : static_cast<double>(seen) / valid;
}

KeyframeFuser::KeyframeFuser(const FusionParams& params, const Intrinsics& k) : params_(params), k_(k) {
  params_.validate();
}

bool KeyframeFuser::startsNewKeyframe(int64_t dvo_keyframe_id, const Pose& camera_to_world) const {
  if (!open_) return true;
  switch (params_.strategy) {
    case KeyframeStrategy::kConst: return frames_ >= params_.kappa;
    case KeyframeStrategy::kDvo: return dvo_keyframe_id != dvo_keyframe_id_;
    case KeyframeStrategy::kDist:
      return translationDistance(kf_world_, camera_to_world) > params_.dist_translation ||
             rotationAngle(kf_world_, camera_to_world) * 180.0 / M_PI > params_.dist_rotation_deg;
    case KeyframeStrategy::kOverlap:
      return overlapRatio(kf_.depth, k_, camera_to_world.inverse() * kf_world_) < params_.min_overlap;
  }
  return true;
}

void KeyframeFuser::begin(int64_t kf_id, int64_t anchor_keyframe_id, const Pose& pose_in_anchor,
                          const Pose& camera_to_world) {
  kf_ = FusedKeyframe{};
  kf_.id = kf_id;
  kf_.anchor_keyframe_id = anchor_keyframe_id;
  kf_.pose_in_anchor = pose_in_anchor;
  kf_.depth = cv::Mat(k_.height, k_.width, CV_32F, cv::Scalar(0));
  kf_.weight = cv::Mat(k_.height, k_.width, CV_32F, cv::Scalar(0));
  kf_world_ = camera_to_world;
  dvo_keyframe_id_ = anchor_keyframe_id;
  frames_ = 0;
  open_ = true;
  inputs_.clear();
}

void KeyframeFuser::add(const RgbdFrame& frame, const Pose& camera_to_world) {
  if (!open_) throw Error("keyframe fusion: add() before begin()");
  if (frame.depth.cols != k_.width || frame.depth.rows != k_.height || frame.color.size() != frame.depth.size() ||
      frame.color.type() != CV_8UC3)
    throw Error("keyframe fusion: frame " + std::to_string(frame.id) + " does not match the " +
                std::to_string(k_.width) + "x" + std::to_string(k_.height) + " camera (16-bit depth, BGR color)");
  const cv::Mat depth = toMetres(frame.depth, k_.depth_scale);
  const cv::Mat w_z = depthWeights(depth, k_, params_);
  const Pose kf_from_frame = kf_world_.inverse() * camera_to_world;
  const Eigen::Matrix3f r = kf_from_frame.linear().cast<float>();
  const Eigen::Vector3f t = kf_from_frame.translation().cast<float>();
  const float agree = static_cast<float>(params_.depth_agreement);
  for (int y = 0; y < depth.rows; ++y) {
    const float* zrow = depth.ptr<float>(y);
    const float* wrow = w_z.ptr<float>(y);
    for (int x = 0; x < depth.cols; ++x) {
      const float w = wrow[x];
      if (w <= 0) continue;
      const float z = zrow[x];
      const Eigen::Vector3f p(static_cast<float>((x - k_.cx) / k_.fx) * z, static_cast<float>((y - k_.cy) / k_.fy) * z, z);
      const Eigen::Vector3f q = r * p + t;
      if (q.z() <= 0) continue;
      const int u = static_cast<int>(std::lround(k_.fx * q.x() / q.z() + k_.cx));
      const int v = static_cast<int>(std::lround(k_.fy * q.y() / q.z() + k_.cy));
      if (u < 0 || v < 0 || u >= k_.width || v >= k_.height) continue;
      float& zk = kf_.depth.at<float>(v, u);
      float& wk = kf_.weight.at<float>(v, u);
      if (wk > 0 && std::abs(q.z() - zk) > agree * zk) {
        if (q.z() > zk) continue;  // behind the keyframe's surface: occluded
        wk = 0;                    // in front: a nearer surface replaces the old one
      }
      zk = (wk * zk + w * q.z()) / (wk + w);  // eq. (1)
      wk += w;
    }
  }
  ColorInput in;
  in.sharp = unsharpMask(frame.color, params_.unsharp_sigma, params_.unsharp_amount);
  in.depth = depth;
  in.w_z = w_z;
  in.w_b = std::max(1e-3, 1.0 - blurriness(frame.color));
  in.keyframe_to_camera = camera_to_world.inverse() * kf_world_;
  inputs_.push_back(std::move(in));
  if (frames_ == 0) {
    kf_.first_frame_id = frame.id;
    kf_.timestamp = frame.timestamp;
  }
  kf_.last_frame_id = frame.id;
  ++frames_;
}

FusedKeyframe KeyframeFuser::finish() {
  if (frames_ == 0) throw Error("keyframe fusion: finish() without frames (begin() and add() first)");
  kf_.frames = frames_;
  kf_.color = cv::Mat(k_.height, k_.width, CV_8UC3, cv::Scalar(0, 0, 0));
  std::vector<Observation> obs;
  obs.reserve(inputs_.size());
  const double agree = params_.depth_agreement;
  for (int y = 0; y < k_.height; ++y) {
    const float* zrow = kf_.depth.ptr<float>(y);
    auto* crow = kf_.color.ptr<cv::Vec3b>(y);
    for (int x = 0; x < k_.width; ++x) {
      if (!(zrow[x] > 0)) continue;
      const Eigen::Vector3d p = backProject(k_, x, y, zrow[x]);
      obs.clear();
      for (const ColorInput& in : inputs_) {
        const Eigen::Vector3d q = in.keyframe_to_camera * p;
        if (q.z() <= 0) continue;
        const double u = k_.fx * q.x() / q.z() + k_.cx, v = k_.fy * q.y() / q.z() + k_.cy;
        const int ui = static_cast<int>(std::lround(u)), vi = static_cast<int>(std::lround(v));
        if (ui < 0 || vi < 0 || ui >= k_.width || vi >= k_.height) continue;
        const float zi = in.depth.at<float>(vi, ui);
        const float wz = in.w_z.at<float>(vi, ui);
        // Only where the frame saw this very surface (not an occluder in front of it).
        if (wz <= 0 || std::abs(zi - q.z()) > agree * q.z()) continue;
        double bgr[3];
        if (!sampleBilinear(in.sharp, u, v, bgr)) continue;
        Observation o;
        for (int c = 0; c < 3; ++c) o.bgr[c] = cv::saturate_cast<uint8_t>(bgr[c]);
        o.luma = static_cast<float>(0.114 * bgr[0] + 0.587 * bgr[1] + 0.299 * bgr[2]);
        o.w = static_cast<float>(in.w_b) * wz;
        obs.push_back(o);
      }
      if (obs.empty()) continue;
      // Weighted median by luminance: the observation where the cumulative
      // weight crosses half keeps its whole color (no mixed hues).
      std::sort(obs.begin(), obs.end(), [](const Observation& a, const Observation& b) { return a.luma < b.luma; });
      float total = 0;
      for (const Observation& o : obs) total += o.w;
      float acc = 0;
      for (const Observation& o : obs) {
        acc += o.w;
        if (acc >= 0.5f * total) {
          crow[x] = o.bgr;
          break;
        }
      }
    }
  }
  inputs_.clear();
  frames_ = 0;
  open_ = false;
  return std::move(kf_);
}

}  // namespace rekon::fusion
