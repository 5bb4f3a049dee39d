// TORO's scalar stiffness of a constraint: the optimiser spreads one scalar fraction of a
// constraint's rotational (and, separately, translational) error over its path, so each 3x3 block
// of the information matrix is reduced to one number (Grisetti et al. take the smallest diagonal
// entry: a conservative stiffness).  Real ROS senders mark axes they do not measure with a huge
// variance (planar robots: 1e6 on z, roll and pitch), which would make that smallest entry ~0 and
// the constraint weightless.  So the scalar comes from the axes that are measured, and the update
// moves only along them: an unmeasured axis neither zeroes the weight nor receives a correction.
#pragma once

#include "toro_ros/core/pose2.h"
#include "toro_ros/core/pose3.h"

namespace toro {

// N = 3: a translation or rotation block of a 3D constraint; N = 2: the translation block of a
// planar one (its rotation block is the single yaw entry).
template <int N>
struct BlockStiffnessN {
  using Matrix = Eigen::Matrix<double, N, N>;
  // The scalar information of the block: its smallest diagonal entry when every axis is measured
  // (TORO's rule, unchanged), else the smallest eigenvalue among the measured axes.
  double weight = 0.0;
  // False when some eigenvalue is below kUnmeasuredInformationRatio (pose_graph.h) of the largest.
  bool all_axes_measured = true;
  // Orthogonal projector onto the measured axes, in the frame of the block (identity when all are).
  Matrix measured_projection = Matrix::Identity();
};
using BlockStiffness = BlockStiffnessN<3>;
using PlanarBlockStiffness = BlockStiffnessN<2>;

// Of a symmetric positive-semidefinite 3x3 block (translation or rotation) of an information matrix.
BlockStiffness blockStiffness(const Matrix3& block);
// Of the 2x2 (x, y) translation block of a planar constraint, by the same rule.
PlanarBlockStiffness planarBlockStiffness(const Matrix2& block);

}  // namespace toro
