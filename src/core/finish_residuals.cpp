#include "toro_ros/core/finish_residuals.h"

#include <cmath>

namespace toro {

namespace {

// D = Z^-1 X_i^-1 X_j with its quaternion flipped to w >= 0 (the g2o error's representative).
Pose3 residualPose(const Pose3& x_i, const Pose3& x_j, const Pose3& z, Quaternion* q) {
  const Pose3 d = z.inverse() * (x_i.inverse() * x_j);
  *q = d.rotation();
  if (q->w() < 0.0) q->coeffs() = -q->coeffs();
  return d;
}

}  // namespace

double wrapAngle(double angle) {
  const double a = std::remainder(angle, 2.0 * M_PI);
  return a <= -M_PI ? a + 2.0 * M_PI : a;
}

Vector6 errorSE3(const Pose3& x_i, const Pose3& x_j, const Pose3& measurement) {
  Quaternion q;
  const Pose3 d = residualPose(x_i, x_j, measurement, &q);
  Vector6 e;
  e << d.translation(), q.vec();
  return e;
}

void linearizeSE3(const Pose3& x_i, const Pose3& x_j, const Pose3& z, Linearization3D* out) {
  Quaternion q;
  const Pose3 d = residualPose(x_i, x_j, z, &q);
  out->error << d.translation(), q.vec();
  const Matrix3 r_d = q.toRotationMatrix();
  const Matrix3 rz_t = z.rotationMatrix().transpose();
  const Matrix3 q_skew = skew(q.vec());
  const Matrix3 w_identity = q.w() * Matrix3::Identity();

  // X_j <- X_j (Exp(phi), rho) gives D <- D (Exp(phi), rho): t_D moves by R_D rho, and the
  // quaternion product q (1, phi/2) moves the vector part by (w I + [v]x) phi / 2.
  out->d_to.setZero();
  out->d_to.topLeftCorner<3, 3>() = r_d;
  out->d_to.bottomRightCorner<3, 3>() = 0.5 * (w_identity + q_skew);

  // X_i <- X_i (Exp(phi), rho) gives D <- M D with M = Z^-1 (Exp(-phi), -rho) Z, a left
  // perturbation of D by rotation psi = -Rz^T phi and translation Rz^T ([t_Z]x phi - rho).
  // Then t_D moves by [t_D]x Rz^T phi + Rz^T [t_Z]x phi - Rz^T rho, and the quaternion product
  // (1, psi/2) q moves the vector part by (w I - [v]x) psi / 2.
  out->d_from.setZero();
  out->d_from.topLeftCorner<3, 3>() = -rz_t;
  out->d_from.topRightCorner<3, 3>() = skew(d.translation()) * rz_t + rz_t * skew(z.translation());
  out->d_from.bottomRightCorner<3, 3>() = -0.5 * (w_identity - q_skew) * rz_t;
}

Pose3 retractSE3(const Pose3& x, const Vector6& delta) {
  const Vector3 phi = delta.tail<3>();
  const double theta2 = phi.squaredNorm();
  const double theta = std::sqrt(theta2);
  // SE(3) exponential: translation V(phi) rho, V = I + b [phi]x + c [phi]x^2.
  double b, c;
  if (theta < 1e-4) {
    b = 0.5 - theta2 / 24.0;
    c = 1.0 / 6.0 - theta2 / 120.0;
  } else {
    b = (1.0 - std::cos(theta)) / theta2;
    c = (theta - std::sin(theta)) / (theta2 * theta);
  }
  const Matrix3 k = skew(phi);
  const Vector3 t = delta.head<3>() + b * (k * delta.head<3>()) + c * (k * (k * delta.head<3>()));
  return x * Pose3(quaternionFromRotationVector(phi), t);
}

Vector3 errorSE2(const Vector3& x_i, const Vector3& x_j, const Vector3& z) {
  const double ci = std::cos(x_i.z()), si = std::sin(x_i.z());
  const double cz = std::cos(z.z()), sz = std::sin(z.z());
  const double dx = x_j.x() - x_i.x(), dy = x_j.y() - x_i.y();
  // Ri^T (tj - ti) - tz, then rotated by Rz^T.
  const double lx = ci * dx + si * dy - z.x();
  const double ly = -si * dx + ci * dy - z.y();
  return Vector3(cz * lx + sz * ly, -sz * lx + cz * ly, wrapAngle(x_j.z() - x_i.z() - z.z()));
}

void linearizeSE2(const Vector3& x_i, const Vector3& x_j, const Vector3& z, Linearization2D* out) {
  out->error = errorSE2(x_i, x_j, z);
  const double ci = std::cos(x_i.z()), si = std::sin(x_i.z());
  const double cz = std::cos(z.z()), sz = std::sin(z.z());
  const double dx = x_j.x() - x_i.x(), dy = x_j.y() - x_i.y();
  Eigen::Matrix2d rz_t, ri_t, dri_t;
  rz_t << cz, sz, -sz, cz;
  ri_t << ci, si, -si, ci;
  dri_t << -si, ci, -ci, -si;  // d(Ri^T) / d theta_i
  const Eigen::Matrix2d a = rz_t * ri_t;
  out->d_to.setZero();
  out->d_to.topLeftCorner<2, 2>() = a;
  out->d_to(2, 2) = 1.0;
  out->d_from.setZero();
  out->d_from.topLeftCorner<2, 2>() = -a;
  out->d_from.topRightCorner<2, 1>() = rz_t * dri_t * Eigen::Vector2d(dx, dy);
  out->d_from(2, 2) = -1.0;
}

}  // namespace toro
