// Internal: the sparse Cholesky behind the finish, one interface over Eigen's and CHOLMOD's.
// The pattern is analysed once (symbolic factorisation); every iteration only refactorises the
// numbers.  The matrix comes in a fill-reducing order already (the finish orders its blocks), so
// the solvers keep the order they are given.
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <memory>
#include <vector>

#include "toro_ros/core/sparse_finisher.h"

namespace toro {
namespace detail {

// Symmetric matrices are stored by their lower triangle (column-major): the form CHOLMOD's
// supernodal factorisation reads without a copy.
using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

class SparseCholesky {
 public:
  virtual ~SparseCholesky() = default;
  virtual void analyzePattern(const SparseMatrix& lower) = 0;
  // False if the matrix is not (numerically) positive definite.
  virtual bool factorize(const SparseMatrix& lower) = 0;
  virtual Eigen::VectorXd solve(const Eigen::VectorXd& rhs) = 0;
  // Several right-hand sides at once (CHOLMOD's supernodal solve then runs on BLAS-3 blocks).
  virtual Eigen::MatrixXd solveColumns(const Eigen::MatrixXd& rhs) = 0;
  // Y = L^-1 P rhs, the forward half of a solve with the factorisation P A P^T = L L^T, so that
  // Y^T Y = rhs^T A^-1 rhs: the quadratic forms of A^-1 for half the triangular work of
  // solveColumns, symmetric by construction.  False when this factorisation is not L L^T (the
  // caller then uses solveColumns).
  virtual bool forwardSolveColumns(const Eigen::MatrixXd& /*rhs*/, Eigen::MatrixXd* /*y*/) { return false; }
  // Y^T Y for Y = L^-1 P rhs, for a right-hand side nonzero in few rows (a constraint's Jacobian
  // transposed: two blocks): only the part of the factor the forward solve reaches from those rows
  // is read (the supernodes on their paths to the root of the elimination tree).  False when this
  // factorisation is not a supernodal L L^T (the caller then uses forwardSolveColumns).
  virtual bool forwardGram(const SparseMatrix& /*rhs*/, Eigen::MatrixXd* /*gram*/) { return false; }
};

// A fill-reducing order of a symmetric pattern (both triangles given): position[i] is where row
// and column i go.  CHOLMOD's AMD when built in (Eigen's AMD left 17 % more time per factorisation
// of sphere2500.g2o's blocks), else Eigen's.
std::vector<int> fillReducingPositions(const SparseMatrix& pattern);

// Throws std::invalid_argument for a solver not built in.
std::unique_ptr<SparseCholesky> makeSparseCholesky(LinearSolverType type);

}  // namespace detail
}  // namespace toro
