#include "toro_ros/core/carried_measurement.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "toro_ros/core/pose_graph.h"

namespace toro {

Matrix6 measuredCovariance(const Matrix6& information, double unmeasured_variance) {
  const Eigen::SelfAdjointEigenSolver<Matrix6> eigen(0.5 * (information + information.transpose()));
  const auto& values = eigen.eigenvalues();
  const double largest = values.maxCoeff();
  Vector6 inverse = Vector6::Zero();
  if (largest > 0.0)
    for (int i = 0; i < 6; ++i)
      if (values(i) > kUnmeasuredInformationRatio * largest && values(i) * unmeasured_variance > 1.0)
        inverse(i) = 1.0 / values(i);
  return eigen.eigenvectors() * inverse.asDiagonal() * eigen.eigenvectors().transpose();
}

Matrix6 carriedInformation(const Matrix6& a_covariance, const Pose3& z, const Matrix6& z_information,
                           const Pose3& b, const Matrix6& b_covariance) {
  // Information transforms with the inverse adjoint: Sigma' = Ad Sigma Ad^T, Lambda' = Ad^-T Lambda Ad^-1.
  const Matrix6 ad_b_inverse = adjoint(b.inverse());
  const Matrix6 carried = ad_b_inverse.transpose() * z_information * ad_b_inverse;
  const Matrix6 ad_a = adjoint(b * z.inverse());
  const Matrix6 ad_b = adjoint(b);
  const Matrix6 offsets = ad_a * a_covariance * ad_a.transpose() + ad_b * b_covariance * ad_b.transpose();
  const Matrix6 out = carried * (Matrix6::Identity() + offsets * carried).inverse();
  return 0.5 * (out + out.transpose());
}

}  // namespace toro
