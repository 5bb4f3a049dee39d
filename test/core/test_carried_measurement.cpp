// carriedInformation: a measurement between two stamps carried to keyframes along the odometry
// keeps its own noise and gains the odometry's, in the frame the constraint is expressed in.
#include <gtest/gtest.h>

#include <Eigen/LU>

#include "toro_ros/core/carried_measurement.h"

namespace toro {
namespace {

Matrix6 diagonal(double tx, double ty, double tz, double rx, double ry, double rz) {
  Vector6 d;
  d << tx, ty, tz, rx, ry, rz;
  return d.asDiagonal();
}

Pose3 translation(double x, double y, double z) { return Pose3(Quaternion::Identity(), Vector3(x, y, z)); }

TEST(CarriedMeasurement, NoOffsetUncertaintyKeepsTheInformation) {
  const Matrix6 info = diagonal(1e6, 1e6, 1e6, 1e4, 1e4, 1e4);
  const Matrix6 out =
      carriedInformation(Matrix6::Zero(), translation(1, 0, 0), info, Pose3(), Matrix6::Zero());
  EXPECT_LT((out - info).norm(), 1e-6 * info.norm());
}

// A millimetre-sure measurement carried over odometry with 5 cm of noise is 5 cm sure: the
// covariances add (B at the identity, so no frame change).
TEST(CarriedMeasurement, OffsetCovarianceAdds) {
  const Matrix6 info = diagonal(1e6, 1e6, 1e6, 1e4, 1e4, 1e4);
  const Matrix6 offset = diagonal(0.05 * 0.05, 0.05 * 0.05, 0.0, 0.0, 0.0, 1e-4);
  const Matrix6 out = carriedInformation(Matrix6::Zero(), translation(1, 0, 0), info, Pose3(), offset);
  const Matrix6 expected = (info.inverse() + offset).inverse();
  EXPECT_LT((out - expected).norm(), 1e-9 * expected.norm());
  EXPECT_NEAR(1.0 / out(0, 0), 1e-6 + 0.0025, 1e-9);
}

// The uncertainty of the near end's heading moves the far end sideways by the lever arm: with Z a
// metre forwards, a yaw variance s2 at the start adds s2 to y (and to yaw) of the carried one.
TEST(CarriedMeasurement, HeadingOfTheStartOffsetActsOverTheMeasurementsLength) {
  const Matrix6 info = diagonal(1e6, 1e6, 1e6, 1e6, 1e6, 1e6);
  const double s2 = 1e-4;
  const Matrix6 out =
      carriedInformation(diagonal(0, 0, 0, 0, 0, s2), translation(1, 0, 0), info, Pose3(), Matrix6::Zero());
  const Matrix6 covariance = out.inverse();
  EXPECT_NEAR(covariance(1, 1), 1e-6 + s2, 1e-10);
  EXPECT_NEAR(covariance(5, 5), 1e-6 + s2, 1e-10);
  EXPECT_NEAR(covariance(0, 0), 1e-6, 1e-10);
  EXPECT_NEAR(std::abs(covariance(1, 5)), s2, 1e-10);  // y and yaw move together
}

// Axes the measurement does not measure stay unmeasured whatever the odometry adds there.
TEST(CarriedMeasurement, UnmeasuredAxesStayUnmeasured) {
  const Matrix6 info = diagonal(1e6, 1e6, 0.0, 0.0, 0.0, 1e4);
  const Matrix6 offset = diagonal(1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4);
  const Matrix6 out = carriedInformation(Matrix6::Zero(), translation(1, 0, 0), info, Pose3(), offset);
  EXPECT_NEAR(out(2, 2), 0.0, 1e-12);
  EXPECT_NEAR(out(3, 3), 0.0, 1e-12);
  EXPECT_NEAR(out(4, 4), 0.0, 1e-12);
  EXPECT_NEAR(1.0 / out(0, 0), 1e-6 + 1e-4, 1e-9);
}

TEST(CarriedMeasurement, MeasuredCovarianceInvertsOnlyMeasuredAxes) {
  const Matrix6 c = measuredCovariance(diagonal(100, 400, 1e-20, 4, 1, 0));
  EXPECT_NEAR(c(0, 0), 0.01, 1e-12);
  EXPECT_NEAR(c(1, 1), 0.0025, 1e-12);
  EXPECT_EQ(c(2, 2), 0.0);
  EXPECT_NEAR(c(3, 3), 0.25, 1e-12);
  EXPECT_EQ(c(5, 5), 0.0);
}

TEST(CarriedMeasurement, FlaggedVariancesAreNoSize) {
  // diff_drive_controller's planar odometry: x, y, yaw measured, z, roll, pitch at 1e6 (information
  // 1e-6, a ratio 4e-10 of x's) -- below kUnmeasuredInformationRatio, no variance.
  const Matrix6 planar = measuredCovariance(diagonal(2500, 2500, 1e-6, 1e-6, 1e-6, 400));
  EXPECT_NEAR(planar(0, 0), 4e-4, 1e-15);
  EXPECT_EQ(planar(2, 2), 0.0);
  EXPECT_EQ(planar(3, 3), 0.0);
  EXPECT_NEAR(planar(5, 5), 2.5e-3, 1e-15);
  // A vague odometry (1 m^2) with roll at the 1e3 flag: a ratio of only 1e-3, so the flag's own
  // threshold says it (variance >= 1e3: unmeasured); just below it, it is a variance.
  const Matrix6 vague = diagonal(1, 1, 1, 1e-3, 1.001e-3, 1);
  EXPECT_NEAR(measuredCovariance(vague)(3, 3), 1e3, 1e-9);
  EXPECT_EQ(measuredCovariance(vague, 1e3)(3, 3), 0.0);
  EXPECT_NEAR(measuredCovariance(vague, 1e3)(4, 4), 1 / 1.001e-3, 1e-9);
  EXPECT_NEAR(measuredCovariance(vague, 1e3)(0, 0), 1.0, 1e-12);
}

}  // namespace
}  // namespace toro
