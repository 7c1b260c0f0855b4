#pragma once
// The relative-pose residual, written once as a template: Ceres evaluates it
// on Jets for the Jacobians, relativePoseResidual() on doubles.
#include <Eigen/Core>
#include <Eigen/Geometry>

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

// Whitened residual U * e with U^T U = information.
struct RelativePoseCost {
  Eigen::Quaterniond q_z_inverse;
  Eigen::Vector3d t_z;
  Eigen::Matrix<double, 6, 6> sqrt_information;

  // Each pose block is (tx, ty, tz, qx, qy, qz, qw).
  template <typename T>
  bool operator()(const T* a, const T* b, T* residual) const {
    T e[6];
    relativeError(a + 3, a, b + 3, b, q_z_inverse, t_z, e);
    for (int r = 0; r < 6; ++r) {
      residual[r] = T(0);
      for (int c = r; c < 6; ++c) residual[r] += sqrt_information(r, c) * e[c];  // U is upper triangular
    }
    return true;
  }
};

}  // namespace rekon::optimiser::detail
