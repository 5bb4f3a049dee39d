#include "toro_ros/pipeline/covariance_conversion.h"

#include <stdexcept>

#include <Eigen/Cholesky>

#include "toro_ros/core/pose_graph.h"

namespace toro_ros {

toro::Matrix6 covarianceFromInformation(const toro::Matrix6& information) {
  const toro::Matrix6 per_angle = toro::quaternionToAngleUnits(information);
  const Eigen::LLT<toro::Matrix6> llt(0.5 * (per_angle + per_angle.transpose()));
  if (!information.allFinite() || llt.info() != Eigen::Success)
    throw std::invalid_argument("information matrix is not symmetric positive definite");
  toro::Matrix6 covariance = llt.solve(toro::Matrix6::Identity());
  return 0.5 * (covariance + covariance.transpose());
}

Covariance6 covarianceToMsg(const toro::Matrix6& covariance) {
  Covariance6 out;
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) out[6 * r + c] = covariance(r, c);
  return out;
}

}  // namespace toro_ros
