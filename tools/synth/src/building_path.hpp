#pragma once
// A walk along a polyline in the floor plane whose corners are rounded by
// circular arcs: arc length -> position and heading, and how near a turn a
// point of the path is. The building scene walks its laps on one.
#include <vector>

namespace rekon::synth {

struct Point2 {
  double x = 0, y = 0;
};

class RoundedPath {
 public:
  // `corners`: the polyline's points; each interior corner is replaced by an
  // arc of `radius` (less where the segments beside it are short).
  RoundedPath(const std::vector<Point2>& corners, double radius);

  double length() const { return length_; }
  struct State {
    double x, y, heading;
  };
  // Position and heading at arc length s (clamped to [0, length]).
  State at(double s) const;
  // 1 on an arc, falling smoothly to 0 at `slow_zone_m` before and after it.
  double turnWeight(double s, double slow_zone_m) const;
  // Points every `step_m` along the path (for clearance checks).
  std::vector<Point2> samples(double step_m) const;

 private:
  struct Piece {
    double s0, len;
    bool arc;
    double x0, y0, heading0;  // start point and heading
    double curvature;         // signed (left positive); 0 on a straight piece
  };
  std::vector<Piece> pieces_;
  double length_ = 0;
  const Piece& pieceAt(double s) const;
};

}  // namespace rekon::synth
