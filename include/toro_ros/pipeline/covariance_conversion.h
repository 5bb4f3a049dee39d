// The inverse of informationFromCovariance (msg_conversion.h): the core's information matrix back
// to a covariance in geometry_msgs order and units, for writers of messages (the bag converter).
// Kept beside msg_conversion so the two directions share one definition of the unit change.
#pragma once

#include "toro_ros/core/pose3.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

// information: g2o order, rotation block in quaternion-vector units (the core's convention).
// Returns the covariance with translation in m^2 and rotation in rad^2 (rotation vector):
// Sigma = (J^T Omega_q J)^-1 with J = diag(1,1,1,1/2,1/2,1/2), i.e. the information's rotation
// block /4 and its cross blocks /2 before inverting.  Throws std::invalid_argument if the
// information is not symmetric positive definite.
toro::Matrix6 covarianceFromInformation(const toro::Matrix6& information);
Covariance6 covarianceToMsg(const toro::Matrix6& covariance);

}  // namespace toro_ros
