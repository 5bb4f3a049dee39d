// How well each loop closure agrees with the odometry alone: its innovation chi2
//   e^T (Sigma_z + Sigma_odo)^-1 e,
// e the loop closure's residual at the dead-reckoned poses, Sigma_z its covariance and Sigma_odo the
// first-order covariance of the relative pose of its two ends along the odometry (every odometry
// step's covariance carried into the frame of the later end and summed).  A right loop closure
// that closes a long loop has a large plain chi2 (the drift) but a small innovation; a wrong one
// is usually far outside the odometry's uncertainty.  Only as good as the declared odometry
// covariances, and lenient where the odometry between the two ends is long and uncertain.
#pragma once

#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

// Per constraint index: the innovation chi2 of each loop closure (isLoopClosure) whose two ends the
// odometry connects, in the units of the g2o chi2 (angle units internally); -1 for odometry and
// for loop closures between poses the odometry does not connect.  `graph`'s poses must be the
// odometry's (TreeOptimizer's InitialGuess::kChainOdometry); 2D graphs use x, y and yaw only.
std::vector<double> odometryInnovationChi2(const PoseGraph& graph);

// e^T Sigma^-1 e for a pose error (translation, rotation vector; angle units), on x, y and yaw
// only when `planar`.
double poseErrorChi2(const Pose3& error, const Matrix6& covariance, bool planar);

}  // namespace toro
