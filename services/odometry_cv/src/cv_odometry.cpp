#include "rekon/odometry_cv/cv_odometry.hpp"

#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/rgbd.hpp>

#include <Eigen/Cholesky>
#include <cmath>
#include <limits>

#include "rekon/common/error.hpp"

namespace rekon::odometry_cv {

struct CvOdometry::Keyframe {
  int64_t id = 0;
  Pose world = Pose::Identity();
  cv::Ptr<cv::rgbd::OdometryFrame> frame;
  cv::Mat points;   // CV_32FC3, camera frame, NaN where no depth
  cv::Mat normals;  // CV_32FC3, NaN where undefined
};

namespace {

// Normals from the cross product of the neighbours' differences; NaN at the border and where depth is missing.
cv::Mat normalsOf(const cv::Mat& points) {
  cv::Mat normals(points.size(), CV_32FC3, cv::Scalar::all(std::numeric_limits<float>::quiet_NaN()));
  for (int v = 1; v + 1 < points.rows; ++v) {
    for (int u = 1; u + 1 < points.cols; ++u) {
      const cv::Vec3f dx = points.at<cv::Vec3f>(v, u + 1) - points.at<cv::Vec3f>(v, u - 1);
      const cv::Vec3f dy = points.at<cv::Vec3f>(v + 1, u) - points.at<cv::Vec3f>(v - 1, u);
      cv::Vec3f n = dy.cross(dx);
      const float len = static_cast<float>(cv::norm(n));
      if (std::isfinite(len) && len > 0) normals.at<cv::Vec3f>(v, u) = n / len;
    }
  }
  return normals;
}

Pose poseOf(const cv::Mat& rt) {
  Eigen::Matrix4d m;
  cv::cv2eigen(rt, m);
  Pose p = Pose::Identity();
  p.matrix() = m;
  return orthonormalised(p);
}

cv::Mat matOf(const Pose& p) {
  cv::Mat m;
  const Eigen::Matrix4d e = p.matrix();
  cv::eigen2cv(e, m);
  return m;
}

}  // namespace

std::optional<double> errorChi2(const Pose& estimate, const Matrix6d& covariance, const Pose& truth) {
  const Vector6d xi = logSe3(estimate.inverse() * truth);
  const Eigen::LDLT<Matrix6d> ldlt(covariance);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0)) return std::nullopt;
  return xi.dot(ldlt.solve(xi));
}

CvOdometry::CvOdometry(const Intrinsics& intrinsics, const CvOdometryParams& params) : k_(intrinsics), params_(params) {
  k_.validate("odometry_cv");
  if (!(params_.keyframe_translation > 0) || !(params_.keyframe_rotation_deg > 0) || !(params_.max_depth > 0) ||
      params_.covariance_stride < 1 || !(params_.covariance_max_residual > 0) || !(params_.covariance_scale > 0) ||
      !(params_.covariance_floor_t >= 0) || !(params_.covariance_floor_r >= 0))
    throw Error("odometry_cv parameters must be positive (keyframe distances, max depth, covariance stride and residual)");
  camera_matrix_ = (cv::Mat_<float>(3, 3) << k_.fx, 0, k_.cx, 0, k_.fy, k_.cy, 0, 0, 1);
  odometry_ = cv::rgbd::RgbdICPOdometry::create(camera_matrix_, cv::rgbd::Odometry::DEFAULT_MIN_DEPTH(),
                                                static_cast<float>(params_.max_depth));
}

CvOdometry::~CvOdometry() = default;

cv::Mat CvOdometry::depthMetres(const cv::Mat& depth) const {
  if (depth.type() != CV_16UC1 || depth.cols != k_.width || depth.rows != k_.height)
    throw Error("odometry_cv: depth must be 16-bit at the announced size");
  cv::Mat m;
  depth.convertTo(m, CV_32F, 1.0 / k_.depth_scale);
  m.setTo(std::numeric_limits<float>::quiet_NaN(), depth == 0);
  return m;
}

void CvOdometry::startKeyframe(const cv::Ptr<cv::rgbd::OdometryFrame>& frame, const cv::Mat& depth_m, const Pose& world) {
  auto kf = std::make_unique<Keyframe>();
  kf->id = keyframe_ ? keyframe_->id + 1 : 0;
  kf->world = world;
  kf->frame = frame;
  cv::rgbd::depthTo3d(depth_m, camera_matrix_, kf->points);
  kf->normals = normalsOf(kf->points);
  keyframes_.emplace_back(kf->id, world);
  keyframe_ = std::move(kf);
  last_pose_ = Pose::Identity();
}

Matrix6d CvOdometry::covariance(const cv::Mat& depth_m, const Pose& pose_in_keyframe) const {
  cv::Mat points;
  cv::rgbd::depthTo3d(depth_m, camera_matrix_, points);
  Matrix6d h = Matrix6d::Zero();
  double squared = 0;
  int n = 0;
  const int s = params_.covariance_stride;
  for (int v = 0; v < points.rows; v += s) {
    for (int u = 0; u < points.cols; u += s) {
      const cv::Vec3f& pc = points.at<cv::Vec3f>(v, u);
      if (!std::isfinite(pc[2])) continue;
      const Eigen::Vector3d p = pose_in_keyframe * Eigen::Vector3d(pc[0], pc[1], pc[2]);
      if (!(p.z() > 0)) continue;
      const int ku = static_cast<int>(std::lround(k_.fx * p.x() / p.z() + k_.cx));
      const int kv = static_cast<int>(std::lround(k_.fy * p.y() / p.z() + k_.cy));
      if (ku < 0 || kv < 0 || ku >= points.cols || kv >= points.rows) continue;
      const cv::Vec3f& q = keyframe_->points.at<cv::Vec3f>(kv, ku);
      const cv::Vec3f& nk = keyframe_->normals.at<cv::Vec3f>(kv, ku);
      if (!std::isfinite(q[2]) || !std::isfinite(nk[0])) continue;
      const Eigen::Vector3d normal(nk[0], nk[1], nk[2]);
      const double r = normal.dot(p - Eigen::Vector3d(q[0], q[1], q[2]));
      if (std::abs(r) > params_.covariance_max_residual) continue;
      // d r / d (dt, dphi) of a left perturbation p' = exp(xi) p, in the keyframe's frame.
      Vector6d j;
      j << normal, p.cross(normal);
      h.noalias() += j * j.transpose();
      squared += r * r;
      ++n;
    }
  }
  const Eigen::LDLT<Matrix6d> ldlt(h);
  if (n <= 6 || ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0)) return Matrix6d::Zero();
  const Matrix6d left = (squared / (n - 6)) * ldlt.solve(Matrix6d::Identity());
  // pose = exp(xi_left) pose = pose exp(Ad(pose^-1) xi_left): the contract's right perturbation.
  const Matrix6d ad = adjoint(pose_in_keyframe.inverse());
  Matrix6d right = params_.covariance_scale * (ad * left * ad.transpose());
  right.diagonal() += (Vector6d() << Eigen::Vector3d::Constant(params_.covariance_floor_t * params_.covariance_floor_t),
                       Eigen::Vector3d::Constant(params_.covariance_floor_r * params_.covariance_floor_r))
                          .finished();
  return 0.5 * (right + right.transpose());
}

CvTracked CvOdometry::track(const cv::Mat& depth, const cv::Mat& color) {
  const cv::Mat depth_m = depthMetres(depth);
  cv::Mat gray;
  cv::cvtColor(color, gray, cv::COLOR_BGR2GRAY);
  cv::Ptr<cv::rgbd::OdometryFrame> frame = cv::rgbd::OdometryFrame::create(gray, depth_m);
  odometry_->prepareFrameCache(frame, cv::rgbd::OdometryFrame::CACHE_ALL);
  CvTracked out;
  if (!keyframe_) {
    startKeyframe(frame, depth_m, Pose::Identity());
    out.new_keyframe = true;
    return out;
  }
  cv::Mat rt;
  const bool ok = odometry_->compute(frame, keyframe_->frame, rt, matOf(last_pose_));
  out.keyframe_id = keyframe_->id;
  out.keyframe_world = keyframe_->world;
  if (!ok || rt.empty() || !cv::checkRange(rt)) {
    out.lost = true;
    out.pose_in_keyframe = last_pose_;
    return out;
  }
  const Pose pose = poseOf(rt);
  if (pose.translation().norm() > params_.keyframe_translation ||
      Eigen::AngleAxisd(pose.linear()).angle() * 180.0 / M_PI > params_.keyframe_rotation_deg) {
    startKeyframe(frame, depth_m, orthonormalised(keyframe_->world * pose));
    out.keyframe_id = keyframe_->id;
    out.keyframe_world = keyframe_->world;
    out.new_keyframe = true;
    return out;
  }
  last_pose_ = pose;
  out.pose_in_keyframe = pose;
  out.covariance = covariance(depth_m, pose);
  return out;
}

}  // namespace rekon::odometry_cv
