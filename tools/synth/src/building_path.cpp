#include "building_path.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "rekon/common/error.hpp"

namespace rekon::synth {
namespace {

double wrapAngle(double a) {
  while (a > std::numbers::pi) a -= 2 * std::numbers::pi;
  while (a < -std::numbers::pi) a += 2 * std::numbers::pi;
  return a;
}

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

}  // namespace

RoundedPath::RoundedPath(const std::vector<Point2>& corners, double radius) {
  if (corners.size() < 2) throw Error("a path needs two points or more");
  const size_t n = corners.size();
  auto dir = [&](size_t i) {  // unit direction and length of segment i -> i+1
    const double dx = corners[i + 1].x - corners[i].x, dy = corners[i + 1].y - corners[i].y;
    const double len = std::hypot(dx, dy);
    if (len < 1e-9) throw Error("a path has two equal points in a row");
    return std::array<double, 3>{dx / len, dy / len, len};
  };
  // The tangent length cut off each segment end by the arc at its corner.
  std::vector<double> cut(n, 0.0), rad(n, 0.0), turn(n, 0.0);
  for (size_t i = 1; i + 1 < n; ++i) {
    const auto a = dir(i - 1), b = dir(i);
    turn[i] = wrapAngle(std::atan2(b[1], b[0]) - std::atan2(a[1], a[0]));
    if (std::abs(turn[i]) < 1e-9) continue;
    if (std::abs(turn[i]) > std::numbers::pi - 1e-6) throw Error("a path reverses at a corner; give it a turn");
    const double half_tan = std::tan(0.5 * std::abs(turn[i]));
    // At most 45 % of each segment beside the corner, so neighbouring arcs never overlap.
    const double r = std::min(radius, 0.45 * std::min(a[2], b[2]) / half_tan);
    rad[i] = r;
    cut[i] = r * half_tan;
  }
  double s = 0;
  for (size_t i = 0; i + 1 < n; ++i) {
    const auto d = dir(i);
    const double heading = std::atan2(d[1], d[0]);
    const double start = cut[i], end = d[2] - cut[i + 1];
    pieces_.push_back({s, end - start, false, corners[i].x + d[0] * start, corners[i].y + d[1] * start, heading, 0.0});
    s += end - start;
    if (i + 2 < n && rad[i + 1] > 0) {
      const double len = rad[i + 1] * std::abs(turn[i + 1]);
      const double k = (turn[i + 1] > 0 ? 1.0 : -1.0) / rad[i + 1];
      pieces_.push_back({s, len, true, corners[i].x + d[0] * end, corners[i].y + d[1] * end, heading, k});
      s += len;
    }
  }
  length_ = s;
}

const RoundedPath::Piece& RoundedPath::pieceAt(double s) const {
  auto it = std::upper_bound(pieces_.begin(), pieces_.end(), s, [](double v, const Piece& p) { return v < p.s0; });
  return it == pieces_.begin() ? pieces_.front() : *std::prev(it);
}

RoundedPath::State RoundedPath::at(double s) const {
  s = std::clamp(s, 0.0, length_);
  const Piece& p = pieceAt(s);
  const double u = std::min(s - p.s0, p.len);
  if (!p.arc) return {p.x0 + u * std::cos(p.heading0), p.y0 + u * std::sin(p.heading0), p.heading0};
  const double h = p.heading0 + p.curvature * u;
  // Exact integral of the unit tangent along an arc of constant curvature.
  const double x = p.x0 + (std::sin(h) - std::sin(p.heading0)) / p.curvature;
  const double y = p.y0 - (std::cos(h) - std::cos(p.heading0)) / p.curvature;
  return {x, y, h};
}

double RoundedPath::turnWeight(double s, double slow_zone_m) const {
  // The arcs within reach of s: the pieces are few per metre, so look a few either side.
  auto it = std::upper_bound(pieces_.begin(), pieces_.end(), s, [](double v, const Piece& p) { return v < p.s0; });
  const auto lo = it - std::min<std::ptrdiff_t>(it - pieces_.begin(), 4);
  const auto hi = it + std::min<std::ptrdiff_t>(pieces_.end() - it, 4);
  double w = 0.0;
  for (auto p = lo; p != hi; ++p) {
    if (!p->arc) continue;
    const double d = std::max({p->s0 - s, s - (p->s0 + p->len), 0.0});
    if (d < slow_zone_m) w = std::max(w, 1.0 - smoothstep(0.0, slow_zone_m, d));
  }
  return w;
}

std::vector<Point2> RoundedPath::samples(double step_m) const {
  std::vector<Point2> out;
  for (double s = 0; s <= length_; s += step_m) {
    const State st = at(s);
    out.push_back({st.x, st.y});
  }
  return out;
}

}  // namespace rekon::synth
