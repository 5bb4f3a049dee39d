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
  const double theta2 = rotation_vector.squaredNorm();
  double c, k;  // cos(theta/2) and sin(theta/2)/theta
  if (theta2 < 0.01) {
    // Taylor series: below 0.1 rad the truncation error is under 1e-16, it avoids 0/0 at zero and
    // is several times faster than sin/cos in the optimiser's inner loop, where angles are small.
    const double h2 = 0.25 * theta2;  // (theta/2)^2
    c = 1.0 - h2 / 2.0 * (1.0 - h2 / 12.0 * (1.0 - h2 / 30.0 * (1.0 - h2 / 56.0)));
    k = 0.5 * (1.0 - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0))));
  } else {
    const double theta = std::sqrt(theta2);
    c = std::cos(0.5 * theta);
    k = std::sin(0.5 * theta) / theta;
  }
  return Quaternion(c, k * rotation_vector.x(), k * rotation_vector.y(), k * rotation_vector.z());
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
