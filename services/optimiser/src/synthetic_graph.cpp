#include "rekon/optimiser/synthetic_graph.hpp"

#include <cmath>
#include <numbers>
#include <random>

#include "rekon/common/error.hpp"
#include "rekon/common/se3.hpp"

namespace rekon::optimiser {

Matrix6d isotropicInformation(double sigma_translation_m, double sigma_rotation_rad) {
  Matrix6d info = Matrix6d::Zero();
  info.diagonal().head<3>().setConstant(1.0 / (sigma_translation_m * sigma_translation_m));
  info.diagonal().tail<3>().setConstant(1.0 / (sigma_rotation_rad * sigma_rotation_rad));
  return info;
}

SyntheticGraph makeSyntheticGraph(const SyntheticGraphSpec& spec) {
  if (spec.keyframes < 2 || spec.laps < 1 || spec.loop_edges < 0 || (spec.loop_edges > 0 && spec.laps < 2))
    throw Error("synthetic graph: need at least 2 keyframes, 1 lap, and 2 laps for loop edges");
  std::mt19937_64 rng(spec.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto noise = [&] {
    Vector6d xi;
    for (int i = 0; i < 3; ++i) xi[i] = spec.sigma_translation_m * normal(rng);
    for (int i = 3; i < 6; ++i) xi[i] = spec.sigma_rotation_rad * normal(rng);
    return xi;
  };
  const Matrix6d info = isotropicInformation(spec.sigma_translation_m, spec.sigma_rotation_rad);

  SyntheticGraph g;
  const int n = spec.keyframes;
  const int per_lap = (n + spec.laps - 1) / spec.laps;
  for (int i = 0; i < n; ++i) {
    // Around the circle, looking inwards, with a slow vertical wobble and tilt
    // so that every axis of translation and rotation is exercised.
    const double a = 2.0 * std::numbers::pi * static_cast<double>(i) / static_cast<double>(per_lap);
    const Eigen::Vector3d centre(spec.radius_m * std::cos(a), 0.2 * std::sin(3.0 * a), spec.radius_m * std::sin(a));
    const Eigen::Matrix3d r = (Eigen::AngleAxisd(-a - std::numbers::pi / 2, Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(0.1 * std::sin(2.0 * a), Eigen::Vector3d::UnitX()))
                                  .toRotationMatrix();
    Pose p = Pose::Identity();
    p.linear() = r;
    p.translation() = centre;
    g.truth.push_back(p);
  }
  g.initial.push_back(g.truth[0]);
  for (int i = 0; i + 1 < n; ++i) {
    Constraint c;
    c.kind = EdgeKind::Odometry;
    c.from_id = i;
    c.to_id = i + 1;
    c.relative = orthonormalised(g.truth[i].inverse() * g.truth[i + 1] * expSe3(noise()));
    c.information = info;
    g.constraints.push_back(c);
    g.initial.push_back(orthonormalised(g.initial.back() * c.relative));
  }
  std::uniform_int_distribution<int> pick(0, n - 1);
  std::uniform_int_distribution<int> offset(-2, 2);
  for (int k = 0; k < spec.loop_edges;) {
    // A keyframe and one a whole number of laps later, give or take a couple.
    const int i = pick(rng);
    const int laps_later = 1 + static_cast<int>(rng() % static_cast<uint64_t>(spec.laps - 1));
    const int j = i + laps_later * per_lap + offset(rng);
    if (j >= n || j <= i + 1) continue;
    Constraint c;
    c.kind = EdgeKind::Loop;
    c.from_id = i;
    c.to_id = j;
    c.relative = orthonormalised(g.truth[i].inverse() * g.truth[j] * expSe3(noise()));
    c.information = info;
    g.constraints.push_back(c);
    ++k;
  }
  return g;
}

double loopClosureErrorBound(const SyntheticGraphSpec& spec, int k, double sigmas) {
  const double n = spec.keyframes;
  const double lever = 2.0 * spec.radius_m;
  const double s = std::hypot(spec.sigma_translation_m, spec.sigma_rotation_rad * lever);
  return std::sqrt(3.0) * sigmas * s * std::sqrt(static_cast<double>(k) * (n - k) / n);
}

double maxTranslationError(const std::vector<Pose>& truth, const std::vector<std::pair<int64_t, Pose>>& estimate) {
  double worst = 0.0;
  for (const auto& [id, pose] : estimate) {
    if (id < 0 || static_cast<size_t>(id) >= truth.size()) continue;
    worst = std::max(worst, (pose.translation() - truth[static_cast<size_t>(id)].translation()).norm());
  }
  return worst;
}

}  // namespace rekon::optimiser
