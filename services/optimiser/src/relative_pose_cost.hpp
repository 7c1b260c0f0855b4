#pragma once
// The relative-pose residual: written once as a template for the value
// (relativePoseResidual() on doubles, the reference that tests differentiate
// with Jets), and once with analytic Jacobians for Ceres (RelativePoseCost).
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "rekon/common/se3.hpp"

namespace rekon::optimiser::detail {

// E = Z^-1 * A^-1 * B with Z = (q_z, t_z); out = (t_E, 2 * sign(w_E) * vec(q_E)).
// The sign picks the quaternion with w >= 0 so that the rotation error is the
// short way round.
template <typename T>
void relativeError(const T* qa_ptr, const T* ta_ptr, const T* qb_ptr, const T* tb_ptr,
                   const Eigen::Quaterniond& q_z_inverse, const Eigen::Vector3d& t_z, T* out) {
  const Eigen::Map<const Eigen::Quaternion<T>> qa(qa_ptr), qb(qb_ptr);
  const Eigen::Map<const Eigen::Matrix<T, 3, 1>> ta(ta_ptr), tb(tb_ptr);
  const Eigen::Quaternion<T> qa_inverse = qa.conjugate();
  const Eigen::Quaternion<T> q_ab = qa_inverse * qb;
  const Eigen::Matrix<T, 3, 1> t_ab = qa_inverse * (tb - ta);
  const Eigen::Quaternion<T> qz_inv = q_z_inverse.template cast<T>();
  const Eigen::Quaternion<T> q_e = qz_inv * q_ab;
  const Eigen::Matrix<T, 3, 1> t_e = qz_inv * (t_ab - t_z.template cast<T>());
  const T two = q_e.w() < T(0) ? T(-2) : T(2);
  out[0] = t_e[0];
  out[1] = t_e[1];
  out[2] = t_e[2];
  out[3] = two * q_e.x();
  out[4] = two * q_e.y();
  out[5] = two * q_e.z();
}

// One edge: the measurement Z, precomputed.
struct RelativeMeasurement {
  Eigen::Quaterniond q_z_inverse;
  Eigen::Matrix3d r_z_transpose;
  Eigen::Vector3d t_z;

  explicit RelativeMeasurement(const Eigen::Quaterniond& q_z_inv, const Eigen::Vector3d& t)
      : q_z_inverse(q_z_inv), r_z_transpose(q_z_inv.toRotationMatrix()), t_z(t) {}
};

// The unwhitened error e of relativeError() and, when ja/jb are given, its
// Jacobians in closed form with respect to world-frame perturbations of each
// pose, (dt, phi): t' = t + dt, R' = Exp(phi) R. With M = w_E I + [vec(q_E)]x
// (w_E >= 0) and d = t_b - t_a:
//   de_t/dt_b = (R_a R_z)^T = -de_t/dt_a,   de_t/dphi_a = (R_a R_z)^T [d]x,   de_t/dphi_b = 0,
//   de_r/dphi_b = M R_b^T = -de_r/dphi_a,   de_r/dt = 0.
// (Autodiff through the quaternion products on 14-wide Jets costs 4x more.)
inline void relativeErrorAndJacobians(const double* pose_a, const double* pose_b, const RelativeMeasurement& z,
                                      Vector6d& e, Matrix6d* ja, Matrix6d* jb) {
  using Mat3 = Eigen::Matrix3d;
  const Eigen::Map<const Eigen::Quaterniond> qa(pose_a + 3), qb(pose_b + 3);
  const Eigen::Map<const Eigen::Vector3d> ta(pose_a), tb(pose_b);
  const Mat3 ra = qa.toRotationMatrix();
  const Eigen::Vector3d d = tb - ta;
  const Mat3 raz_t = z.r_z_transpose * ra.transpose();
  Eigen::Quaterniond q_e = z.q_z_inverse * (qa.conjugate() * qb);
  if (q_e.w() < 0) q_e.coeffs() = -q_e.coeffs();
  e.head<3>() = raz_t * d - z.r_z_transpose * z.t_z;
  e.tail<3>() = 2.0 * q_e.vec();
  if (ja == nullptr && jb == nullptr) return;
  Mat3 m = skew(q_e.vec());
  m.diagonal().array() += q_e.w();
  const Mat3 dr_db = m * qb.toRotationMatrix().transpose();
  if (jb != nullptr) {
    jb->setZero();
    jb->topLeftCorner<3, 3>() = raz_t;
    jb->bottomRightCorner<3, 3>() = dr_db;
  }
  if (ja != nullptr) {
    ja->topLeftCorner<3, 3>() = -raz_t;
    ja->topRightCorner<3, 3>() = raz_t * skew(d);
    ja->bottomLeftCorner<3, 3>().setZero();
    ja->bottomRightCorner<3, 3>() = -dr_db;
  }
}

// The 4x3 Jacobian of EigenQuaternionManifold::Plus at delta = 0, rows (x, y, z, w).
inline Eigen::Matrix<double, 4, 3> quaternionPlusJacobian(const Eigen::Quaterniond& q) {
  Eigen::Matrix<double, 4, 3> p;
  p.topRows<3>() = q.w() * Eigen::Matrix3d::Identity() - skew(q.vec());
  p.row(3) = -q.vec().transpose();
  return p;
}

// Ceres cost of one edge: whitened residual U * e with U^T U = information,
// each pose block (tx, ty, tz, qx, qy, qz, qw) on R^3 x EigenQuaternionManifold.
// That manifold perturbs q' = [sin|d| d/|d|, cos|d|] * q, i.e. phi = 2 d. Ceres
// wants Jacobians in the ambient 7 coordinates and multiplies them by the
// manifold's 7x6 PlusJacobian; for a unit quaternion its quaternion part Q
// (4x3) has orthonormal columns, so the ambient Jacobian J_tangent * Q^T
// gives back exactly J_tangent after that product.
class RelativePoseCost final : public ceres::SizedCostFunction<6, 7, 7> {
 public:
  RelativePoseCost(const RelativeMeasurement& z, const Matrix6d& sqrt_information)
      : z_(z), u_(sqrt_information) {}

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    Vector6d e;
    Matrix6d ja, jb;
    const bool want = jacobians != nullptr;
    relativeErrorAndJacobians(parameters[0], parameters[1], z_, e, want && jacobians[0] ? &ja : nullptr,
                              want && jacobians[1] ? &jb : nullptr);
    Eigen::Map<Vector6d> r(residuals);
    r.noalias() = u_ * e;
    if (!want) return true;
    if (jacobians[0] != nullptr) writeAmbient(ja, parameters[0], jacobians[0]);
    if (jacobians[1] != nullptr) writeAmbient(jb, parameters[1], jacobians[1]);
    return true;
  }

 private:
  void writeAmbient(const Matrix6d& tangent, const double* pose, double* out) const {
    const Matrix6d whitened = u_ * tangent;
    Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> j(out);
    j.leftCols<3>() = whitened.leftCols<3>();
    j.rightCols<4>() = 2.0 * whitened.rightCols<3>() * quaternionPlusJacobian(Eigen::Quaterniond(pose + 3)).transpose();
  }

  RelativeMeasurement z_;
  Matrix6d u_;
};

}  // namespace rekon::optimiser::detail
