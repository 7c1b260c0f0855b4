#pragma once
// Dense RGB-D alignment (Kerl, Sturm, Cremers, ICRA 2013): Gauss-Newton on
// se(3) over the joint photometric and geometric residuals of every selected
// keyframe pixel, coarse to fine, with bivariate t-distribution weights whose
// 2x2 scale matrix is re-estimated each iteration. Used frame-to-keyframe by
// the Tracker and keyframe-to-keyframe by loop-closure checks.
#include <vector>

#include "rekon/common/pose.hpp"
#include "rekon/common/se3.hpp"
#include "rekon/tracker/keyframe_reference.hpp"
#include "rekon/tracker/params.hpp"
#include "rekon/tracker/rgbd_pyramid.hpp"

namespace rekon::tracker {

struct AlignResult {
  // Current camera in the reference keyframe (camera-to-keyframe); always a
  // valid rigid pose, the initial guess when the alignment failed.
  Pose pose = Pose::Identity();
  // Inverse covariance of `pose` for a perturbation pose * exp(xi), xi =
  // (v, w) in the current camera's frame: the final normal matrix J^T W J.
  Matrix6d information = Matrix6d::Zero();
  // Differential entropy of that Gaussian, 0.5 ln((2 pi e)^6 det(cov)), nats.
  double entropy = 0.0;
  int valid_pixels = 0;     // pixels that constrained the last iteration at the finest level
  int selected_pixels = 0;  // keyframe pixels selected at the finest level
  double intensity_sigma = 0.0;  // robust residual scales (sqrt of the scale matrix diagonal)
  double depth_sigma = 0.0;
  int iterations = 0;      // over all levels
  bool converged = false;  // the finest level stopped on a small step, not on max_iterations
  bool valid = false;      // finite, enough pixels at the finest level, positive-definite information

  Matrix6d covariance() const;
};

// Differential entropy 0.5 ln((2 pi e)^6 det(information^-1)) of a 6-DoF
// Gaussian, in nats; +infinity when `information` is not positive definite.
// Loop-closure checks compare it with the odometry constraints' entropies.
double entropyOfInformation(const Matrix6d& information);

class DenseAligner {
 public:
  explicit DenseAligner(const AlignerParams& params = {});

  // Aligns `current` to `reference` from `initial` (current in reference),
  // on levels coarsest..finest (default: the params' levels; both must be
  // built in `reference` and `current`). Not thread-safe: an aligner owns
  // scratch buffers, so each thread uses its own.
  AlignResult align(const KeyframeReference& reference, const RgbdPyramid& current, const Pose& initial,
                    int coarsest = -1, int finest = -1);

  const AlignerParams& params() const { return params_; }

 private:
  struct Scale {
    double s11 = 0, s12 = 0, s22 = 0;  // 2x2 scale matrix of (intensity, depth) residuals
  };
  int warp(const KeyframeReference::Level& ref, const PyramidLevel& cur, const Eigen::Matrix<float, 3, 4>& t_ck);
  // Rows of U with U^T U = S^-1, the photometric row x photometric_weight.
  struct Whitening {
    float u11, u12, u22;
  };
  Whitening whitening(const Scale& scale) const;
  // Over all `count` points of the level, of which warp() kept `n`.
  double estimateScale(int count, int n, Scale& scale);
  void accumulate(const KeyframeReference::Level& ref, const Scale& scale, Matrix6d& h, Vector6d& b);

  AlignerParams params_;
  // Per reference point: residuals (0 where it does not count), valid (1 or 0).
  std::vector<float> res_i_, res_z_, valid_, block_;
};

}  // namespace rekon::tracker
