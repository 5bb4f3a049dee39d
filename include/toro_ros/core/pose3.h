// SE(3) value type used throughout the core: a unit quaternion and a translation.
//
// Convention: a Pose3 named `a_T_b` maps coordinates in frame b to frame a, so
// `a_T_c = a_T_b * b_T_c`.  A constraint i->j measures `i_T_j`.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace toro {

using Vector3 = Eigen::Vector3d;
using Vector6 = Eigen::Matrix<double, 6, 1>;
using Matrix3 = Eigen::Matrix3d;
using Matrix6 = Eigen::Matrix<double, 6, 6>;
using Quaternion = Eigen::Quaterniond;

class Pose3 {
 public:
  Pose3() : rotation_(Quaternion::Identity()), translation_(Vector3::Zero()) {}
  // The quaternion is normalised here so that every Pose3 holds a rotation.
  Pose3(const Quaternion& rotation, const Vector3& translation)
      : rotation_(rotation.normalized()), translation_(translation) {}

  static Pose3 identity() { return Pose3(); }
  // R = Rz(yaw) * Ry(pitch) * Rx(roll), the convention of TORO, g2o and GTSAM.
  static Pose3 fromRollPitchYaw(double x, double y, double z, double roll, double pitch, double yaw);
  // Rotation vector (axis * angle, radians) and translation.
  static Pose3 fromAngleAxis(const Vector3& rotation_vector, const Vector3& translation);

  const Quaternion& rotation() const { return rotation_; }
  const Vector3& translation() const { return translation_; }
  Matrix3 rotationMatrix() const { return rotation_.toRotationMatrix(); }

  // Rotation skipping the normalisation of the constructor; the caller guarantees a unit quaternion.
  void setRotationUnchecked(const Quaternion& q) { rotation_ = q; }
  void setTranslation(const Vector3& t) { translation_ = t; }

  Pose3 operator*(const Pose3& other) const {
    Pose3 out;
    out.rotation_ = rotation_ * other.rotation_;
    out.translation_ = translation_ + rotation_ * other.translation_;
    return out;
  }
  Vector3 operator*(const Vector3& point) const { return translation_ + rotation_ * point; }

  Pose3 inverse() const {
    Pose3 out;
    out.rotation_ = rotation_.conjugate();
    out.translation_ = -(out.rotation_ * translation_);
    return out;
  }

  // (roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll); pitch in [-pi/2, pi/2].
  Vector3 rollPitchYaw() const;
  // Rotation vector (axis * angle) with angle in [0, pi].
  Vector3 angleAxis() const;
  // Rotation angle in [0, pi].
  double angle() const;

  bool isFinite() const { return rotation_.coeffs().allFinite() && translation_.allFinite(); }

  // Re-normalise the quaternion after many multiplications (drift control in long loops).
  void normalize() { rotation_.normalize(); }
  // Cheap first-order re-normalisation, q *= (3 - |q|^2) / 2, for quaternions already within
  // rounding error of unit length (it removes the drift of repeated products without a sqrt).
  void renormalize() { rotation_.coeffs() *= 0.5 * (3.0 - rotation_.squaredNorm()); }

 private:
  Quaternion rotation_;
  Vector3 translation_;
};

// a_T_b given world_T_a and world_T_b.
inline Pose3 relativePose(const Pose3& world_T_a, const Pose3& world_T_b) {
  return world_T_a.inverse() * world_T_b;
}

// The cross-product matrix: skew(a) * b == a.cross(b).
inline Matrix3 skew(const Vector3& v) {
  Matrix3 m;
  m << 0.0, -v.z(), v.y(),  //
      v.z(), 0.0, -v.x(),   //
      -v.y(), v.x(), 0.0;
  return m;
}

// Adjoint of a pose for twists ordered (translation, rotation): carries a covariance of a frame's
// pose error into the frame t maps it to, Ad(t) * Sigma * Ad(t)^T (first order).
inline Matrix6 adjoint(const Pose3& t) {
  Matrix6 a = Matrix6::Zero();
  const Matrix3 r = t.rotationMatrix();
  a.topLeftCorner<3, 3>() = r;
  a.topRightCorner<3, 3>() = skew(t.translation()) * r;
  a.bottomRightCorner<3, 3>() = r;
  return a;
}

// Quaternion for a rotation vector, with a small-angle branch.
Quaternion quaternionFromRotationVector(const Vector3& rotation_vector);
// Rotation vector of a unit quaternion, taking the shorter way (angle in [0, pi]).
Vector3 rotationVectorFromQuaternion(const Quaternion& q);

// Rotation part: spherical interpolation (shorter arc); translation part: linear.
// fraction 0 gives a, 1 gives b.
Pose3 slerp(const Pose3& a, const Pose3& b, double fraction);

// Spherical interpolation from the identity to q: the rotation about q's axis by fraction * angle(q).
Quaternion slerpFromIdentity(const Quaternion& q, double fraction);

}  // namespace toro
