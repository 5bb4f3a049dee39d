#include "toro_ros/core/block_stiffness.h"

#include <Eigen/Eigenvalues>
#include <algorithm>

#include "toro_ros/core/pose_graph.h"

namespace toro {

BlockStiffness blockStiffness(const Matrix3& block) {
  BlockStiffness out;
  const Matrix3 symmetric = 0.5 * (block + block.transpose());
  Eigen::SelfAdjointEigenSolver<Matrix3> eigen;
  eigen.computeDirect(symmetric);
  const Vector3 values = eigen.eigenvalues();  // ascending
  const double largest = values(2);
  if (!(largest > 0.0)) return out;  // nothing measured: weight 0
  const double floor = kUnmeasuredInformationRatio * largest;
  if (values(0) > floor) {
    out.weight = symmetric.diagonal().minCoeff();
    return out;
  }
  out.all_axes_measured = false;
  out.measured_projection.setZero();
  out.weight = largest;
  for (int i = 0; i < 3; ++i) {
    if (values(i) <= floor) continue;
    out.weight = std::min(out.weight, values(i));
    const Vector3 axis = eigen.eigenvectors().col(i);
    out.measured_projection += axis * axis.transpose();
  }
  return out;
}

}  // namespace toro
