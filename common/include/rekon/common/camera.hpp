#pragma once
// Pinhole intrinsics of an RGB-D camera and its depth encoding.
#include <string>

namespace rekon {

struct Intrinsics {
  int width = 640;
  int height = 480;
  double fx = 525.0;
  double fy = 525.0;
  double cx = 319.5;
  double cy = 239.5;
  double depth_scale = 5000.0;  // raw 16-bit depth units per metre

  // Throws rekon::Error naming `source` when a value is not finite or out of range.
  void validate(const std::string& source) const;

  // Intrinsics of pyramid level `level` (each level halves the resolution).
  Intrinsics atLevel(int level) const;
};

// The same camera: equal size and focal lengths and principal point within
// 1e-6 relative (a text file's rounding); the depth encoding is not compared.
bool sameCamera(const Intrinsics& a, const Intrinsics& b);
// "640x480 fx 525 fy 525 cx 319.5 cy 239.5", for messages.
std::string describeCamera(const Intrinsics& k);

// A camera.yaml holds `width height fx fy cx cy depth_scale` in one of two
// forms: a mapping with those seven keys, or the seven numbers on one line
// (`640 480 585 585 320 240 1000`). Anything else is a rekon::Error naming
// `source` and both forms.
Intrinsics parseIntrinsics(const std::string& text, const std::string& source);
Intrinsics loadIntrinsics(const std::string& yaml_path);
void saveIntrinsics(const Intrinsics& k, const std::string& yaml_path);

}  // namespace rekon
