// covarianceFromInformation is the exact inverse of informationFromCovariance (both directions of
// the q-vector / rotation-vector unit change).
#include <gtest/gtest.h>

#include <random>

#include "toro_ros/pipeline/covariance_conversion.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {
namespace {

toro::Matrix6 randomSpd(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  toro::Matrix6 a;
  for (int i = 0; i < 36; ++i) a(i / 6, i % 6) = n(rng);
  return a * a.transpose() + 0.5 * toro::Matrix6::Identity();
}

TEST(CovarianceConversion, InvertsInformationFromCovariance) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    const toro::Matrix6 information = randomSpd(rng);
    const toro::Matrix6 covariance = covarianceFromInformation(information);
    const InformationResult back = informationFromCovariance(covariance, DefaultStddev{});
    ASSERT_FALSE(back.used_default) << back.reason;
    EXPECT_LT((back.information - information).norm(), 1e-9 * information.norm()) << "trial " << trial;
  }
}

TEST(CovarianceConversion, DiagonalUnits) {
  // 1/sigma^2 per rad^2 on the angle is 4/sigma^2 on the q-vector: the covariance is sigma^2 again.
  toro::Matrix6 information = toro::Matrix6::Zero();
  information.diagonal() << 100, 100, 100, 4 * 400, 4 * 400, 4 * 400;
  const toro::Matrix6 covariance = covarianceFromInformation(information);
  EXPECT_NEAR(covariance(0, 0), 0.01, 1e-15);
  EXPECT_NEAR(covariance(5, 5), 1.0 / 400, 1e-15);
  EXPECT_NEAR(covariance(0, 5), 0.0, 1e-15);
  const Covariance6 msg = covarianceToMsg(covariance);
  EXPECT_DOUBLE_EQ(msg[35], covariance(5, 5));
  EXPECT_DOUBLE_EQ(msg[1 * 6 + 1], covariance(1, 1));
}

TEST(CovarianceConversion, RefusesNonPositiveDefinite) {
  toro::Matrix6 information = toro::Matrix6::Identity();
  information(3, 3) = -1.0;
  EXPECT_THROW(covarianceFromInformation(information), std::invalid_argument);
  information(3, 3) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(covarianceFromInformation(information), std::invalid_argument);
}

}  // namespace
}  // namespace toro_ros
