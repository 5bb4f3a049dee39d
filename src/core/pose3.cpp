#include "toro_ros/core/pose3.h"

#include <cmath>

namespace toro {

Pose3 Pose3::fromRollPitchYaw(double x, double y, double z, double roll, double pitch, double yaw) {
  const Quaternion q = Eigen::AngleAxisd(yaw, Vector3::UnitZ()) *
                       Eigen::AngleAxisd(pitch, Vector3::UnitY()) *
                       Eigen::AngleAxisd(roll, Vector3::UnitX());
  return Pose3(q, Vector3(x, y, z));
}

Pose3 Pose3::fromAngleAxis(const Vector3& rotation_vector, const Vector3& translation) {
  return Pose3(quaternionFromRotationVector(rotation_vector), translation);
}

Vector3 Pose3::rollPitchYaw() const {
  const Matrix3 r = rotationMatrix();
  const double roll = std::atan2(r(2, 1), r(2, 2));
  const double pitch = std::atan2(-r(2, 0), std::sqrt(r(2, 1) * r(2, 1) + r(2, 2) * r(2, 2)));
  const double yaw = std::atan2(r(1, 0), r(0, 0));
  return Vector3(roll, pitch, yaw);
}

Vector3 Pose3::angleAxis() const { return rotationVectorFromQuaternion(rotation_); }

double Pose3::angle() const {
  // 2*atan2(|v|, |w|) is accurate for small and large angles alike (acos(w) is not near 0).
  return 2.0 * std::atan2(rotation_.vec().norm(), std::abs(rotation_.w()));
}

Quaternion quaternionFromRotationVector(const Vector3& rotation_vector) {
  const double theta = rotation_vector.norm();
  const double half = 0.5 * theta;
  // sin(half)/theta, with its Taylor series near zero to avoid 0/0.
  const double k = theta < 1e-8 ? 0.5 - theta * theta / 48.0 : std::sin(half) / theta;
  return Quaternion(std::cos(half), k * rotation_vector.x(), k * rotation_vector.y(),
                    k * rotation_vector.z());
}

Vector3 rotationVectorFromQuaternion(const Quaternion& q_in) {
  // Take the representative with w >= 0 so the angle is in [0, pi].
  const Quaternion q = q_in.w() < 0 ? Quaternion(-q_in.coeffs()) : q_in;
  const double n = q.vec().norm();
  if (n < 1e-12) {
    // angle ~ 2n and axis*angle ~ 2*vec/w.
    return (2.0 / q.w()) * q.vec();
  }
  const double theta = 2.0 * std::atan2(n, q.w());
  return (theta / n) * q.vec();
}

Quaternion slerpFromIdentity(const Quaternion& q, double fraction) {
  return quaternionFromRotationVector(fraction * rotationVectorFromQuaternion(q));
}

Pose3 slerp(const Pose3& a, const Pose3& b, double fraction) {
  const Quaternion delta = a.rotation().conjugate() * b.rotation();
  const Quaternion r = a.rotation() * slerpFromIdentity(delta, fraction);
  return Pose3(r, (1.0 - fraction) * a.translation() + fraction * b.translation());
}

}  // namespace toro
