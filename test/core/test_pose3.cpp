#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "toro_ros/core/pose3.h"
#include "toro_ros/core/random_draws.h"

using namespace toro;

namespace {
Pose3 randomPose(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return drawPose3(n, n, rng);
}
void expectNear(const Pose3& a, const Pose3& b, double tol) {
  EXPECT_LT((a.inverse() * b).angle(), tol);
  EXPECT_LT((a.translation() - b.translation()).norm(), tol);
}
}  // namespace

TEST(Pose3, ComposeInverseIdentity) {
  std::mt19937 rng(1);
  for (int i = 0; i < 100; ++i) {
    const Pose3 a = randomPose(rng), b = randomPose(rng), c = randomPose(rng);
    expectNear(a * a.inverse(), Pose3(), 1e-12);
    expectNear((a * b) * c, a * (b * c), 1e-12);
    expectNear(a * relativePose(a, b), b, 1e-12);
    const Vector3 p(0.3, -1.2, 2.0);
    EXPECT_LT(((a * b) * p - a * (b * p)).norm(), 1e-12);
  }
}

TEST(Pose3, RollPitchYawConvention) {
  // R = Rz(yaw) Ry(pitch) Rx(roll): a pure yaw of 90 degrees sends x to y.
  const Pose3 yaw = Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, M_PI / 2);
  EXPECT_LT((yaw * Vector3(1, 0, 0) - Vector3(0, 1, 0)).norm(), 1e-12);
  const Pose3 roll = Pose3::fromRollPitchYaw(0, 0, 0, M_PI / 2, 0, 0);
  EXPECT_LT((roll * Vector3(0, 1, 0) - Vector3(0, 0, 1)).norm(), 1e-12);
  // Composition order: first roll, then pitch, then yaw (in the fixed frame).
  const double r = 0.3, p = -0.4, y = 1.1;
  const Matrix3 expected = (Eigen::AngleAxisd(y, Vector3::UnitZ()) * Eigen::AngleAxisd(p, Vector3::UnitY()) *
                            Eigen::AngleAxisd(r, Vector3::UnitX())).toRotationMatrix();
  EXPECT_LT((Pose3::fromRollPitchYaw(0, 0, 0, r, p, y).rotationMatrix() - expected).norm(), 1e-12);
  const Vector3 rpy = Pose3::fromRollPitchYaw(1, 2, 3, r, p, y).rollPitchYaw();
  EXPECT_NEAR(rpy.x(), r, 1e-12);
  EXPECT_NEAR(rpy.y(), p, 1e-12);
  EXPECT_NEAR(rpy.z(), y, 1e-12);
}

TEST(Pose3, AngleAxisRoundTripIncludingSmallAngles) {
  for (double angle : {0.0, 1e-14, 1e-9, 1e-4, 0.5, 3.0, M_PI - 1e-9}) {
    const Vector3 v = angle * Vector3(1, -2, 0.5).normalized();
    const Pose3 p = Pose3::fromAngleAxis(v, Vector3::Zero());
    EXPECT_LT((p.angleAxis() - v).norm(), 1e-12 + 1e-9 * angle) << angle;
    EXPECT_NEAR(p.angle(), angle, 1e-12);
  }
}

TEST(Pose3, SlerpEndPointsAndMidpoint) {
  std::mt19937 rng(2);
  for (int i = 0; i < 50; ++i) {
    const Pose3 a = randomPose(rng), b = randomPose(rng);
    expectNear(slerp(a, b, 0.0), a, 1e-12);
    expectNear(slerp(a, b, 1.0), b, 1e-12);
    const Pose3 m = slerp(a, b, 0.5);
    // The midpoint is equally far (in angle) from both ends, at half the total angle.
    const double total = relativePose(a, b).angle();
    EXPECT_NEAR(relativePose(a, m).angle(), 0.5 * total, 1e-9);
    EXPECT_NEAR(relativePose(m, b).angle(), 0.5 * total, 1e-9);
  }
}

TEST(Pose3, SlerpFromIdentityComposes) {
  // slerp(I, q, s) * slerp(I, q, t) == slerp(I, q, s + t): the same axis, angles add.
  const Quaternion q = quaternionFromRotationVector(Vector3(0.4, -0.2, 1.0));
  const Quaternion lhs = slerpFromIdentity(q, 0.3) * slerpFromIdentity(q, 0.5);
  EXPECT_LT(lhs.angularDistance(slerpFromIdentity(q, 0.8)), 1e-12);
}

TEST(Pose3, QuaternionFromRotationVectorSeriesMatchesTrigonometry) {
  // The small-angle series branch (below 0.1 rad) must agree with sin/cos to double precision.
  for (double angle : {1e-12, 1e-6, 1e-3, 0.05, 0.0999, 0.1001, 0.3}) {
    const Vector3 axis = Vector3(0.3, -0.5, 0.8).normalized();
    const Quaternion q = quaternionFromRotationVector(angle * axis);
    EXPECT_NEAR(q.w(), std::cos(angle / 2), 1e-16) << angle;
    EXPECT_LT((q.vec() - std::sin(angle / 2) * axis).norm(), 1e-16) << angle;
  }
}
