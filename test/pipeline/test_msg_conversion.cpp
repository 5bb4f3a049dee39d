#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/msg_conversion.h"

using namespace toro_ros;

namespace {

Covariance6 diagonal(double t2, double r2) {
  Covariance6 c{};
  for (int k = 0; k < 3; ++k) {
    c[7 * k] = t2;
    c[7 * (k + 3)] = r2;
  }
  return c;
}

}  // namespace

TEST(MsgConversion, PoseRoundTrip) {
  const toro::Pose3 p = toro::Pose3::fromRollPitchYaw(1, -2, 3, 0.1, -0.2, 2.5);
  const toro::Pose3 q = poseFromMsg(poseToMsg(p));
  EXPECT_NEAR((q.translation() - p.translation()).norm(), 0, 1e-12);
  EXPECT_NEAR(toro::relativePose(p, q).angle(), 0, 1e-12);
}

TEST(MsgConversion, UnnormalisedQuaternionIsNormalised) {
  geometry_msgs::Pose m;
  m.orientation.w = 2.0;
  EXPECT_NEAR(poseFromMsg(m).rotation().norm(), 1.0, 1e-15);
}

TEST(MsgConversion, DiagonalCovarianceGivesCoreUnits) {
  const DefaultStddev defaults;
  const InformationResult r = informationFromCovariance(diagonal(0.04, 0.01), defaults);
  ASSERT_FALSE(r.used_default) << r.reason;
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(r.information(k, k), 1 / 0.04, 1e-9);
    // 1/0.01 per rad^2 is 4/0.01 per unit^2 of the quaternion vector.
    EXPECT_NEAR(r.information(k + 3, k + 3), 4 / 0.01, 1e-9);
  }
}

TEST(MsgConversion, FullCovarianceScalesBlocksByTwoAndFour) {
  // A random SPD covariance: information in core units must be D Sigma^-1 D with D = diag(1,1,1,2,2,2).
  toro::Matrix6 a;
  a << 1, 2, 0, 1, 0, 3, 0, 1, 1, 0, 2, 1, 2, 0, 3, 1, 1, 0, 1, 1, 0, 2, 0, 1, 0, 3, 1, 1, 2, 0, 1, 0, 2, 0,
      1, 2;
  const toro::Matrix6 cov = 0.01 * (a * a.transpose() + toro::Matrix6::Identity());
  const InformationResult r = informationFromCovariance(cov, DefaultStddev{});
  ASSERT_FALSE(r.used_default) << r.reason;
  toro::Vector6 d;
  d << 1, 1, 1, 2, 2, 2;
  const toro::Matrix6 expected = d.asDiagonal() * cov.inverse() * d.asDiagonal();
  EXPECT_LT((r.information - expected).cwiseAbs().maxCoeff(), 1e-9 * expected.cwiseAbs().maxCoeff());
}

TEST(MsgConversion, ConvertedInformationGivesMahalanobisChi2InTheCore) {
  // A rotation error of delta rad about x with sigma rad must cost (delta/sigma)^2 in g2o chi2.
  const double sigma = 0.05, delta = 0.01;
  toro::PoseGraph g;
  g.addNode(0, toro::Pose3());
  g.addNode(1, toro::Pose3::fromRollPitchYaw(0, 0, 0, delta, 0, 0));
  g.addConstraint(
      {0, 1, toro::Pose3(), informationFromCovariance(diagonal(1.0, sigma * sigma), {}).information});
  EXPECT_NEAR(toro::g2oChi2(g), (delta / sigma) * (delta / sigma), 1e-3);
}

TEST(MsgConversion, UnusableCovariancesFallBackToDefaults) {
  const DefaultStddev defaults{0.1, 0.2};
  const toro::Matrix6 expected = defaultInformation(defaults);
  EXPECT_NEAR(expected(0, 0), 100.0, 1e-9);
  EXPECT_NEAR(expected(5, 5), 4.0 / 0.04, 1e-9);

  const InformationResult zero = informationFromCovariance(Covariance6{}, defaults);
  EXPECT_TRUE(zero.used_default);
  EXPECT_EQ(zero.reason, "covariance is zero");
  EXPECT_EQ(zero.information, expected);

  Covariance6 nan = diagonal(0.01, 0.01);
  nan[8] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(informationFromCovariance(nan, defaults).reason, "covariance is not finite");

  Covariance6 singular = diagonal(0.01, 0.01);
  singular[35] = 0.0;  // yaw variance missing (a planar sensor that leaves it at zero)
  const InformationResult s = informationFromCovariance(singular, defaults);
  EXPECT_TRUE(s.used_default);
  EXPECT_EQ(s.reason, "covariance is not positive definite");

  Covariance6 asym = diagonal(0.01, 0.01);
  asym[1] = 0.001;
  EXPECT_EQ(informationFromCovariance(asym, defaults).reason, "covariance is not symmetric");
}

TEST(MsgConversion, ValidationNamesTheProblem) {
  nav_msgs::Odometry odom;
  odom.pose.pose.orientation.w = 1;
  EXPECT_EQ(validateOdometry(odom), "stamp is zero");
  odom.header.stamp = ros::Time(5);
  EXPECT_EQ(validateOdometry(odom), "");
  odom.pose.pose.orientation.w = 0;
  EXPECT_NE(validateOdometry(odom).find("orientation"), std::string::npos);
  odom.pose.pose.orientation.w = 1;
  odom.pose.pose.position.y = std::numeric_limits<double>::infinity();
  EXPECT_NE(validateOdometry(odom).find("position"), std::string::npos);

  LoopClosure lc;
  lc.from_T_to.orientation.w = 1;
  lc.id_from = lc.id_to = -1;
  EXPECT_NE(validateLoopClosure(lc).find("names no pose"), std::string::npos);
  lc.id_from = lc.id_to = 3;
  EXPECT_EQ(validateLoopClosure(lc), "id_from equals id_to");
  lc.id_to = 4;
  EXPECT_EQ(validateLoopClosure(lc), "");
}
