#include <gtest/gtest.h>

#include "toro_ros/pipeline/keyframer.h"

using namespace toro_ros;

namespace {

OdometrySample sample(double t, double x, double yaw) {
  return OdometrySample{ros::Time(t), toro::Pose3::fromRollPitchYaw(x, 0, 0, 0, 0, yaw),
                        toro::Matrix6::Zero()};
}

KeyframerOptions options() {
  KeyframerOptions o;
  o.distance_m = 0.5;
  o.angle_rad = 0.3;
  o.interval_sec = 5.0;
  return o;
}

}  // namespace

TEST(Keyframer, FirstSampleIsAKeyframe) {
  Keyframer k(options());
  EXPECT_TRUE(k.isKeyframe(sample(1, 0, 0)));
  EXPECT_FALSE(k.accept(sample(1, 0, 0)).has_value());
}

TEST(Keyframer, DistanceAngleAndIntervalThresholds) {
  Keyframer k(options());
  k.accept(sample(1, 0, 0));
  EXPECT_FALSE(k.isKeyframe(sample(2, 0.49, 0)));
  EXPECT_TRUE(k.isKeyframe(sample(2, 0.51, 0)));
  EXPECT_FALSE(k.isKeyframe(sample(2, 0, 0.29)));
  EXPECT_TRUE(k.isKeyframe(sample(2, 0, -0.31)));
  EXPECT_FALSE(k.isKeyframe(sample(5.9, 0, 0)));
  EXPECT_TRUE(k.isKeyframe(sample(6.0, 0, 0)));
  KeyframerOptions no_time = options();
  no_time.interval_sec = 0;
  Keyframer k2(no_time);
  k2.accept(sample(1, 0, 0));
  EXPECT_FALSE(k2.isKeyframe(sample(1000, 0, 0)));
}

TEST(Keyframer, ThresholdsAreRelativeToTheLastKeyframeInItsFrame) {
  Keyframer k(options());
  k.accept(sample(1, 10, 1.0));
  // 0.4 m ahead in the keyframe's own heading: no keyframe although the x coordinate changed little.
  const toro::Pose3 ahead =
      toro::Pose3::fromRollPitchYaw(10, 0, 0, 0, 0, 1.0) * toro::Pose3::fromRollPitchYaw(0.4, 0, 0, 0, 0, 0);
  EXPECT_FALSE(k.isKeyframe(OdometrySample{ros::Time(2), ahead, toro::Matrix6::Zero()}));
}

TEST(Keyframer, StepIsTheRelativeOdometry) {
  Keyframer k(options());
  k.accept(sample(1, 1, 0.5));
  const auto step = k.accept(sample(2, 3, 0.7));
  ASSERT_TRUE(step.has_value());
  const toro::Pose3 expected =
      toro::relativePose(sample(1, 1, 0.5).odom_T_base, sample(2, 3, 0.7).odom_T_base);
  EXPECT_NEAR((step->previous_T_current.translation() - expected.translation()).norm(), 0, 1e-12);
  EXPECT_NEAR(step->previous_T_current.rollPitchYaw().z(), 0.2, 1e-12);
  EXPECT_TRUE(step->information.used_default);  // zero covariances
}

TEST(Keyframer, DifferenceModeUsesTheGrowthOfTheCovariance) {
  KeyframerOptions o = options();
  o.covariance_mode = OdometryCovarianceMode::kDifference;
  Keyframer k(o);
  OdometrySample a = sample(1, 0, 0), b = sample(2, 1, 0);
  a.covariance = 0.01 * toro::Matrix6::Identity();
  b.covariance = 0.05 * toro::Matrix6::Identity();
  k.accept(a);
  const auto step = k.accept(b);
  ASSERT_FALSE(step->information.used_default);
  EXPECT_NEAR(step->information.information(0, 0), 1 / 0.04, 1e-9);
  EXPECT_NEAR(step->information.information(3, 3), 4 / 0.04, 1e-9);
}

TEST(Keyframer, DifferenceModeRotatesIntoTheBodyFrame) {
  KeyframerOptions o = options();
  Keyframer k(o);
  OdometrySample a = sample(1, 0, 0), b = sample(2, 0, M_PI / 2);  // robot faces odom +y
  b.covariance.diagonal() << 0.01, 0.04, 0.01, 0.01, 0.01, 0.01;   // odom y is the body x
  b.covariance.diagonal() += 1e-6 * toro::Vector6::Ones();
  a.covariance = 1e-6 * toro::Matrix6::Identity();
  k.accept(a);
  const auto step = k.accept(b);
  EXPECT_NEAR(step->information.information(0, 0), 1 / 0.04, 1e-6);
  EXPECT_NEAR(step->information.information(1, 1), 1 / 0.01, 1e-6);
}

TEST(Keyframer, OptionsValidate) {
  KeyframerOptions o;
  EXPECT_EQ(o.validate(), "");
  o.distance_m = 0;
  EXPECT_NE(o.validate(), "");
  EXPECT_EQ(odometryCovarianceModeFromString("latest"), OdometryCovarianceMode::kLatest);
  EXPECT_FALSE(odometryCovarianceModeFromString("bogus").has_value());
}
