// Internal: the sparse Cholesky behind the finish, one interface over Eigen's and CHOLMOD's.
// The pattern is analysed once (fill-reducing ordering, symbolic factorisation); every
// iteration only refactorises the numbers.
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <memory>

#include "toro_ros/core/sparse_finisher.h"

namespace toro {
namespace detail {

// Symmetric matrices are stored by their upper triangle (column-major).
using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

class SparseCholesky {
 public:
  virtual ~SparseCholesky() = default;
  virtual void analyzePattern(const SparseMatrix& upper) = 0;
  // False if the matrix is not (numerically) positive definite.
  virtual bool factorize(const SparseMatrix& upper) = 0;
  virtual Eigen::VectorXd solve(const Eigen::VectorXd& rhs) = 0;
};

// Throws std::invalid_argument for a solver not built in.
std::unique_ptr<SparseCholesky> makeSparseCholesky(LinearSolverType type);

}  // namespace detail
}  // namespace toro
