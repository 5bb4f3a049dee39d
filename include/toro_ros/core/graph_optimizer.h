// The combined optimiser: TORO (tree-parameterised SGD, robust from poor starts) first, then the
// sparse Levenberg-Marquardt finish (exact optimum).  One function, so the command-line tool and
// the node run the same code.
//
// Switch-over: the TORO phase ends after toro_max_iterations, or earlier, once an iteration
// lowers the g2o chi2 by less than switch_relative_decrease of its value (TORO's progress has
// flattened out and the finish takes over), but never before toro_min_iterations.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/core/tree_optimizer.h"

namespace toro {

enum class OptimizeMode {
  kToro,            // TORO iterations only
  kFinish,          // the sparse finish only (from the graph's poses or the chained guess)
  kToroThenFinish,  // TORO, then the finish once the switch-over rule fires
};
const char* optimizeModeName(OptimizeMode mode);

// TORO's rotational gamma for a TORO phase that a finish follows.  The finish needs the right
// basin more than a low chi2: larger rotational steps (gamma 0.1 instead of 1) lead it to the best
// known minimum on both big-noise spheres, where gamma 1 leaves it in a worse local minimum
// (sphere_bignoise_vertex3.g2o: 743862.77 instead of 860415.79; toro/sphere_bignoise.graph:
// 758990 instead of 874498), and give the same minimum on the 16 other shared datasets tried
// (bench/finish_results.md, "TORO gamma before the finish").  TORO alone keeps gamma 1, which
// gives the lower chi2 after 100 iterations.
constexpr double kToroGammaBeforeFinish = 0.1;

inline TreeOptimizerOptions toroOptionsBeforeFinish() {
  TreeOptimizerOptions options;
  options.gamma = kToroGammaBeforeFinish;
  return options;
}
// Parses "toro", "finish" or "toro+finish"; false for anything else.
bool parseOptimizeMode(const std::string& text, OptimizeMode* mode);


struct OptimizeOptions {
  OptimizeMode mode = OptimizeMode::kToroThenFinish;
  // Start: the poses stored in the graph, or the measurements chained along TORO's tree.
  InitialGuess initial_guess = InitialGuess::kChainOnTree;
  // gamma defaults to kToroGammaBeforeFinish (the default mode); use TreeOptimizerOptions{}.gamma
  // for TORO alone.  toro.parameterization picks the group: SE(2) for 2D graphs by default;
  // kPlanar on a 3D graph first replaces `graph` by its projection onto the plane (planar.h), so the
  // finish, the metrics and the result are planar too (the finish of a 2D graph is always planar).
  TreeOptimizerOptions toro = toroOptionsBeforeFinish();
  // TORO phase length (0: no TORO iteration, only the initial guess).  In kToro mode the switch
  // threshold still ends the phase early when it is positive; set it to 0 to run exactly
  // toro_max_iterations.
  // Defaults chosen by measurement (bench/finish_results.md, "Switch-over rule"): on sphere2500,
  // parking-garage, smallGrid3D, intel, MIT, manhattanOlson3500, city10000 and ais2klinik every
  // threshold from 1.0 to 0.01 reaches the best known minimum (MIT only with TORO first); 1.0 to
  // 0.2 are the fastest on the timed files, and 0.2 keeps TORO going while its first iterations
  // still remove more than a fifth of chi2 each.
  std::size_t toro_max_iterations = 100;
  std::size_t toro_min_iterations = 3;
  double switch_relative_decrease = 0.2;
  FinishOptions finish;
  // Robust loop closures in both phases (robust_kernel.h); overrides toro.robust and finish.robust.
  // With it, the switch-over rule and the history follow the robust objective (sum rho over loop
  // closures plus the chi2 of odometry) instead of the plain chi2.  With initial_guess
  // kChainOdometry (the robust start), the TORO phase runs from two starts and keeps the one whose
  // robust objective ends lower (after a few finish iterations each): dead reckoning, and the plain
  // optimum of the odometry plus the loop closures the odometry alone agrees with
  // (odometry_consistency.h).  See robust_optimizer.cpp.
  // Why both: from dead reckoning, right loop closures that close a long loop start with the whole
  // drift as residual and are weighted out (kitti_00: all 137 rejected); the odometry test is
  // lenient where the odometry between two poses is long and uncertain, so on dense graphs with
  // many wrong loop closures the second start is bent by the wrong ones it lets through.
  RobustOptions robust;

  // Empty when valid, otherwise what is wrong (including the nested options).
  std::string validate() const;
};

enum class OptimizePhase { kStart, kToro, kFinish };
const char* optimizePhaseName(OptimizePhase phase);

// One line of the per-iteration report, for both phases.
struct OptimizeIteration {
  OptimizePhase phase = OptimizePhase::kToro;
  std::size_t iteration = 0;  // 1-based within its phase (0 for kStart)
  double chi2 = 0.0;          // g2o chi2 (REFERENCE.md (B)) after the iteration; the robust
                              // objective when OptimizeOptions::robust is enabled
  double lambda = 0.0;        // finish: damping of the step; TORO: learning rate
  bool accepted = true;       // finish: whether the step was taken
  double seconds = 0.0;       // wall time since optimizeGraph() started (callbacks included)
  // The current estimate, for callers that measure more than chi2; valid during the callback
  // only.  Null in the finish phase, whose state lives inside the solver until it ends.
  const PoseGraph* estimate = nullptr;
};

// Which start the robust TORO phase kept (OptimizeOptions::robust).
// kCorroborated: the odometry-consistent loop closures without those pairs of nearby loop closures
// contradict or do not corroborate (run only when the dead-reckoning start held some).
enum class RobustStart { kNone, kDeadReckoning, kOdometryConsistent, kCorroborated };

// Loop closures whose innovation chi2 against the odometry is below the chi-square quantile at
// this confidence make the robust second start's map (OptimizeOptions::robust).
constexpr double kOdometryConsistencyConfidence = 0.999;
// ... times this: declared odometry covariances are often too small (kitti_02's right loop
// closures reach 31, MIT's 50 against 16.3 for 3 degrees of freedom), and a wrong loop closure let
// through here is still judged by the robust passes that follow.
constexpr double kOdometryConsistencyLenience = 4.0;

struct OptimizeReport {
  // g2o chi2 (the robust objective when OptimizeOptions::robust is enabled)
  double initial_chi2 = 0.0;  // at the initial guess
  double final_chi2 = 0.0;
  std::size_t toro_iterations = 0;
  std::string switch_reason;  // why the TORO phase ended (empty if it did not run)
  double toro_seconds = 0.0;
  FinishReport finish;  // stop == kNotRun if the finish did not run
  double seconds = 0.0;
  // Final robust weight of every constraint (by index; all 1 without robust estimation), the
  // number of loop closures (isLoopClosure) and of those whose weight ended below kRejectedWeight.
  std::vector<double> weights;
  std::size_t loop_closures = 0;
  std::size_t rejected_loop_closures = 0;
  RobustStart robust_start = RobustStart::kNone;
  double robust_width = 0.0;  // the kernel width the weights are reported at (after adaptation)
  std::size_t width_rounds = 0;  // finishes run to refine with an adapted width
  std::size_t odometry_consistent_loop_closures = 0;  // of the robust second start
  std::size_t subset_finish_iterations = 0;  // the second start's plain finish on its subgraph
  std::size_t candidate_finish_iterations = 0;  // the finishes of the starts that were not kept
  // Loop closures the dead-reckoning start left out of its first finish (robust_optimizer.cpp,
  // heldFromDeadReckoning); 0 when that start did not run.
  std::size_t dead_reckoning_held = 0;
  // Loop closures the kept start rejected that the map without them predicts (innovation chi2
  // within the chi-square quantile at kOdometryConsistencyConfidence, times the map's variance
  // factor when below 1; robust_optimizer.cpp), and whether counting them in full once lowered the
  // robust cost (then the result is that finish's).
  std::size_t predicted_rejected = 0;
  bool predicted_readmitted = false;
  std::vector<OptimizeIteration> history;  // kStart line first
};

using OptimizeCallback = std::function<void(const OptimizeIteration&)>;

// Optimises the poses of `graph` in place.  Throws std::invalid_argument for invalid options.
OptimizeReport optimizeGraph(PoseGraph& graph, const OptimizeOptions& options,
                             const OptimizeCallback& callback = {});

}  // namespace toro
