#include "rekon/common/camera.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <fstream>

#include "rekon/common/error.hpp"

namespace rekon {

void Intrinsics::validate(const std::string& source) const {
  auto bad = [&](const char* key, double v, const char* want) {
    throw Error(source + ": camera " + key + " = " + std::to_string(v) + " is invalid; it must be " + want);
  };
  if (width <= 0 || width > 16384) bad("width", width, "between 1 and 16384");
  if (height <= 0 || height > 16384) bad("height", height, "between 1 and 16384");
  if (!std::isfinite(fx) || fx <= 0) bad("fx", fx, "a positive finite number");
  if (!std::isfinite(fy) || fy <= 0) bad("fy", fy, "a positive finite number");
  if (!std::isfinite(cx)) bad("cx", cx, "finite");
  if (!std::isfinite(cy)) bad("cy", cy, "finite");
  if (!std::isfinite(depth_scale) || depth_scale <= 0) bad("depth_scale", depth_scale, "a positive finite number");
}

Intrinsics Intrinsics::atLevel(int level) const {
  Intrinsics k = *this;
  for (int i = 0; i < level; ++i) {
    k.width /= 2;
    k.height /= 2;
    k.fx *= 0.5;
    k.fy *= 0.5;
    // Pixel centres: a 2x2 block at (2x, 2x+1) maps to x, so c -> (c - 0.5) / 2.
    k.cx = (k.cx - 0.5) * 0.5;
    k.cy = (k.cy - 0.5) * 0.5;
  }
  return k;
}

Intrinsics loadIntrinsics(const std::string& yaml_path) {
  YAML::Node node;
  try {
    node = YAML::LoadFile(yaml_path);
  } catch (const YAML::BadFile&) {
    throw Error(yaml_path + ": cannot read camera file; give the dataset a camera.yaml with width height fx fy cx cy depth_scale");
  } catch (const YAML::Exception& e) {
    throw Error(yaml_path + ": not valid YAML (" + e.msg + "); fix the camera file");
  }
  Intrinsics k;
  const char* keys[] = {"width", "height", "fx", "fy", "cx", "cy", "depth_scale"};
  for (const char* key : keys) {
    if (!node[key]) throw Error(yaml_path + ": missing key '" + key + "'; camera.yaml needs width height fx fy cx cy depth_scale");
  }
  try {
    k.width = node["width"].as<int>();
    k.height = node["height"].as<int>();
    k.fx = node["fx"].as<double>();
    k.fy = node["fy"].as<double>();
    k.cx = node["cx"].as<double>();
    k.cy = node["cy"].as<double>();
    k.depth_scale = node["depth_scale"].as<double>();
  } catch (const YAML::Exception& e) {
    throw Error(yaml_path + ": a camera value is not a number (" + e.msg + ")");
  }
  k.validate(yaml_path);
  return k;
}

void saveIntrinsics(const Intrinsics& k, const std::string& yaml_path) {
  std::ofstream out(yaml_path);
  if (!out) throw Error(yaml_path + ": cannot write camera file; check the output folder");
  out.precision(10);
  out << "width: " << k.width << "\nheight: " << k.height << "\nfx: " << k.fx << "\nfy: " << k.fy
      << "\ncx: " << k.cx << "\ncy: " << k.cy << "\ndepth_scale: " << k.depth_scale << "\n";
}

}  // namespace rekon
