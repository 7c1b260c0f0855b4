#include "rekon/camera/kinect_depth.hpp"

#include <yaml-cpp/yaml.h>

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <vector>

#include "rekon/common/error.hpp"

namespace rekon::camera {

namespace {

// A depth-to-color translation longer than this is a unit mistake (millimetres
// for metres): the Kinect's cameras are 2.5 cm apart.
constexpr double kMaxBaselineM = 1.0;
// How far R R^T may be from the identity: a rotation written with 6 digits.
constexpr double kRotationTolerance = 1e-4;

}  // namespace

// ---- disparity model ----

DisparityTable::DisparityTable(const DisparityModel& model) : model_(model) {
  for (int raw = 0; raw < kSize; ++raw) {
    const double denominator = model.c0 + model.c1 * raw;
    if (raw == kNoValue || !(denominator > 0.0)) continue;
    metres_[static_cast<size_t>(raw)] = static_cast<float>(1.0 / denominator);
    last_valid_ = raw;
  }
}

uint16_t DisparityTable::nearestRaw(double metres) const {
  if (!std::isfinite(metres) || metres <= 0.0 || last_valid_ < 1) return kNoValue;
  // The model is monotonic (c1 < 0: depth grows with raw), so the nearest raw
  // value is one of the two around the exact inverse.
  const double exact = (1.0 / metres - model_.c0) / model_.c1;
  const int lo = static_cast<int>(std::clamp(std::floor(exact), 0.0, static_cast<double>(last_valid_)));
  const int hi = std::min(lo + 1, last_valid_);
  const auto error = [&](int raw) { return std::abs(static_cast<double>(metres_[static_cast<size_t>(raw)]) - metres); };
  const int best = error(hi) < error(lo) ? hi : lo;
  // Beyond either end of the table by more than half a step: no raw value measures it.
  const auto m = [&](int raw) { return static_cast<double>(metres_[static_cast<size_t>(raw)]); };
  if (metres < m(0) && error(0) > 0.5 * (m(1) - m(0))) return kNoValue;
  if (metres > m(last_valid_) && error(last_valid_) > 0.5 * (m(last_valid_) - m(last_valid_ - 1))) return kNoValue;
  return static_cast<uint16_t>(best);
}

cv::Mat DisparityTable::toMetres(const cv::Mat& raw) const {
  CV_Assert(raw.type() == CV_16UC1);
  cv::Mat out(raw.size(), CV_32FC1);
  for (int v = 0; v < raw.rows; ++v) {
    const uint16_t* in = raw.ptr<uint16_t>(v);
    float* o = out.ptr<float>(v);
    for (int u = 0; u < raw.cols; ++u) o[u] = metres(in[u]);
  }
  return out;
}

// ---- calibration file ----

KinectCalibration KinectCalibration::nominal() {
  KinectCalibration c;
  c.color = Intrinsics{640, 480, 525.0, 525.0, 319.5, 239.5, 1000.0};
  c.depth = Intrinsics{640, 480, 580.0, 580.0, 319.5, 239.5, 1000.0};
  c.depth_to_color_translation = Eigen::Vector3d(-0.025, 0.0, 0.0);
  c.aligned = false;
  return c;
}

namespace {

double numberAt(const YAML::Node& node, const std::string& key, const std::string& source) {
  if (!node.IsScalar()) throw Error(source + ": " + key + " is not a number");
  double v = 0.0;
  try {
    v = node.as<double>();
  } catch (const YAML::Exception&) {
    throw Error(source + ": " + key + " = '" + node.Scalar() + "' is not a number");
  }
  if (!std::isfinite(v)) throw Error(source + ": " + key + " = '" + node.Scalar() + "' is not finite");
  return v;
}

// A sequence of exactly `count` numbers under `key`.
std::vector<double> numbersAt(const YAML::Node& map, const char* key, size_t count, const char* what,
                              const std::string& source) {
  const YAML::Node node = map[key];
  if (!node.IsSequence() || node.size() != count) {
    throw Error(source + ": " + key + " must be " + std::to_string(count) + " numbers (" + what + "), got " +
                (node.IsSequence() ? std::to_string(node.size()) + " values" : std::string("no list")));
  }
  std::vector<double> values;
  for (size_t i = 0; i < count; ++i)
    values.push_back(numberAt(node[i], std::string(key) + "[" + std::to_string(i) + "]", source));
  return values;
}

Intrinsics depthCamera(const YAML::Node& node, const Intrinsics& color, const std::string& source) {
  if (!node.IsMap()) throw Error(source + ": depth_camera must be a mapping {fx, fy, cx, cy} (the IR camera)");
  Intrinsics k = color;
  for (const char* size_key : {"width", "height"}) {
    const int want = std::string(size_key) == "width" ? color.width : color.height;
    if (node[size_key] && numberAt(node[size_key], std::string("depth_camera.") + size_key, source) != want) {
      throw Error(source + ": depth_camera." + size_key + " differs from the color camera's " + std::to_string(want) +
                  "; the depth image must have the color image's size");
    }
  }
  double* fields[] = {&k.fx, &k.fy, &k.cx, &k.cy};
  const char* names[] = {"fx", "fy", "cx", "cy"};
  for (size_t i = 0; i < 4; ++i) {
    const std::string key = std::string("depth_camera.") + names[i];
    if (!node[names[i]]) throw Error(source + ": missing key " + key + "; depth_camera needs fx, fy, cx and cy");
    *fields[i] = numberAt(node[names[i]], key, source);
  }
  k.validate(source + " (depth_camera)");
  return k;
}

Eigen::Matrix3d rotationAt(const YAML::Node& map, const std::string& source) {
  const std::vector<double> v = numbersAt(map, "depth_to_color_rotation", 9, "a row-major 3x3 rotation", source);
  Eigen::Matrix3d r;
  r << v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8];
  const double off = (r * r.transpose() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (off > kRotationTolerance || r.determinant() < 0.0) {
    std::ostringstream why;
    why << source << ": depth_to_color_rotation is not a rotation (R R^T differs from the identity by " << off
        << ", det " << r.determinant() << "); give the 3x3 rotation row-major";
    throw Error(why.str());
  }
  return r;
}

DisparityModel disparityAt(const YAML::Node& map, const std::string& source) {
  const std::vector<double> v = numbersAt(map, "disparity", 2, "c0, c1 of depth_m = 1 / (c0 + c1 raw)", source);
  if (!(v[0] > 0.0) || !(v[1] < 0.0)) {
    throw Error(source + ": disparity must be [c0, c1] with c0 > 0 and c1 < 0 (depth grows with the raw value), got [" +
                std::to_string(v[0]) + ", " + std::to_string(v[1]) + "]");
  }
  return DisparityModel{v[0], v[1]};
}

}  // namespace

KinectCalibration parseKinectCalibration(const std::string& text, const std::string& source) {
  KinectCalibration c;
  c.color = parseIntrinsics(text, source);  // also proves the text is YAML
  c.depth = c.color;
  const YAML::Node map = YAML::Load(text);
  if (!map.IsMap()) return c;  // the one-line form has no depth keys
  if (map["disparity"]) c.disparity = disparityAt(map, source);
  if (!map["depth_camera"]) {
    for (const char* key : {"depth_to_color_translation", "depth_to_color_rotation"}) {
      if (map[key]) throw Error(source + ": " + key + " needs depth_camera (the IR camera's fx, fy, cx, cy)");
    }
    return c;
  }
  c.aligned = false;
  c.depth = depthCamera(map["depth_camera"], c.color, source);
  if (map["depth_to_color_rotation"]) c.depth_to_color_rotation = rotationAt(map, source);
  if (map["depth_to_color_translation"]) {
    const std::vector<double> t = numbersAt(map, "depth_to_color_translation", 3, "x, y, z in metres", source);
    c.depth_to_color_translation = Eigen::Vector3d(t[0], t[1], t[2]);
    if (c.depth_to_color_translation.norm() > kMaxBaselineM) {
      throw Error(source + ": depth_to_color_translation is " + std::to_string(c.depth_to_color_translation.norm()) +
                  " m long; give it in metres (the Kinect's cameras are about 0.025 m apart)");
    }
  }
  return c;
}

KinectCalibration loadKinectCalibration(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot read the calibration file; check the --calibration path");
  std::stringstream text;
  text << in.rdbuf();
  return parseKinectCalibration(text.str(), path);
}

void saveKinectCalibration(const KinectCalibration& c, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw Error(path + ": cannot write the calibration file; check the output folder");
  out.precision(12);  // the disparity model has 11 significant digits
  const Intrinsics& k = c.color;
  out << "width: " << k.width << "\nheight: " << k.height << "\nfx: " << k.fx << "\nfy: " << k.fy << "\ncx: " << k.cx
      << "\ncy: " << k.cy << "\ndepth_scale: " << k.depth_scale << "\n";
  out << "disparity: [" << c.disparity.c0 << ", " << c.disparity.c1 << "]\n";
  if (c.aligned) return;
  const Intrinsics& d = c.depth;
  out << "depth_camera: {fx: " << d.fx << ", fy: " << d.fy << ", cx: " << d.cx << ", cy: " << d.cy << "}\n";
  const Eigen::Vector3d& t = c.depth_to_color_translation;
  out << "depth_to_color_translation: [" << t.x() << ", " << t.y() << ", " << t.z() << "]\n";
  out << "depth_to_color_rotation: [";
  for (int i = 0; i < 9; ++i) out << (i ? ", " : "") << c.depth_to_color_rotation(i / 3, i % 3);
  out << "]\n";
  if (!out) throw Error(path + ": writing the calibration file failed (disk full?)");
}

// ---- registration ----

DepthWarp::DepthWarp(const Intrinsics& from, const Intrinsics& to, const Eigen::Matrix3d& rotation,
                     const Eigen::Vector3d& translation)
    : to_(to), translation_(translation.cast<float>()), rays_(from.height, from.width, CV_32FC3) {
  const Eigen::Matrix3f r = rotation.cast<float>();
  for (int v = 0; v < from.height; ++v) {
    auto* row = rays_.ptr<cv::Vec3f>(v);
    for (int u = 0; u < from.width; ++u) {
      const Eigen::Vector3f ray = r * Eigen::Vector3f(static_cast<float>((u - from.cx) / from.fx),
                                                      static_cast<float>((v - from.cy) / from.fy), 1.0f);
      row[u] = cv::Vec3f(ray.x(), ray.y(), ray.z());
    }
  }
}

cv::Mat DepthWarp::apply(const cv::Mat& depth_m) const {
  CV_Assert(depth_m.type() == CV_32FC1 && depth_m.size() == rays_.size());
  cv::Mat out = cv::Mat::zeros(to_.height, to_.width, CV_32FC1);
  const float fx = static_cast<float>(to_.fx), fy = static_cast<float>(to_.fy);
  const float cx = static_cast<float>(to_.cx), cy = static_cast<float>(to_.cy);
  // Pixel centres are at integer coordinates: x rounds to column round(x).
  const float max_x = static_cast<float>(to_.width) - 0.5f, max_y = static_cast<float>(to_.height) - 0.5f;
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* z = depth_m.ptr<float>(v);
    const cv::Vec3f* ray = rays_.ptr<cv::Vec3f>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      if (!(z[u] > 0.0f)) continue;
      const float px = z[u] * ray[u][0] + translation_.x(), py = z[u] * ray[u][1] + translation_.y();
      const float pz = z[u] * ray[u][2] + translation_.z();
      if (!(pz > 0.0f)) continue;
      const float inverse_z = 1.0f / pz;
      const float x = fx * px * inverse_z + cx, y = fy * py * inverse_z + cy;
      if (!(x >= -0.5f && x < max_x && y >= -0.5f && y < max_y)) continue;
      // x + 0.5 >= 0 here, so truncation is floor: the nearest column.
      float& target = out.at<float>(static_cast<int>(y + 0.5f), static_cast<int>(x + 0.5f));
      if (target == 0.0f || pz < target) target = pz;
    }
  }
  return out;
}

cv::Mat toMillimetres(const cv::Mat& depth_m) {
  CV_Assert(depth_m.type() == CV_32FC1);
  cv::Mat out(depth_m.size(), CV_16UC1);
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* in = depth_m.ptr<float>(v);
    uint16_t* o = out.ptr<uint16_t>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      const double mm = static_cast<double>(in[u]) * 1000.0 + 0.5;  // rounded by the truncation below
      o[u] = mm >= 1.0 && mm < 65536.0 ? static_cast<uint16_t>(mm) : 0;
    }
  }
  return out;
}

KinectRegistration::KinectRegistration(const KinectCalibration& calibration)
    : calibration_(calibration),
      table_(calibration.disparity),
      warp_(calibration.depth, calibration.color, calibration.depth_to_color_rotation,
            calibration.depth_to_color_translation) {}

cv::Mat KinectRegistration::apply(const cv::Mat& raw) const {
  const Intrinsics& d = calibration_.depth;
  if (raw.type() != CV_16UC1 || raw.cols != d.width || raw.rows != d.height) {
    throw Error("raw depth image of " + std::to_string(raw.cols) + "x" + std::to_string(raw.rows) +
                " does not match the depth camera's " + std::to_string(d.width) + "x" + std::to_string(d.height));
  }
  const cv::Mat metres = table_.toMetres(raw);
  // Aligned depth keeps its pixels: no resampling, no holes from rounding.
  return toMillimetres(calibration_.aligned ? metres : warp_.apply(metres));
}

}  // namespace rekon::camera
