// Residuals and analytic Jacobians of one constraint, the building blocks of the sparse finish.
//
// 3D: the residual is exactly the g2o error of ../shared/datasets/REFERENCE.md (B):
//   e = [t(D); qvec(D) with w >= 0],  D = Z^-1 X_i^-1 X_j,
// so that sum e^T Omega e is g2oChi2().  The state of a node is perturbed on the right,
//   X <- X * Exp_SE3(delta),  delta = (rho, phi)   (translation first, like the error).
// (The cheaper X * (Exp_SO3(phi), rho) has the same Jacobians at delta = 0, but measured on
// parking-garage.g2o it needs 28 instead of 13 iterations: the coupled translation V(phi) rho
// follows the curved valleys of the cost better on long steps.)
//
// 2D (lifted graphs, GraphDimension::k2D): the state is (x, y, theta), updated additively, and
// the residual is the planar g2o error e = [Rz^T (Ri^T (tj - ti) - tz); wrap(thj - thi - thz)].
// Optimising the planar problem keeps z, roll and pitch out of the state altogether (they are
// zero in lifted graphs) and minimises exactly the 2D chi2 that g2oChi2() reports for k2D.
#pragma once

#include <Eigen/Core>

#include "toro_ros/core/pose3.h"

namespace toro {

struct Linearization3D {
  Vector6 error;
  Matrix6 d_from;  // d error / d delta_i
  Matrix6 d_to;    // d error / d delta_j
};

// Residual only (used for trial steps).
Vector6 errorSE3(const Pose3& x_i, const Pose3& x_j, const Pose3& measurement);
// Residual and both Jacobians.
void linearizeSE3(const Pose3& x_i, const Pose3& x_j, const Pose3& measurement, Linearization3D* out);
// X * Exp_SE3(delta) with delta = (rho, phi): rotation Exp(phi), translation V(phi) rho.
Pose3 retractSE3(const Pose3& x, const Vector6& delta);

// Planar state and measurement: (x, y, theta).
struct Linearization2D {
  Vector3 error;
  Matrix3 d_from;
  Matrix3 d_to;
};
Vector3 errorSE2(const Vector3& x_i, const Vector3& x_j, const Vector3& measurement);
void linearizeSE2(const Vector3& x_i, const Vector3& x_j, const Vector3& measurement, Linearization2D* out);

// Angle in (-pi, pi].
double wrapAngle(double angle);

}  // namespace toro
