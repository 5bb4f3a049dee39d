#include "toro_ros/core/pose2.h"

#include <cmath>

namespace toro {

Pose2 planarPart(const Pose3& pose) {
  const Quaternion& q = pose.rotation();
  // The first column of R: (R00, R10) points along the heading; its length is cos(pitch).
  const double r00 = 1.0 - 2.0 * (q.y() * q.y() + q.z() * q.z());
  const double r10 = 2.0 * (q.x() * q.y() + q.w() * q.z());
  const double norm = std::hypot(r00, r10);
  const Vector2 xy = pose.translation().head<2>();
  // Pitch of +-90 degrees: the heading is undefined; the Euler convention's yaw decides.
  if (!(norm > 1e-9)) return Pose2(Rotation2::fromAngle(pose.rollPitchYaw().z()), xy);
  return Pose2(Rotation2(r00 / norm, r10 / norm), xy);
}

}  // namespace toro
