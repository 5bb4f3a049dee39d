// Error measures of a pose graph at its current poses.  Definitions follow
// ../shared/datasets/REFERENCE.md exactly, so figures compare with published ones of the same kind.
#pragma once

#include <cstddef>
#include <vector>

#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/robust_kernel.h"

namespace toro {

// (B) g2o chi2: sum of e^T Omega e, e = [t(D); qvec(D) with w >= 0], D = Z^-1 X_i^-1 X_j (no 1/2).
// For 2D graphs (GraphDimension::k2D) the 2D definition is used:
// e = [Rz^T (R_i^T (t_j - t_i) - t_z); wrap(theta_j - theta_i - theta_z)] with the planar 3x3 information.
double g2oChi2(const PoseGraph& graph);

// (A) SE-Sync objective: sum kappa ||R_j - R_i R_z||_F^2 + tau ||t_j - t_i - R_i t_z||^2 with
// 3D: tau = 3 / tr(Omega_t^-1), kappa = 3 / (2 tr(Omega_R^-1)); 2D: tau = 2 / tr(Omega_t^-1), kappa =
// Omega_thth.
double seSyncObjective(const PoseGraph& graph);

// (C) TORO's unweighted error: sum over constraints of (rotation angle of the residual)^2 +
// |translation residual|^2, with the largest and mean rotational (rad) and translational residuals.
struct ToroError {
  double sum = 0.0;
  double max_rotation = 0.0;
  double max_translation = 0.0;
  double mean_rotation = 0.0;
  double mean_translation = 0.0;
};
ToroError toroError(const PoseGraph& graph);

// The robust objective: sum of rho(chi2) over loop closures (isLoopClosure) and chi2 over the rest;
// g2oChi2 when `robust` is off.
double robustObjective(const PoseGraph& graph, const RobustOptions& robust);

// Robust weight of every constraint at the current poses (1 for odometry and with `robust` off).
std::vector<double> robustWeights(const PoseGraph& graph, const RobustOptions& robust);

// The kernel width the accepted loop closures' residuals call for (RobustOptions::
// adaptive_width_factor): that factor times the 99th percentile of the chi2 of the loop closures
// accepted now (weight >= kRejectedWeight), when that is narrower than robust.width, else
// robust.width: the width only ever narrows (for senders whose covariances are too large, whose
// wrong loop closures then stand out), never widens (wrong ones that passed would carry it away).
double adaptedRobustWidth(const PoseGraph& graph, const RobustOptions& robust);

// Position RMSE (m) between the poses of `estimate` and `reference` (matched by node id; nodes
// missing from either are skipped) after the rigid motion that best aligns the estimate onto the
// reference (Horn/Umeyama without scale), so a different gauge costs nothing.  0 for < 1 node.
double alignedPositionRmse(const PoseGraph& estimate, const PoseGraph& reference);

// Per-constraint g2o chi2 (same definition as g2oChi2), e.g. to colour loop closures by residual.
double constraintChi2(const PoseGraph& graph, std::size_t constraint_index);

// The planar (x, y, theta) information of a lifted 2D constraint, in angle units: the internal
// 6x6 at indices (0, 1, 5) with the theta-theta entry divided by 4 and the x-theta, y-theta
// entries by 2 (the internal yaw unit is the quaternion-vector one, about half the angle).
Eigen::Matrix3d planarInformation(const Matrix6& information);

}  // namespace toro
