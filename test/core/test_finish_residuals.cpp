// Analytic Jacobians of the finish against numerical differentiation, and the retraction
// against the matrix exponential.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <unsupported/Eigen/MatrixFunctions>

#include "toro_ros/core/finish_residuals.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/random_draws.h"

using namespace toro;

namespace {

Pose3 randomPose(std::mt19937& rng, double rotation_scale, double translation_scale = 2.0) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Vector3 t = drawVector3(n, rng);
  return Pose3::fromAngleAxis(rotation_scale * drawVector3(n, rng), translation_scale * t);
}

// Central differences of the residual along each coordinate of delta_i (which = 0) or delta_j.
Matrix6 numericJacobianSE3(const Pose3& xi, const Pose3& xj, const Pose3& z, int which) {
  const double h = 1e-6;
  Matrix6 j;
  for (int k = 0; k < 6; ++k) {
    Vector6 d = Vector6::Zero();
    d[k] = h;
    const Vector6 plus = which == 0 ? errorSE3(retractSE3(xi, d), xj, z) : errorSE3(xi, retractSE3(xj, d), z);
    const Vector6 minus =
        which == 0 ? errorSE3(retractSE3(xi, -d), xj, z) : errorSE3(xi, retractSE3(xj, -d), z);
    j.col(k) = (plus - minus) / (2 * h);
  }
  return j;
}

void expectJacobiansMatch(const Pose3& xi, const Pose3& xj, const Pose3& z) {
  Linearization3D lin;
  linearizeSE3(xi, xj, z, &lin);
  EXPECT_LT((lin.error - errorSE3(xi, xj, z)).norm(), 1e-14);
  EXPECT_LT((lin.d_from - numericJacobianSE3(xi, xj, z, 0)).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_LT((lin.d_to - numericJacobianSE3(xi, xj, z, 1)).cwiseAbs().maxCoeff(), 1e-7);
}

// Skips residual rotations near 180 degrees, where the w >= 0 choice flips the error's sign.
bool nearHalfTurn(const Pose3& xi, const Pose3& xj, const Pose3& z) {
  return std::abs((z.inverse() * xi.inverse() * xj).rotation().w()) < 1e-2;
}

}  // namespace

TEST(FinishResiduals, SE3JacobiansMatchNumericForLargeRotations) {
  std::mt19937 rng(21);
  int checked = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const Pose3 xi = randomPose(rng, 1.5), xj = randomPose(rng, 1.5), z = randomPose(rng, 1.5);
    if (nearHalfTurn(xi, xj, z)) continue;
    expectJacobiansMatch(xi, xj, z);
    ++checked;
  }
  EXPECT_GT(checked, 150);
}

TEST(FinishResiduals, SE3JacobiansMatchNumericNearTheSolution) {
  // Near-identity residuals (the finish's regime) and exactly met constraints.
  std::mt19937 rng(22);
  for (int trial = 0; trial < 100; ++trial) {
    const Pose3 xi = randomPose(rng, 2.0), z = randomPose(rng, 2.0);
    const double noise = trial % 2 == 0 ? 0.0 : 1e-4;
    const Pose3 xj = xi * z * randomPose(rng, noise, noise);
    expectJacobiansMatch(xi, xj, z);
  }
}

TEST(FinishResiduals, SE3ErrorIsTheG2oError) {
  std::mt19937 rng(23);
  PoseGraph g;
  g.addNode(0, randomPose(rng, 2.0));
  g.addNode(1, randomPose(rng, 2.0));
  Matrix6 info = Matrix6::Identity();
  info(1, 4) = info(4, 1) = 0.3;
  const Pose3 z = randomPose(rng, 2.0);
  g.addConstraint(Constraint{0, 1, z, info});
  const Vector6 e = errorSE3(g.pose(0), g.pose(1), z);
  EXPECT_NEAR(e.dot(info * e), g2oChi2(g), 1e-12 * g2oChi2(g));
}

TEST(FinishResiduals, RetractionIsTheSE3Exponential) {
  std::mt19937 rng(24);
  std::normal_distribution<double> n(0.0, 1.0);
  for (double scale : {1e-9, 1e-5, 0.1, 1.0, 2.5}) {
    Vector6 d;
    for (int k = 0; k < 6; ++k) d[k] = scale * n(rng);
    Eigen::Matrix4d twist = Eigen::Matrix4d::Zero();
    twist.topLeftCorner<3, 3>() << 0, -d[5], d[4], d[5], 0, -d[3], -d[4], d[3], 0;
    twist.topRightCorner<3, 1>() = d.head<3>();
    const Eigen::Matrix4d expected = twist.exp();
    const Pose3 x = randomPose(rng, 1.0);
    const Pose3 got = x.inverse() * retractSE3(x, d);  // = Exp(d)
    EXPECT_LT((got.rotationMatrix() - expected.topLeftCorner<3, 3>()).norm(), 1e-12);
    EXPECT_LT((got.translation() - expected.topRightCorner<3, 1>()).norm(), 1e-12);
  }
}

TEST(FinishResiduals, SE2JacobiansMatchNumericAndWrap) {
  std::mt19937 rng(25);
  std::normal_distribution<double> n(0.0, 1.0);
  const double h = 1e-6;
  for (int trial = 0; trial < 100; ++trial) {
    const Vector3 scale(2, 2, 3);
    const Vector3 xi = scale.cwiseProduct(drawVector3(n, rng)), xj = scale.cwiseProduct(drawVector3(n, rng));
    const Vector3 z = Vector3(1, 1, 3).cwiseProduct(drawVector3(n, rng));
    Linearization2D lin;
    linearizeSE2(xi, xj, z, &lin);
    EXPECT_LE(std::abs(lin.error.z()), M_PI);
    if (std::abs(std::abs(lin.error.z()) - M_PI) < 1e-3) continue;  // the wrap is discontinuous there
    for (int k = 0; k < 3; ++k) {
      const Vector3 d = h * Vector3::Unit(k);
      const Vector3 num_i = (errorSE2(xi + d, xj, z) - errorSE2(xi - d, xj, z)) / (2 * h);
      const Vector3 num_j = (errorSE2(xi, xj + d, z) - errorSE2(xi, xj - d, z)) / (2 * h);
      EXPECT_LT((lin.d_from.col(k) - num_i).cwiseAbs().maxCoeff(), 1e-7);
      EXPECT_LT((lin.d_to.col(k) - num_j).cwiseAbs().maxCoeff(), 1e-7);
    }
  }
}

TEST(FinishResiduals, WrapAngleRange) {
  EXPECT_NEAR(wrapAngle(3 * M_PI / 2), -M_PI / 2, 1e-15);
  EXPECT_NEAR(wrapAngle(-6.1), 2 * M_PI - 6.1, 1e-15);
  EXPECT_NEAR(wrapAngle(0.3), 0.3, 1e-15);
  EXPECT_DOUBLE_EQ(wrapAngle(-M_PI), M_PI);  // the range is (-pi, pi]
}
