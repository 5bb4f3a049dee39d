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

// Threads of the finish.  The sparse Cholesky runs in runtimes with threads of their own: OpenBLAS
// (when it is the system BLAS; a pool of one thread per CPU, started when it is loaded) and the
// OpenMP loops CHOLMOD 3 runs inside each supernodal factorisation (`num_threads(4)`, fixed at its
// compile time, so omp_set_num_threads alone does not reach them).  On a 2-core machine that team
// of 4 made the finish of smallGrid3D.g2o 2.5x slower than one thread, and sphere2500.g2o 2.2x
// slower beside a two-job compiler build (bench/finish_load_results.md).  setSolverThreads(n), n >= 1:
//  * OpenBLAS: n threads (openblas_set_num_threads; process-wide at once);
//  * OpenMP: n threads and dynamic teams (omp_set_num_threads, omp_set_dynamic).  libgomp then bounds
//    every team, CHOLMOD's num_threads(4) ones included, by n (and by the CPUs left after the
//    15-minute load average).  These are per-thread settings in OpenMP, so the count is kept here
//    and every finish applies it to the thread it runs in (the node's worker, a background finish)
//    before it factorises;
//  * CHOLMOD >= 5 (SuiteSparse 7; not Debian 12's 3.0): also its Common.nthreads_max.
// n = 0 changes nothing: the libraries keep their own settings (or those of an earlier call, which
// stays in force).
// Process-wide: every finish in the process uses the last count set, so programs that own their
// process call it (toro_optimize, toro_offline, the node at start; a nodelet sets it for its whole
// manager process).  Looked up at run time (dlsym): a runtime that is not loaded is left alone.
constexpr int kDefaultSolverThreads = 1;  // measured: bench/finish_load_results.md
constexpr int kMaxSolverThreads = 1024;   // more than any machine this runs on: catches typos
struct SolverThreadSettings {
  int threads = 0;            // the count in force after the call (0: the libraries' own)
  bool openblas_set = false;  // openblas_set_num_threads was found and called
  bool openmp_set = false;    // omp_set_num_threads and omp_set_dynamic were found and called
};
// Empty when `threads` is a valid count (0 to kMaxSolverThreads), otherwise what is wrong.
std::string validateSolverThreads(int threads);
// Throws std::invalid_argument for an invalid count (validateSolverThreads).
SolverThreadSettings setSolverThreads(int threads);
// The count in force: the last non-zero one given to setSolverThreads (0 if none was).
int solverThreads();
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
  // Robust loop closures whose weight at the start of a finish round is below this times the
  // median weight of the loop closures are set aside:
  // left out of the factorisation (a wrong loop closure between far-apart poses only adds fill-in to it,
  // measured 10x slower with 1000 on sphere2500) but kept in the objective, the gradient and, by
  // preconditioned conjugate gradients, in each step (finish_problem.h).  When one regains this
  // weight, the finish starts a new round with it factorised (at most kMaxSetAsideRounds); when
  // that correction does not converge (set-aside loop closures too stiff to leave out: tight
  // information between poses a long chain joins), a new round with every loop closure factorised.
  // 0 keeps all in the factorisation.
  double robust_set_aside_weight = 1e-3;
  // Robust finishes damp with Marquardt's scaling, lambda times each diagonal entry of the normal
  // equations relative to the largest, instead of lambda times the identity (plain finishes always
  // use the identity).  Why: from a map that wrong loop closures bent, many steps are rejected, and
  // where the information of the constraints spans orders of magnitude the identity damping that
  // tames the stiffest directions freezes the soft ones (kitti_02 with 100 random wrong ones: 0.042
  // m from the clean optimum, scaled 0.002 m; bench/robust_results.md, session 33).
  bool robust_scaled_damping = true;

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
  kSetAsideTooStiff,  // internal: a round ended so the next one factorises every loop closure
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
  // Per candidate of optimize(), in its order: e^T (Sigma_z + J H^-1 J^T)^-1 e at the finished
  // poses (H the finished graph's Hessian; units of the g2o chi2), the rise of the optimum's chi2
  // it would bring to first order, chi-square with 6 (3 in 2D) degrees of freedom for a right
  // one.  -1 where it cannot be told (an end not in the graph, a Hessian that does not factorise).
  std::vector<double> innovation_chi2;
  // Per `included` constraint of optimize(), in its order: its leave-one-out innovation chi2, what
  // innovation_chi2 would give it were it left out, computed from the finish with it (for a
  // constraint at full weight e^T (Sigma_z - J H^-1 J^T)^-1 e; in a linear-Gaussian model exactly
  // the left-out value).  -1 where it cannot be told (set aside, or nothing else constrains its
  // ends along some direction).
  std::vector<double> included_innovation_chi2;
};

using FinishCallback = std::function<void(const FinishIteration&)>;

// A constraint of the graph whose leave-one-out innovation a finish gives (optimize's `included`).
struct IncludedConstraint {
  std::size_t index = 0;  // in the graph
  // The weight its information in the graph carries (a caller's robust weight applied with
  // PoseGraph::scaleInformation): its innovation is against its information over this, the
  // information it would be tested with were it left out.  In (0, 1].
  double weight = 1.0;
};

class LevenbergMarquardt {
 public:
  // Throws std::invalid_argument if options.validate() fails or the chosen linear solver is not
  // built in.
  explicit LevenbergMarquardt(const FinishOptions& options = {});

  // Optimises the poses of `graph` in place and reports; `callback` (if set) sees every iteration.
  // Information matrices that are not positive definite are repaired (repairInformation) for the
  // solve only and counted in the report; the graph's constraints are left as they are.
  // Throws std::runtime_error if the sparse factorisation fails for a reason damping cannot cure.
  // `candidates`: constraints not in the graph (e.g. loop closures held out of it) whose
  // innovation chi2 against the finished graph the report gives (innovation_chi2).  `included`:
  // constraints of `graph` whose leave-one-out innovation it gives (included_innovation_chi2),
  // e.g. to calibrate the test of the candidates on the graph's own.
  FinishReport optimize(PoseGraph& graph, const FinishCallback& callback = {},
                        const std::vector<Constraint>& candidates = {},
                        const std::vector<IncludedConstraint>& included = {}) const;

  const FinishOptions& options() const { return options_; }

 private:
  FinishOptions options_;
};

}  // namespace toro
