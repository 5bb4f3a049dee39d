#include "sparse_cholesky.h"

#include <dlfcn.h>

#include <Eigen/SparseCholesky>
#include <stdexcept>

#ifdef TORO_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

namespace toro {

bool cholmodAvailable() {
#ifdef TORO_HAVE_CHOLMOD
  return true;
#else
  return false;
#endif
}

SolverThreadSettings limitSolverThreads(int blas_threads) {
  // dlsym instead of linking: the BLAS behind CHOLMOD is chosen by the system (Debian's
  // alternatives), and OpenMP is CHOLMOD's own dependency.
  using IntSetter = void (*)(int);
  SolverThreadSettings out;
  if (auto set_threads = reinterpret_cast<IntSetter>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) {
    set_threads(blas_threads < 1 ? 1 : blas_threads);
    out.openblas_set = true;
  }
  if (auto set_dynamic = reinterpret_cast<IntSetter>(dlsym(RTLD_DEFAULT, "omp_set_dynamic"))) {
    set_dynamic(1);
    out.openmp_dynamic_set = true;
  }
  return out;
}

const char* linearSolverName(LinearSolverType type) {
  switch (type) {
    case LinearSolverType::kCholmodSupernodal:
      return "cholmod-supernodal";
    case LinearSolverType::kCholmodSimplicial:
      return "cholmod-simplicial";
    case LinearSolverType::kSimplicialLDLT:
      return "eigen-ldlt";
  }
  return "unknown";
}

namespace detail {
namespace {

// Any Eigen-style solver with analyzePattern / factorize / info / solve.
template <class Solver>
class EigenStyleCholesky : public SparseCholesky {
 public:
  void analyzePattern(const SparseMatrix& upper) override { solver_.analyzePattern(upper); }
  bool factorize(const SparseMatrix& upper) override {
    solver_.factorize(upper);
    return solver_.info() == Eigen::Success;
  }
  Eigen::VectorXd solve(const Eigen::VectorXd& rhs) override { return solver_.solve(rhs); }

 protected:
  Solver solver_;
};

#ifdef TORO_HAVE_CHOLMOD
template <class Solver>
class QuietCholmod : public EigenStyleCholesky<Solver> {
 public:
  // CHOLMOD prints warnings (e.g. "not positive definite") by default; the library must not
  // print, and a failed factorisation is reported through factorize()'s result instead.
  QuietCholmod() { this->solver_.cholmod().print = 0; }
};
#endif

}  // namespace

std::unique_ptr<SparseCholesky> makeSparseCholesky(LinearSolverType type) {
  switch (type) {
    case LinearSolverType::kSimplicialLDLT:
      return std::make_unique<EigenStyleCholesky<Eigen::SimplicialLDLT<SparseMatrix, Eigen::Upper>>>();
#ifdef TORO_HAVE_CHOLMOD
    case LinearSolverType::kCholmodSupernodal:
      return std::make_unique<QuietCholmod<Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Upper>>>();
    case LinearSolverType::kCholmodSimplicial:
      return std::make_unique<QuietCholmod<Eigen::CholmodSimplicialLDLT<SparseMatrix, Eigen::Upper>>>();
#else
    case LinearSolverType::kCholmodSupernodal:
    case LinearSolverType::kCholmodSimplicial:
      break;
#endif
  }
  throw std::invalid_argument(std::string("linear solver ") + linearSolverName(type) +
                              " is not built in (CHOLMOD was not found at configure time)");
}

}  // namespace detail
}  // namespace toro
