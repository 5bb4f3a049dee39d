// The sparse second-order finish: Levenberg-Marquardt on the exact g2o chi2 (REFERENCE.md (B)).
//
// TORO gets close to the optimum from poor starts; this solver takes the last digits.  The
// residuals and analytic Jacobians are in finish_residuals.h (3D: right perturbation on SE(3);
// 2D graphs: the planar (x, y, theta) problem, whose cost is the 2D chi2 g2oChi2() reports).
// The normal equations are assembled straight into the values of a sparse matrix whose pattern
// is built once; the sparse Cholesky analyses that pattern once and factorises every iteration.
//
// Gauge: the graph's FIX nodes when it has any, otherwise the node with the smallest id (the
// root of TORO's tree).  A connected component that contains no held node (e.g. a second,
// unconnected map) gets its own smallest id held as well, so the system is never singular.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/robust_kernel.h"

namespace toro {

enum class LinearSolverType {
  kCholmodSupernodal,  // CHOLMOD supernodal LL^T (SuiteSparse; BLAS-based dense supernodes)
  kCholmodSimplicial,  // CHOLMOD simplicial LDL^T (SuiteSparse)
  kSimplicialLDLT,     // Eigen's SimplicialLDLT (no external library)
};

// True if this build links CHOLMOD (kCholmodSupernodal is usable).
bool cholmodAvailable();

// The sparse Cholesky runs in runtimes with their own threads: OpenBLAS (when it is the system
// BLAS) and CHOLMOD's OpenMP loops (4 threads, fixed at its compile time).  On this project's
// 2-core machines, shared with other work, those threads spin and wait more than they compute:
// measured on sphere2500.g2o (bench/finish_results.md), limiting them makes TORO-then-finish about
// 1.7x faster in wall time and halves its CPU time.  This sets OpenBLAS to `blas_threads` threads
// and lets OpenMP adapt its team sizes to the load (omp_set_dynamic).  Process-wide, so only
// programs that own their process call it (toro_optimize, the benchmark); a library user decides
// for its own process.  Looked up at run time: a runtime that is not loaded is left alone.
struct SolverThreadSettings {
  bool openblas_set = false;        // openblas_set_num_threads was found and called
  bool openmp_dynamic_set = false;  // omp_set_dynamic was found and called
};
SolverThreadSettings limitSolverThreads(int blas_threads);
const char* linearSolverName(LinearSolverType type);

// How often the finish runs again when a set-aside loop closure regained weight (robust only).
constexpr std::size_t kMaxSetAsideRounds = 4;

struct FinishOptions {
  // Stop after this many iterations (accepted or rejected steps).
  std::size_t max_iterations = 100;
  // Stop when an accepted step lowers chi2 by less than this fraction of its value, or when the
  // next step is estimated to (kPredictedDecrease).
  double relative_decrease_tolerance = 1e-7;
  // Stop when the largest gradient entry |J^T Omega e|_inf is below this (chi2 per metre/radian).
  double gradient_tolerance = 1e-10;
  // Stop when the largest entry of a step (metres, radians) is below this.
  double step_tolerance = 1e-12;
  // Initial damping lambda = initial_lambda_factor * (largest diagonal entry of J^T Omega J).
  // Small, so the first steps are nearly Gauss-Newton: measured on parking-garage.g2o, 1e-8
  // damps its weakly constrained directions into 11 slow iterations, 1e-12 needs 4; sphere2500,
  // MIT, intel, ais2klinik and sphere_bignoise need the same or fewer (bench/finish_results.md).
  // Bad steps raise lambda anyway (gain ratio <= 0: lambda *= 2, 4, 8, ...).
  double initial_lambda_factor = 1e-12;
  // Give up (reason kLambdaTooLarge) when lambda exceeds this multiple of the largest diagonal.
  double max_lambda_factor = 1e10;
  LinearSolverType linear_solver = LinearSolverType::kCholmodSupernodal;
  // Robust loop closures (robust_kernel.h): the finish minimises sum rho(chi2) over loop closures
  // plus the plain chi2 of odometry, by iteratively reweighted Levenberg-Marquardt.  Off by default.
  RobustOptions robust;
  // Robust loop closures whose weight at the start of a finish round is below this are set aside:
  // left out of the factorisation (a wrong loop closure between far-apart poses only adds fill-in to it,
  // measured 10x slower with 1000 on sphere2500) but kept in the objective, the gradient and, by
  // preconditioned conjugate gradients, in each step (finish_problem.h).  When one regains this
  // weight, the finish starts a new round with it factorised (at most kMaxSetAsideRounds).
  // 0 keeps all in the factorisation.
  double robust_set_aside_weight = 1e-3;

  // Empty when valid, otherwise what is wrong.
  std::string validate() const;
};

enum class FinishStop {
  kNotRun,
  kRelativeDecrease,   // converged: chi2 no longer decreases noticeably
  kPredictedDecrease,  // converged: the next step's decrease, estimated with the last
                       // factorisation, is below relative_decrease_tolerance
  kGradient,           // converged: gradient ~ 0
  kStep,               // converged: steps ~ 0
  kMaxIterations,
  kLambdaTooLarge,  // no step lowers chi2 any more (stalled, e.g. at the limit of precision)
  kNoConstraints,
  kSetAsideRegained,  // internal: a round ended so the next one factorises regained loop closures
};
const char* finishStopName(FinishStop stop);

struct FinishIteration {
  std::size_t iteration = 0;   // 1-based
  double chi2 = 0.0;           // objective after this iteration (unchanged if the step was rejected)
  double lambda = 0.0;         // damping used for this iteration's step
  double gain_ratio = 0.0;     // actual / predicted decrease
  double step_norm = 0.0;      // largest entry of the step
  double gradient_norm = 0.0;  // largest gradient entry before the step
  bool accepted = false;
  double seconds = 0.0;  // wall time since optimize() started
};

struct FinishReport {
  // Plain g2o chi2 of all constraints (robust or not), before and after.
  double initial_chi2 = 0.0;
  double final_chi2 = 0.0;
  // The objective minimised: chi2, or with robust loop closures sum rho(chi2) over them plus the
  // chi2 of the others.  The per-iteration history reports this one.
  double initial_objective = 0.0;
  double final_objective = 0.0;
  // Final weight rho'(chi2) of each constraint, by constraint index (1 for non-robust ones).
  std::vector<double> weights;
  std::size_t iterations = 0;
  FinishStop stop = FinishStop::kNotRun;
  std::size_t held_nodes = 0;            // gauge nodes (see the header comment)
  std::size_t repaired_information = 0;  // constraints whose information was not positive definite
  std::size_t set_aside = 0;  // robust loop closures left out in the last round (robust_set_aside_weight)
  std::size_t rounds = 1;     // finish runs (more than 1 when a set-aside loop closure regained weight)
  std::size_t conjugate_gradient_iterations = 0;  // spent on set-aside loop closures
  double seconds = 0.0;
  double factorization_seconds = 0.0;  // of which: numeric factorisations and solves
  std::vector<FinishIteration> history;
};

using FinishCallback = std::function<void(const FinishIteration&)>;

class LevenbergMarquardt {
 public:
  // Throws std::invalid_argument if options.validate() fails or the chosen linear solver is not
  // built in.
  explicit LevenbergMarquardt(const FinishOptions& options = {});

  // Optimises the poses of `graph` in place and reports; `callback` (if set) sees every iteration.
  // Information matrices that are not positive definite are repaired (repairInformation) for the
  // solve only and counted in the report; the graph's constraints are left as they are.
  // Throws std::runtime_error if the sparse factorisation fails for a reason damping cannot cure.
  FinishReport optimize(PoseGraph& graph, const FinishCallback& callback = {}) const;

  const FinishOptions& options() const { return options_; }

 private:
  FinishOptions options_;
};

}  // namespace toro
