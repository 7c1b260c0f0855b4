#include "rekon/common/camera.hpp"

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <vector>

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

bool sameCamera(const Intrinsics& a, const Intrinsics& b) {
  const auto close = [](double x, double y) { return std::abs(x - y) <= 1e-6 * std::max(1.0, std::abs(x)); };
  return a.width == b.width && a.height == b.height && close(a.fx, b.fx) && close(a.fy, b.fy) && close(a.cx, b.cx) &&
         close(a.cy, b.cy);
}

std::string describeCamera(const Intrinsics& k) {
  return fmt::format("{}x{} fx {} fy {} cx {} cy {}", k.width, k.height, k.fx, k.fy, k.cx, k.cy);
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

namespace {

constexpr const char* kKeys[] = {"width", "height", "fx", "fy", "cx", "cy", "depth_scale"};
constexpr const char* kForms =
    "camera.yaml needs the keys width height fx fy cx cy depth_scale, or those seven numbers on one line "
    "(e.g. 640 480 585 585 320 240 1000)";

// The seven values in kKeys order, from whichever form the file has.
std::vector<std::string> cameraValues(const YAML::Node& node, const std::string& source) {
  std::vector<std::string> values;
  if (node.IsMap()) {
    for (const char* key : kKeys) {
      const YAML::Node v = node[key];
      if (!v) throw Error(source + ": missing key '" + key + "'; " + kForms);
      if (!v.IsScalar()) throw Error(source + ": '" + key + "' is not a number; " + kForms);
      values.push_back(v.Scalar());
    }
    return values;
  }
  if (node.IsScalar()) {
    std::istringstream in(node.Scalar());
    for (std::string word; in >> word;) values.push_back(word);
    if (values.size() == 7) return values;
    throw Error(source + ": one line of " + std::to_string(values.size()) + " values; " + kForms);
  }
  throw Error(source + ": neither a mapping nor one line of numbers; " + kForms);
}

double number(const std::string& text, const char* key, const std::string& source) {
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE)
    throw Error(source + ": " + key + " = '" + text + "' is not a number; " + kForms);
  return v;
}

int integer(const std::string& text, const char* key, const std::string& source) {
  const double v = number(text, key, source);
  if (v != std::floor(v) || std::abs(v) > 1e9) throw Error(source + ": " + key + " = '" + text + "' is not a whole number of pixels");
  return static_cast<int>(v);
}

}  // namespace

Intrinsics parseIntrinsics(const std::string& text, const std::string& source) {
  YAML::Node node;
  try {
    node = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw Error(source + ": not valid YAML (" + e.msg + "); " + kForms);
  }
  const std::vector<std::string> v = cameraValues(node, source);
  Intrinsics k;
  k.width = integer(v[0], kKeys[0], source);
  k.height = integer(v[1], kKeys[1], source);
  k.fx = number(v[2], kKeys[2], source);
  k.fy = number(v[3], kKeys[3], source);
  k.cx = number(v[4], kKeys[4], source);
  k.cy = number(v[5], kKeys[5], source);
  k.depth_scale = number(v[6], kKeys[6], source);
  k.validate(source);
  return k;
}

Intrinsics loadIntrinsics(const std::string& yaml_path) {
  std::ifstream in(yaml_path, std::ios::binary);
  if (!in) throw Error(yaml_path + ": cannot read camera file; give the dataset a camera.yaml (" + kForms + ")");
  std::stringstream text;
  text << in.rdbuf();
  return parseIntrinsics(text.str(), yaml_path);
}

void saveIntrinsics(const Intrinsics& k, const std::string& yaml_path) {
  std::ofstream out(yaml_path);
  if (!out) throw Error(yaml_path + ": cannot write camera file; check the output folder");
  out.precision(10);
  out << "width: " << k.width << "\nheight: " << k.height << "\nfx: " << k.fx << "\nfy: " << k.fy
      << "\ncx: " << k.cx << "\ncy: " << k.cy << "\ndepth_scale: " << k.depth_scale << "\n";
}

}  // namespace rekon
