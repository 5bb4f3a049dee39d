#include <gtest/gtest.h>

#include <limits>

#include "toro_ros/core/pose_graph.h"
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
  o.covariance_mode = OdometryCovarianceMode::kDifference;
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

namespace {

// Feeds samples to observe() and returns the step of the last one from the first.
std::optional<OdometryStep> stepAfter(Keyframer& k, const std::vector<OdometrySample>& samples) {
  std::optional<OdometryStep> step;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    k.observe(samples[i]);
    if (i == 0 || i + 1 == samples.size()) step = k.accept(samples[i]);
  }
  return step;
}

toro::Matrix6 diagonalCovariance(double xy, double z_roll_pitch, double yaw) {
  toro::Matrix6 c = toro::Matrix6::Zero();
  c.diagonal() << xy, xy, z_roll_pitch, z_roll_pitch, z_roll_pitch, yaw;
  return c;
}

}  // namespace

TEST(Keyframer, AutoReadsAConstantCovariancePerMetreAndRadianOfMotion) {
  // diff_drive_controller: the same pose_covariance_diagonal in every message, 1e6 on z/roll/pitch.
  Keyframer k(options());
  std::vector<OdometrySample> s;
  for (int i = 0; i <= 6; ++i) {
    s.push_back(sample(1 + 0.1 * i, 0.1 * i, 0.05 * i));  // 0.6 m and 0.3 rad in all
    s.back().covariance = diagonalCovariance(1e-3, 1e6, 4e-4);
  }
  const auto step = stepAfter(k, s);
  ASSERT_TRUE(step.has_value());
  EXPECT_EQ(k.convention(), OdometryCovarianceConvention::kConstant);
  EXPECT_EQ(k.effectiveMode(), OdometryCovarianceMode::kMotionScaled);
  const double motion = step->previous_T_current.translation().norm() + step->previous_T_current.angle();
  EXPECT_NEAR(motion, 0.6 + 0.3, 1e-3);
  const InformationResult& info = step->information;
  EXPECT_FALSE(info.used_default);
  EXPECT_EQ(info.default_axes, 0);
  EXPECT_EQ(axisNames(info.axes, AxisReading::kUnmeasured), "z roll pitch");
  // In the body frame x/y are isotropic, so the rotation does not change them; yaw is about z.
  EXPECT_NEAR(info.information(0, 0), 1 / (1e-3 * motion), 1e-6);
  EXPECT_NEAR(info.information(5, 5), 4 / (4e-4 * motion), 1e-6);
  EXPECT_NEAR(info.information(2, 2), 1e-6, 1e-12);  // ~0, as the sender said, not the default
  EXPECT_NE(k.ruleDescription().find("same in every message"), std::string::npos) << k.ruleDescription();
  EXPECT_NE(k.ruleDescription().find("unmeasured"), std::string::npos);
}

TEST(Keyframer, AConstantCovarianceStandingStillCountsAsTheMinimumMotion) {
  Keyframer k(options());
  std::vector<OdometrySample> s = {sample(1, 0, 0), sample(7, 0, 0)};  // an interval keyframe
  for (auto& x : s) x.covariance = diagonalCovariance(1e-3, 1e6, 4e-4);
  const auto step = stepAfter(k, s);
  EXPECT_NEAR(step->information.information(0, 0), 1 / (1e-3 * kMinMotionScale), 1e-6);
}

TEST(Keyframer, AutoReadsAGrowingCovarianceAsItsGrowthOverTheStepOnTheAxesThatGrew) {
  // robot_localization in two_d_mode: x, y and yaw propagated as an EKF does (the heading
  // uncertainty grows into the position across the motion), z/roll/pitch held at 1e-6.  Each
  // message adds `added` (x, y, yaw) to the carried covariance; the keyframe step must read the
  // sum of what was added, not the plain difference (which also holds the carried heading error).
  Keyframer k(options());
  toro::Matrix6 added = toro::Matrix6::Zero();
  added.diagonal() << 1e-4, 4e-5, 0, 0, 0, 2e-5;
  toro::Matrix6 p = toro::Matrix6::Zero();
  p.diagonal() << 0.01, 0.01, 1e-6, 1e-6, 1e-6, 0.02;  // the state before the step: uncertain
  std::vector<OdometrySample> s;
  for (int i = 0; i <= 6; ++i) {
    s.push_back(sample(1 + 0.1 * i, 0.1 * i, 0.0));
    if (i > 0) {
      p = carriedCovariance(p, toro::Vector3(0.1, 0, 0)) + added;
      p(2, 2) = p(3, 3) = p(4, 4) = 1e-6;  // two_d_mode holds them
    }
    s.back().covariance = p;
  }
  const auto step = stepAfter(k, s);
  EXPECT_EQ(k.convention(), OdometryCovarianceConvention::kGrowing);
  const InformationResult& info = step->information;
  EXPECT_EQ(axisNames(info.axes, AxisReading::kMeasured), "x y yaw");
  EXPECT_EQ(axisNames(info.axes, AxisReading::kUnknown), "z roll pitch");  // did not grow: defaults
  EXPECT_EQ(info.default_axes, 3);
  EXPECT_FALSE(info.used_default);
  // What the six messages added, carried to the keyframe: x 6e-4; yaw 1.2e-4; y 2.4e-4 plus the
  // added yaw variances carried over the rest of the step (sum over i of 2e-5 (0.1 (6 - i))^2).
  double y = 6 * 4e-5;
  for (int i = 1; i <= 6; ++i) y += 2e-5 * std::pow(0.1 * (6 - i), 2);
  const toro::Matrix6 covariance = toro::quaternionToAngleUnits(info.information).inverse();
  EXPECT_NEAR(covariance(0, 0), 6e-4, 1e-12);
  EXPECT_NEAR(covariance(5, 5), 1.2e-4, 1e-12);
  EXPECT_NEAR(covariance(1, 1), y, 1e-12);
  EXPECT_NEAR(info.information(2, 2), 1 / (0.05 * 0.05), 1e-6);  // the default translation stddev
  // The plain difference would have read 0.02 * 0.6^2 = 7.2e-3 of carried heading error into y.
  EXPECT_LT(covariance(1, 1), 1e-3);
  EXPECT_NE(k.ruleDescription().find("changes between messages"), std::string::npos) << k.ruleDescription();
}

TEST(Keyframer, AGrowingCovarianceBeyondTheUnmeasuredThresholdIsStillItsGrowth) {
  // Dead reckoning after a long drive: the accumulated variance passes 1e3, each step adds 0.01.
  KeyframerOptions o = options();
  o.covariance_mode = OdometryCovarianceMode::kDifference;
  Keyframer k(o);
  OdometrySample a = sample(1, 0, 0), b = sample(11, 0, 0);  // a keyframe by time, standing still
  a.covariance = 5e3 * toro::Matrix6::Identity();
  b.covariance = (5e3 + 0.01) * toro::Matrix6::Identity();
  k.accept(a);
  const auto step = k.accept(b);
  EXPECT_EQ(axisNames(step->information.axes, AxisReading::kMeasured), "x y z roll pitch yaw");
  EXPECT_NEAR(step->information.information(0, 0), 100.0, 1e-3);
  // An axis pinned at 1e6 that does not grow is unmeasured, with the sender's variance.
  a.covariance(2, 2) = b.covariance(2, 2) = 1e6;
  k.reset();
  k.accept(a);
  const auto pinned = k.accept(b);
  EXPECT_EQ(pinned->information.axes[2], AxisReading::kUnmeasured);
  EXPECT_NEAR(pinned->information.information(2, 2), 1e-6, 1e-12);
}

TEST(Keyframer, ALargeVarianceThatShrankIsUnknownNotUnmeasured) {
  // Dead reckoning far from the start: z's accumulated variance is past the threshold, and in this
  // step it shrank a little (an EKF's correlations, a partial fix).  The step's own z variance is
  // then unknown (the default), not unmeasured: one odometry step free along z would leave every
  // later pose free along it, and the map's exact finish undetermined for the rest of the run.
  KeyframerOptions o = options();
  o.covariance_mode = OdometryCovarianceMode::kDifference;
  Keyframer k(o);
  OdometrySample a = sample(1, 0, 0), b = sample(11, 0, 0);  // standing still: nothing carried
  a.covariance = 5e3 * toro::Matrix6::Identity();
  b.covariance = (5e3 + 0.01) * toro::Matrix6::Identity();
  b.covariance(2, 2) = 5e3 - 0.5;
  k.accept(a);
  const auto shrank = k.accept(b);
  EXPECT_EQ(axisNames(shrank->information.axes, AxisReading::kMeasured), "x y roll pitch yaw");
  EXPECT_EQ(axisNames(shrank->information.axes, AxisReading::kUnknown), "z");
  EXPECT_NEAR(shrank->information.information(2, 2), 1 / (0.05 * 0.05), 1e-6);  // the default
  // Past the threshold and left as it was: the sender pins it, unmeasured; so is a variance that is
  // infinite now.  A finite one after an infinite one changed: unknown.
  b.covariance(2, 2) = 5e3;
  k.reset();
  k.accept(a);
  EXPECT_EQ(k.accept(b)->information.axes[2], AxisReading::kUnmeasured);
  a.covariance(2, 2) = std::numeric_limits<double>::infinity();
  b.covariance(2, 2) = 2e3;
  k.reset();
  k.accept(a);
  EXPECT_EQ(k.accept(b)->information.axes[2], AxisReading::kUnknown);
  b.covariance(2, 2) = std::numeric_limits<double>::infinity();
  k.reset();
  k.accept(a);
  EXPECT_EQ(k.accept(b)->information.axes[2], AxisReading::kUnmeasured);
}

TEST(Keyframer, AnIndefiniteDifferenceIsRepairedNotThrownAway) {
  // An EKF's correlations change as well as its variances: the difference is indefinite.
  KeyframerOptions o = options();
  o.covariance_mode = OdometryCovarianceMode::kDifference;
  Keyframer k(o);
  OdometrySample a = sample(1, 0, 0), b = sample(11, 0, 0);  // standing still: nothing carried
  a.covariance = diagonalCovariance(0.01, 1e-6, 0.01);
  b.covariance = diagonalCovariance(0.02, 1e-6, 0.02);
  a.covariance(0, 5) = a.covariance(5, 0) = -0.008;
  b.covariance(0, 5) = b.covariance(5, 0) = 0.008;  // the difference's x-yaw correlation is 1.6
  k.accept(a);
  const auto step = k.accept(b);
  EXPECT_TRUE(step->information.repaired);
  EXPECT_EQ(axisNames(step->information.axes, AxisReading::kMeasured), "x y yaw");
  EXPECT_EQ(toro::checkInformation(step->information.information), "");
  // The variances of the growth are kept (0.01 on x and yaw).
  const toro::Matrix6 covariance = toro::quaternionToAngleUnits(step->information.information).inverse();
  EXPECT_NEAR(covariance(0, 0), 0.01, 1e-9);
  EXPECT_NEAR(covariance(5, 5), 0.01, 1e-9);
}

TEST(Keyframer, AutoSwitchesToGrowingWhenTheCovarianceChangesAndAllZeroIsDefaults) {
  Keyframer k(options());
  std::vector<OdometrySample> s = {sample(1, 0, 0), sample(1.1, 0.3, 0), sample(1.2, 0.6, 0)};
  const auto zero = stepAfter(k, s);
  EXPECT_EQ(k.convention(), OdometryCovarianceConvention::kConstant);
  EXPECT_TRUE(zero->information.used_default);  // all zero: every axis unknown
  OdometrySample c = sample(1.3, 1.2, 0);
  c.covariance = 0.1 * toro::Matrix6::Identity();
  k.observe(c);
  EXPECT_EQ(k.convention(), OdometryCovarianceConvention::kGrowing);
  const auto grown = k.accept(c);
  EXPECT_EQ(grown->information.default_axes, 0);
  EXPECT_NEAR(grown->information.information(0, 0), 10.0, 1e-9);
  // A load forgets the convention: the next step takes the defaults until messages tell.
  k.setLast(c);
  EXPECT_EQ(k.convention(), OdometryCovarianceConvention::kUndetermined);
  EXPECT_EQ(k.effectiveMode(), OdometryCovarianceMode::kDefault);
  EXPECT_EQ(odometryCovarianceModeFromString("auto"), OdometryCovarianceMode::kAuto);
  EXPECT_EQ(odometryCovarianceModeFromString("motion_scaled"), OdometryCovarianceMode::kMotionScaled);
  EXPECT_EQ(KeyframerOptions().covariance_mode, OdometryCovarianceMode::kAuto);
}
