#include "toro_ros/core/block_stiffness.h"

#include <Eigen/Eigenvalues>
#include <algorithm>

#include "toro_ros/core/pose_graph.h"

namespace toro {

namespace {

template <int N>
BlockStiffnessN<N> stiffnessOf(const typename BlockStiffnessN<N>::Matrix& block) {
  using Matrix = typename BlockStiffnessN<N>::Matrix;
  BlockStiffnessN<N> out;
  const Matrix symmetric = 0.5 * (block + block.transpose());
  Eigen::SelfAdjointEigenSolver<Matrix> eigen;
  eigen.computeDirect(symmetric);
  const Eigen::Matrix<double, N, 1> values = eigen.eigenvalues();  // ascending
  const double largest = values(N - 1);
  if (!(largest > 0.0)) return out;  // nothing measured: weight 0
  const double floor = kUnmeasuredInformationRatio * largest;
  if (values(0) > floor) {
    out.weight = symmetric.diagonal().minCoeff();
    return out;
  }
  out.all_axes_measured = false;
  out.measured_projection.setZero();
  out.weight = largest;
  for (int i = 0; i < N; ++i) {
    if (values(i) <= floor) continue;
    out.weight = std::min(out.weight, values(i));
    const Eigen::Matrix<double, N, 1> axis = eigen.eigenvectors().col(i);
    out.measured_projection += axis * axis.transpose();
  }
  return out;
}

}  // namespace

BlockStiffness blockStiffness(const Matrix3& block) { return stiffnessOf<3>(block); }

PlanarBlockStiffness planarBlockStiffness(const Matrix2& block) { return stiffnessOf<2>(block); }

}  // namespace toro
