#include <cmath>
#include <limits>
#include <random>

#include <Eigen/Eigenvalues>

#include <gtest/gtest.h>

#include "toro_ros/core/metrics.h"
#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/random_draws.h"
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

TEST(MsgConversion, UnusableVariancesTakeTheDefaultsOnTheirAxesOnly) {
  const DefaultStddev defaults{0.1, 0.2};
  const toro::Matrix6 expected = defaultInformation(defaults);
  EXPECT_NEAR(expected(0, 0), 100.0, 1e-9);
  EXPECT_NEAR(expected(5, 5), 4.0 / 0.04, 1e-9);

  const InformationResult zero = informationFromCovariance(Covariance6{}, defaults);
  EXPECT_TRUE(zero.used_default);
  EXPECT_EQ(zero.default_axes, 6);
  EXPECT_NE(zero.reason.find("no usable variance"), std::string::npos) << zero.reason;
  EXPECT_EQ(zero.information, expected);

  Covariance6 missing_yaw = diagonal(0.01, 0.01);
  missing_yaw[35] = 0.0;  // a planar sensor that leaves it at zero
  const InformationResult s = informationFromCovariance(missing_yaw, defaults);
  EXPECT_FALSE(s.used_default);
  EXPECT_EQ(s.default_axes, 1);
  EXPECT_EQ(s.reason, "yaw unknown (zero, negative or not finite): defaults");
  EXPECT_NEAR(s.information(5, 5), expected(5, 5), 1e-9);  // only yaw takes the default
  EXPECT_NEAR(s.information(0, 0), 100.0, 1e-9);
  EXPECT_NEAR(s.information(3, 3), 4 / 0.01, 1e-9);

  Covariance6 nan_variance = diagonal(0.01, 0.01);
  nan_variance[14] = std::numeric_limits<double>::quiet_NaN();  // z
  const InformationResult n = informationFromCovariance(nan_variance, defaults);
  EXPECT_EQ(n.axes[2], AxisReading::kUnknown);
  EXPECT_NEAR(n.information(2, 2), 100.0, 1e-9);

  Covariance6 nan_correlation = diagonal(0.01, 0.01);
  nan_correlation[8] = std::numeric_limits<double>::quiet_NaN();  // (1, 2): dropped
  const InformationResult c = informationFromCovariance(nan_correlation, defaults);
  EXPECT_EQ(c.default_axes, 0);
  EXPECT_TRUE(c.repaired);
  EXPECT_NEAR(c.information(1, 2), 0.0, 1e-12);

  Covariance6 asym = diagonal(0.01, 0.01);
  asym[1] = 0.002;  // (0,1) without (1,0): averaged to 0.001
  const InformationResult a = informationFromCovariance(asym, defaults);
  EXPECT_TRUE(a.repaired);
  EXPECT_NE(a.reason.find("asymmetric"), std::string::npos);
  Eigen::Matrix2d block;
  block << 0.01, 0.001, 0.001, 0.01;
  EXPECT_NEAR(a.information(0, 1), block.inverse()(0, 1), 1e-9);
}

TEST(MsgConversion, HugeVariancesAreUnmeasuredAxesWithAlmostNoInformation) {
  // diff_drive_controller style: 1e6 on z, roll and pitch.
  Covariance6 planar = diagonal(0.01, 0.01);
  for (int axis : {2, 3, 4}) planar[7 * axis] = 1e6;
  const InformationResult r = informationFromCovariance(planar, DefaultStddev{});
  EXPECT_FALSE(r.used_default);
  EXPECT_EQ(r.default_axes, 0);
  EXPECT_EQ(axisNames(r.axes, AxisReading::kUnmeasured), "z roll pitch");
  EXPECT_EQ(axisNames(r.axes, AxisReading::kMeasured), "x y yaw");
  EXPECT_NEAR(r.information(2, 2), 1e-6, 1e-15);
  EXPECT_NEAR(r.information(3, 3), 4e-6, 1e-15);  // quaternion units
  EXPECT_NEAR(r.information(5, 5), 400.0, 1e-9);
  EXPECT_EQ(toro::checkInformation(r.information), "");  // the core accepts it
  // At the threshold exactly: unmeasured; just below: measured.
  Covariance6 edge = diagonal(0.01, 0.01);
  edge[14] = 1e3;
  EXPECT_EQ(informationFromCovariance(edge, DefaultStddev{}, 1e3).axes[2], AxisReading::kUnmeasured);
  edge[14] = 999.0;
  EXPECT_EQ(informationFromCovariance(edge, DefaultStddev{}, 1e3).axes[2], AxisReading::kMeasured);
  // Infinite: unmeasured, with a small positive information so the matrix stays definite.
  edge[14] = std::numeric_limits<double>::infinity();
  const InformationResult inf = informationFromCovariance(edge, DefaultStddev{});
  EXPECT_EQ(inf.axes[2], AxisReading::kUnmeasured);
  EXPECT_GT(inf.information(2, 2), 0.0);
  EXPECT_LE(inf.information(2, 2), 1e-6);
}

TEST(MsgConversion, IndefiniteCorrelationsAreShrunkKeepingTheVariances) {
  // x and y with a correlation of 1.5 (impossible): the variances are kept, the correlation cut
  // to 0.9 (the correlation matrix's eigenvalues 2.5 and -0.5 become 1.9 and 0.1).
  toro::Matrix6 cov = toro::Matrix6::Zero();
  cov.diagonal() << 0.04, 0.01, 0.02, 0.001, 0.001, 0.003;
  cov(0, 1) = cov(1, 0) = 1.5 * std::sqrt(0.04 * 0.01);
  const InformationResult r = informationFromCovariance(cov, DefaultStddev{});
  EXPECT_TRUE(r.repaired);
  EXPECT_EQ(r.default_axes, 0);
  EXPECT_EQ(toro::checkInformation(r.information), "");
  const toro::Matrix6 back = toro::quaternionToAngleUnits(r.information).inverse();
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(back(i, i), cov(i, i), 1e-9 * cov(i, i)) << "axis " << i;
  const double correlation = back(0, 1) / std::sqrt(back(0, 0) * back(1, 1));
  EXPECT_NEAR(correlation, 0.9, 1e-9);
  // Uncorrelated axes stay uncorrelated.
  EXPECT_NEAR(back(2, 5), 0.0, 1e-12);
  // A real but nearly singular covariance (correlation 0.999999) is kept as it is.
  cov(0, 1) = cov(1, 0) = 0.999999 * std::sqrt(0.04 * 0.01);
  const InformationResult kept = informationFromCovariance(cov, DefaultStddev{});
  EXPECT_FALSE(kept.repaired);
  EXPECT_LT((toro::quaternionToAngleUnits(kept.information) - cov.inverse()).norm(),
            1e-6 * cov.inverse().norm());
}

TEST(MsgConversion, UnmeasuredAxesKeepTheirCorrelations) {
  // A huge marginal variance that comes from correlations (parking-garage's loop closures): the
  // information is the covariance's inverse as it is, not an axis-by-axis reading of it.
  toro::Matrix6 info = toro::Matrix6::Identity();
  info(3, 3) = info(4, 4) = 1.0;
  info(3, 4) = info(4, 3) = 0.99995;  // roll and pitch almost only known together
  const toro::Matrix6 cov = info.inverse();
  ASSERT_GT(cov(3, 3), 1e3);
  const InformationResult r = informationFromCovariance(cov, DefaultStddev{});
  EXPECT_EQ(r.axes[3], AxisReading::kUnmeasured);
  EXPECT_FALSE(r.repaired);
  EXPECT_LT((toro::quaternionToAngleUnits(r.information) - info).norm(), 1e-6);
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

TEST(MsgConversion, DenormalVariancesWithHugeCorrelationsAreRepaired) {
  // Found by fuzz_loop_closure: pitch and yaw variances near the underflow limit and a cross term
  // of -9e207 made the correlation overflow to -inf and the information NaN.
  toro::Matrix6 cov = toro::Matrix6::Zero();
  cov(0, 0) = cov(1, 1) = 4e-4;
  cov(3, 4) = 4.08e15;
  cov(4, 4) = 2.53e-320;
  cov(5, 0) = 4.08e15;
  cov(5, 4) = -9.07e207;
  cov(5, 5) = 5.24e-315;
  const InformationResult r = informationFromCovariance(cov, DefaultStddev{});
  ASSERT_TRUE(r.information.allFinite());
  EXPECT_EQ(toro::checkInformation(r.information), "");
  EXPECT_TRUE(r.repaired);
  EXPECT_NE(r.reason.find("correlations"), std::string::npos) << r.reason;
  // z and roll (zero variances) take the defaults; x, y keep theirs.
  EXPECT_EQ(r.default_axes, 2);
  EXPECT_NEAR(toro::quaternionToAngleUnits(r.information).inverse()(0, 0), 4e-4, 1e-9);
}

TEST(MsgConversion, AnyCovarianceGivesAPositiveDefiniteInformation) {
  // Random covariances with variances from 1e-12 to 1e12, random correlations (valid or not) and
  // NaN, infinite, zero and negative entries sprinkled in: the information is always finite,
  // symmetric and positive definite, by the core's test and by its eigenvalues.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> exponent(-12.0, 12.0), u(-1.0, 1.0), pick(0.0, 1.0);
  const double specials[] = {std::numeric_limits<double>::quiet_NaN(),
                             std::numeric_limits<double>::infinity(),
                             -std::numeric_limits<double>::infinity(),
                             0.0,
                             -1.0,
                             5e-320,  // denormal
                             -9e207};
  constexpr int kSpecials = sizeof(specials) / sizeof(specials[0]);
  for (int trial = 0; trial < 2000; ++trial) {
    toro::Matrix6 cov = toro::Matrix6::Zero();
    for (int i = 0; i < 6; ++i) cov(i, i) = std::pow(10.0, exponent(rng));
    for (int i = 0; i < 6; ++i)
      for (int j = i + 1; j < 6; ++j) cov(i, j) = cov(j, i) = 1.2 * u(rng) * std::sqrt(cov(i, i) * cov(j, j));
    for (int k = 0; k < 3; ++k)
      if (pick(rng) < 0.2) {
        const auto at = toro::drawLastFirst<2>(pick, rng);
        cov(static_cast<int>(6 * at[0]) % 6, static_cast<int>(6 * at[1]) % 6) = specials[trial % kSpecials];
      }
    const InformationResult r = informationFromCovariance(cov, DefaultStddev{});
    ASSERT_TRUE(r.information.allFinite()) << "trial " << trial;
    ASSERT_EQ(r.information, r.information.transpose()) << "trial " << trial;
    ASSERT_EQ(toro::checkInformation(r.information), "") << "trial " << trial;
    const Eigen::SelfAdjointEigenSolver<toro::Matrix6> eigen(r.information, Eigen::EigenvaluesOnly);
    ASSERT_GT(eigen.eigenvalues().minCoeff(), 0.0) << "trial " << trial << "\n" << cov;
    ASSERT_EQ(r.used_default, r.default_axes == 6);
  }
}
