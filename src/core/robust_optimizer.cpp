// The robust strategy of optimizeGraph (OptimizeOptions::robust with the kChainOdometry start):
// two starts, each taken through robust TORO passes and a short robust finish, and the one whose
// robust objective is lower finished to convergence.
//
// Why two: from dead reckoning, a right loop closure that closes a long loop starts with the whole
// drift as its residual, so its robust weight is ~0 and nothing pulls the map towards it (kitti_00:
// all 137 rejected).  The odometry-consistency test (odometry_consistency.h) judges each loop
// closure against the odometry's own uncertainty and keeps those, but it is lenient where the
// odometry between two poses is long: on dense graphs with many wrong loop closures it lets most of
// them through, and the map made from them is bent.  Each start fails where the other works; the
// robust objective (sum rho over loop closures + chi2 of odometry) tells which one explains the
// measurements better, and a few finish iterations make that comparison reliable (after TORO alone
// the second start's map is not yet converged).
//
// Then, on the kept map, the rejected loop closures that the map without them predicts are counted
// in full once and weighed again (RobustRun::predictedRejected): a right one that the map reached
// without pulling towards it otherwise stays rejected at any width.
#include <algorithm>
#include <optional>
#include <sstream>

#include "graph_optimizer_detail.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/odometry_consistency.h"
#include "toro_ros/core/pairwise_consistency.h"

namespace toro {
namespace detail {

namespace {

// The width of the dead-reckoning start until its first solution (DCS's own, Agarwal et al.): from
// dead reckoning every right loop closure starts far off, and a wider kernel lets the wrong ones
// pull the map into their basin before the right ones gather weight (sphere2500 with 1000 random
// wrong loop closures: width 10 ends 56 m off, 1 at the clean optimum).  The width then adapts.
constexpr double kDeadReckoningWidth = 1.0;

// Finish iterations the odometry-consistent start gets before the check whether wrong loop closures
// bent it (then dead reckoning is tried too); a clean one converges within them.
constexpr std::size_t kCheckIterations = 8;
constexpr double kStartWidthFactor = 10.0;

// The width adaptation stops once the width moves by less than this factor, or after this many
// refinements (each a finish from the previous solution).
constexpr double kWidthSettled = 1.5;
constexpr int kWidthRounds = 4;
constexpr int kSettleSteps = 10;

struct Candidate {
  PoseGraph graph;
  std::string reason;  // why its TORO phase ended
  FinishReport finish;
  double objective = 0.0;
  double width = 0.0;  // the kernel width its finish ran with (0: none yet)
};

// A loop closure's innovation chi2 against the odometry (odometryInnovationChi2) above this
// refutes it: kOdometryConsistencyLenience times the chi-square quantile at
// kOdometryConsistencyConfidence.
double odometryConsistencyThreshold(const PoseGraph& graph) {
  const int dof = graph.dimension() == GraphDimension::k2D ? 3 : 6;
  return kOdometryConsistencyLenience * chiSquareQuantile(kOdometryConsistencyConfidence, dof);
}

// `graph` (its poses and fixed nodes kept) with the constraints `left_out` marks removed and those
// `gaussian` marks, if given, counted as odometry: plain least squares in a robust finish.
PoseGraph graphWithout(const PoseGraph& graph, const std::vector<char>& left_out,
                       const std::vector<char>* gaussian = nullptr) {
  PoseGraph kept = keepConstraints(graph, [&](std::size_t c) { return !left_out[c]; });
  if (!gaussian) return kept;
  std::size_t k = 0;  // c's index in `kept`
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    if (left_out[c]) continue;
    if ((*gaussian)[c]) kept.setKind(k, ConstraintKind::kOdometry);
    ++k;
  }
  return kept;
}

// `later` as the report of one finish that began with `earlier`: iterations and times summed,
// `earlier`'s iterations first in the history.  The initial chi2 and objective stay `later`'s;
// a caller whose earlier finish ran on the same constraints takes `earlier`'s.
void prependFinish(FinishReport& later, const FinishReport& earlier) {
  later.iterations += earlier.iterations;
  later.seconds += earlier.seconds;
  later.factorization_seconds += earlier.factorization_seconds;
  later.history.insert(later.history.begin(), earlier.history.begin(), earlier.history.end());
}

// The odometry and the loop closures that agree with it alone (innovation chi2 within
// odometryConsistencyThreshold), plus those between poses the odometry does not connect (nothing
// to test them against, and the map needs them to join its pieces), at the dead-reckoned poses.
// `in_subset` marks them; `innovation_out` receives each constraint's innovation
// (odometryInnovationChi2: -1 for odometry and for loop closures the odometry does not connect).
PoseGraph odometryConsistentSubgraph(const PoseGraph& graph, std::size_t* kept, std::vector<char>* in_subset,
                                     std::vector<double>* innovation_out) {
  TreeOptimizer dead_reckoning;
  dead_reckoning.setGraph(graph, InitialGuess::kChainOdometry);
  const PoseGraph& odometry = dead_reckoning.graph();
  *innovation_out = odometryInnovationChi2(odometry);
  const std::vector<double>& innovation = *innovation_out;
  const double threshold = odometryConsistencyThreshold(graph);
  PoseGraph subset;
  subset.setDimension(graph.dimension());
  for (const Node& n : odometry.nodes()) subset.addNode(n.id, n.pose);
  for (NodeId id : graph.fixedNodes()) subset.addFixed(id);
  *kept = 0;
  in_subset->assign(graph.numConstraints(), 1);
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    const Constraint& k = graph.constraints()[c];
    if (isLoopClosure(k)) {
      const bool unconnected = innovation[c] < 0.0;
      if (!(unconnected || innovation[c] <= threshold)) {
        (*in_subset)[c] = 0;
        continue;
      }
      ++*kept;
    }
    subset.addConstraint(k);
  }
  return subset;
}

// The loop closures the dead-reckoning start leaves out of its first finish: those the odometry
// refutes (as odometryConsistentSubgraph), and, once pairs of nearby loop closures have taught the
// sender's scale (pairwise_consistency.h), those their neighbours contradict and those that nothing
// near them corroborates.  They are weighed when the map has settled without them.  Why: the
// dead-reckoning start runs when wrong loop closures bent the first start, and a sender whose
// covariances are far too large makes bending cheap at any width in the declared units
// (parking-garage.g2o with 100 random wrong ones: one of them pulled this start 10.9 m off; with
// them left out, 0.003 m).  `innovation`: odometryConsistentSubgraph's, so the odometry is not
// dead-reckoned and composed again.  Counted in `*held_count`.
std::vector<char> heldFromDeadReckoning(const PoseGraph& graph, const std::vector<double>& innovation,
                                        std::size_t* held_count) {
  const double threshold = odometryConsistencyThreshold(graph);
  const PairwiseConsistency pairs = pairwiseConsistency(graph);
  std::vector<char> held(graph.numConstraints(), 0);
  *held_count = 0;
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    if (!isLoopClosure(graph.constraints()[c])) continue;
    const bool connected = innovation[c] >= 0.0;
    const bool refuted = connected && innovation[c] > threshold;
    const PairVerdict v = pairs.verdicts[c];
    const bool uncorroborated =
        pairs.scale_learnt && (v == PairVerdict::kContradicted || (v == PairVerdict::kAlone && connected));
    held[c] = refuted || uncorroborated;
    *held_count += held[c];
  }
  return held;
}

class RobustRun {
 public:
  RobustRun(const OptimizeOptions& options, const Recorder& record, OptimizeReport* report)
      : options_(options), record_(record), report_(report) {
    robust_toro_ = options.toro;
    robust_toro_.robust = options.robust;
    finish_ = options.finish;
    finish_.robust = options.robust;
  }

  // Start 1: robust TORO from dead reckoning.
  Candidate fromDeadReckoning(const PoseGraph& graph) {
    // Plain-chi2 weights here: against the long uncertain paths of dead reckoning the innovation
    // would find most loop closures plausible, wrong ones too (the finish does the weighing).
    TreeOptimizerOptions plain_weights = robust_toro_;
    plain_weights.robust_by_innovation = false;
    plain_weights.robust.width = std::min(robust_toro_.robust.width, kDeadReckoningWidth);
    TreeOptimizer toro(plain_weights);
    toro.setGraph(graph, InitialGuess::kChainOdometry);
    const double start = robustObjective(toro.graph(), options_.robust);
    record_(OptimizePhase::kStart, 0, start, 0.0, true, &toro.graph());
    Candidate c{graph, runToroPhase(toro, options_, start, record_, report_), {}, 0.0};
    copyPoses(toro.graph(), c.graph);
    return c;
  }

  // Start 2: the odometry-consistent subgraph by plain TORO (chained on its tree): the loop
  // closures the odometry agrees with close their loops, however long.
  Candidate fromConsistentLoopClosures(const PoseGraph& graph, std::vector<char>* in_subset,
                                       std::vector<double>* innovation) {
    PoseGraph subset =
        odometryConsistentSubgraph(graph, &report_->odometry_consistent_loop_closures, in_subset, innovation);
    // The run's start, recorded before any optimisation: the whole graph at the dead-reckoned poses
    // (the robust runs' initial guess), so a caller's "before" and setup time are those.
    PoseGraph start = graph;
    copyPoses(subset, start);
    report_->initial_chi2 = robustObjective(start, options_.robust);
    record_(OptimizePhase::kStart, 0, report_->initial_chi2, 0.0, true, &start);
    OptimizeReport subset_report;
    Candidate c = toroOnSubgraph(graph, subset, &subset_report);
    report_->subset_finish_iterations = subset_report.finish.iterations;
    return c;
  }

  // Start 3: the odometry-consistent loop closures that pairs of nearby ones do not hold
  // (heldFromDeadReckoning), by plain TORO chained on their tree.
  Candidate fromCorroboratedLoopClosures(const PoseGraph& graph, const std::vector<char>& held) {
    PoseGraph subset = graphWithout(graph, held);
    OptimizeReport subset_report;
    return toroOnSubgraph(graph, subset, &subset_report);
  }

  // Plain TORO chained on the tree of `subset` (a subgraph of `graph`), as a candidate for the
  // whole graph at the poses it reached.
  Candidate toroOnSubgraph(const PoseGraph& graph, PoseGraph& subset, OptimizeReport* subset_report) {
    OptimizeOptions plain = options_;
    plain.robust = RobustOptions{};
    plain.initial_guess = InitialGuess::kChainOnTree;
    // TORO only: a plain finish on a subgraph with wrong loop closures in it would pay their
    // fill-in for nothing (measured 30 s on sphere2500 with 1000 random ones).
    plain.mode = OptimizeMode::kToro;
    *subset_report = optimizeGraph(subset, plain);
    report_->toro_iterations += subset_report->toro_iterations;
    Candidate c{graph, subset_report->switch_reason, {}, 0.0};
    copyPoses(subset, c.graph);
    return c;
  }

  // The width the residuals of `c` call for now, the adaptation repeated on them until it settles
  // (no solve in between: each step only looks at the residuals, which stay as they are).
  double settledWidth(const Candidate& c, double width) const {
    RobustOptions robust = options_.robust;
    robust.width = width;
    for (int k = 0; k < kSettleSteps; ++k) {
      const double adapted = adaptedRobustWidth(c.graph, robust);
      const bool settled = adapted > robust.width / kWidthSettled && adapted < robust.width * kWidthSettled;
      robust.width = adapted;
      if (settled) break;
    }
    return robust.width;
  }

  // Finishes `c` with the loop closures `held` marks left out (at `width`), then whole at the width
  // the settled map's residuals call for: the held ones are weighed by their residuals on a map
  // they did not bend.
  void finishLeavingOut(Candidate& c, const std::vector<char>& held, double width) {
    Candidate without{graphWithout(c.graph, held), c.reason, {}, 0.0};
    finish(without, options_.finish.max_iterations, width);
    copyPoses(without.graph, c.graph);
    finish(c, options_.finish.max_iterations, settledWidth(without, options_.robust.width));
    // One report for both: the iterations and time of the finish without them count too (its
    // chi2 at the start is over fewer constraints, so the whole finish's is kept).
    prependFinish(c.finish, without.finish);
  }

  void finish(Candidate& c, std::size_t max_iterations, double width = 0.0) {
    FinishOptions o = finish_;
    o.max_iterations = max_iterations;
    if (width > 0.0) o.robust.width = width;
    c.width = o.robust.width;
    c.finish = LevenbergMarquardt(o).optimize(c.graph, [&](const FinishIteration& it) {
      record_(OptimizePhase::kFinish, it.iteration, it.chi2, it.lambda, it.accepted, nullptr);
    });
    // Over every loop closure: the finish's own objective leaves out the ones it set aside.
    RobustOptions r = options_.robust;
    if (width > 0.0) r.width = width;
    c.objective = robustObjective(c.graph, r);
  }

  // Continues the finish of `c` to its iteration limit when its last one stopped there.
  void finishFurther(Candidate& c) {
    if (c.finish.stop != FinishStop::kMaxIterations || c.finish.iterations >= options_.finish.max_iterations) return;
    const FinishReport first = c.finish;
    finish(c, options_.finish.max_iterations - first.iterations, c.width);
    c.finish.initial_chi2 = first.initial_chi2;
    c.finish.initial_objective = first.initial_objective;
    prependFinish(c.finish, first);
  }

  // The loop closures rejected in `c` (weight below kRejectedWeight at its width) that the map
  // without them predicts: their innovation chi2 (FinishReport::innovation_chi2, the rise of the
  // optimum's chi2 were each added alone) within the chi-square quantile at
  // kOdometryConsistencyConfidence times the a-posteriori variance factor of that map (at most 1,
  // so a sender whose covariances are too large gets a narrower test, not a wider one).  Why: a
  // right loop closure that the map reached without ever pulling towards it keeps its whole
  // residual and a weight of ~1e-6, so no finish moves it (manhattan with 100 grouped wrong ones: 30
  // right ones rejected with residual chi2 up to 9e4, yet innovations 0.4-30; the wrong ones' were
  // 1,090 and more).  No lenience factor as the odometry test has: with 4x the quantile, 1 random
  // wrong one of kitti_05 (seed 2) and 15-23 local ones of manhattan passed; without it none on 7
  // files x 3 seeds but MIT, and 21-27 of manhattan's 29-34 right ones still do.
  // Only those the odometry does not refute (`in_subset`, odometryConsistentSubgraph's) are tested:
  // a right one agrees with the odometry's own uncertainty, and each candidate costs a solve with
  // 3 or 6 right-hand sides.  That leaves out most wrong ones on kitti_00, CSAIL and manhattan;
  // where the odometry cannot refute them (sphere2500, parking-garage) nearly all are tested.
  // Measured cost: the robust solve's CPU time x1.0-1.55 (median per file), at most x3.3.
  std::vector<char> predictedRejected(const PoseGraph& graph, const Candidate& c,
                                      const std::vector<char>& in_subset, std::size_t* count) const {
    RobustOptions robust = options_.robust;
    robust.width = c.width;
    const std::vector<double> weights = robustWeights(c.graph, robust);
    std::vector<char> rejected(graph.numConstraints(), 0);
    std::vector<Constraint> candidates;
    std::vector<std::size_t> index;
    std::size_t accepted = 0;
    for (std::size_t k = 0; k < graph.numConstraints(); ++k) {
      if (!isLoopClosure(graph.constraints()[k])) continue;
      if (weights[k] >= kRejectedWeight) {
        ++accepted;
        continue;
      }
      rejected[k] = 1;
      if (!in_subset[k]) continue;
      candidates.push_back(c.graph.constraints()[k]);
      index.push_back(k);
    }
    std::vector<char> predicted(graph.numConstraints(), 0);
    *count = 0;
    if (candidates.empty() || accepted == 0) return predicted;
    PoseGraph without = graphWithout(c.graph, rejected);
    FinishOptions o = finish_;
    o.robust.width = c.width;
    o.max_iterations = 1;  // the innovations are computed at the end of the run
    const FinishReport r = LevenbergMarquardt(o).optimize(without, nullptr, candidates);
    const double dof = graph.dimension() == GraphDimension::k2D ? 3.0 : 6.0;
    const double variance_factor = r.final_chi2 / (dof * static_cast<double>(accepted));
    const double threshold =
        chiSquareQuantile(kOdometryConsistencyConfidence, dof) * std::min(1.0, variance_factor);
    for (std::size_t k = 0; k < candidates.size(); ++k) {
      const double innovation = r.innovation_chi2[k];
      predicted[index[k]] = innovation >= 0.0 && innovation <= threshold;
      *count += predicted[index[k]];
    }
    return predicted;
  }

  // Finishes `c` with the loop closures `predicted` marks counted in full, so they pull the map
  // out of the residual that kept their weight at ~0, then robustly again from there (each
  // weighed by its own residual once more); kept when the robust objective at the width of `c`
  // ends lower.  Returns whether it was kept.
  bool readmitPredicted(Candidate& c, const std::vector<char>& predicted) {
    const std::vector<char> none(predicted.size(), 0);
    Candidate gaussian{graphWithout(c.graph, none, &predicted), c.reason, {}, 0.0};
    finish(gaussian, options_.finish.max_iterations, c.width);
    Candidate trial{c.graph, c.reason, {}, 0.0};
    copyPoses(gaussian.graph, trial.graph);
    finish(trial, options_.finish.max_iterations, c.width);
    RobustOptions robust = options_.robust;
    robust.width = c.width;
    if (!(robustObjective(trial.graph, robust) < robustObjective(c.graph, robust))) return false;
    prependFinish(trial.finish, gaussian.finish);
    prependFinish(trial.finish, c.finish);
    trial.finish.initial_chi2 = c.finish.initial_chi2;
    trial.finish.initial_objective = c.finish.initial_objective;
    c = std::move(trial);
    return true;
  }

  // Adapts the kernel width to the accepted loop closures' residuals (RobustOptions::
  // adaptive_width_factor) and refines `c` with it, until the width changes by less than a factor
  // of kWidthSettled (at most kWidthRounds times); returns the width the result holds for.
  double adaptWidth(Candidate& c) {
    for (int round = 0; round < kWidthRounds; ++round) {
      const double adapted = settledWidth(c, options_.robust.width);
      if (!(adapted > 0.0) || (adapted > c.width / kWidthSettled && adapted < c.width * kWidthSettled)) break;
      finish(c, options_.finish.max_iterations, adapted);
      report_->width_rounds += 1;
    }
    return c.width;
  }

 private:
  const OptimizeOptions& options_;
  const Recorder& record_;
  OptimizeReport* report_;
  TreeOptimizerOptions robust_toro_;
  FinishOptions finish_;
};

}  // namespace

void optimizeRobustly(PoseGraph& graph, const OptimizeOptions& options, const Recorder& record,
                      OptimizeReport* report) {
  RobustRun run(options, record, report);
  const bool with_finish = options.mode == OptimizeMode::kToroThenFinish;
  const auto complete = [&](Candidate& c) {
    if (with_finish) {
      run.finish(c, options.finish.max_iterations);
    } else {
      c.objective = robustObjective(c.graph, options.robust);
    }
  };
  // The odometry-consistent start first: on a clean file it is the plain optimum however long the
  // loops.  Dead reckoning is needed only when some loop closure the odometry agreed with (or
  // could not judge) ended rejected: then wrong ones may have bent that start.
  std::vector<char> in_subset;
  std::vector<double> innovation;  // each loop closure's against the odometry
  Candidate first = run.fromConsistentLoopClosures(graph, &in_subset, &innovation);
  // Its residuals are near a plain optimum already: the width may narrow to them before the robust
  // finish (senders whose covariances are too large).
  // Only kCheckIterations at first: a start bent by wrong loop closures converges slowly (and pays
  // their fill-in every iteration), and a few iterations tell whether it is.
  // Its TORO map is not converged yet: the first iterations run with a kernel kStartWidthFactor
  // wider, so right loop closures still some way off keep their pull (a narrow kernel at once
  // leaves some of them behind in a local minimum: kitti_05, manhattan), then it narrows.
  if (with_finish) {
    run.finish(first, std::min(options.finish.max_iterations, kCheckIterations),
               kStartWidthFactor * options.robust.width);
    first.width = run.settledWidth(first, options.robust.width);
  } else {
    complete(first);
  }
  RobustOptions first_robust = options.robust;
  if (first.width > 0.0) first_robust.width = first.width;
  const std::vector<double> first_weights = robustWeights(first.graph, first_robust);
  bool contaminated = false;
  for (std::size_t c = 0; c < graph.numConstraints() && !contaminated; ++c)
    contaminated = in_subset[c] && isLoopClosure(graph.constraints()[c]) && first_weights[c] < kRejectedWeight;
  Candidate* best = &first;
  std::optional<Candidate> second, third;
  std::vector<char> held;  // by heldFromDeadReckoning, when the second start runs
  if (contaminated) {
    second = run.fromDeadReckoning(graph);
    if (with_finish) {
      // No wider than what the first start's residuals called for: a sender whose covariances are
      // far too large (parking-garage) makes wrong loop closures pull hard even at width 1.
      const double width = std::min({options.robust.width, kDeadReckoningWidth, first.width});
      held = heldFromDeadReckoning(graph, innovation, &report->dead_reckoning_held);
      if (report->dead_reckoning_held > 0)
        run.finishLeavingOut(*second, held, width);
      else
        run.finish(*second, options.finish.max_iterations, width);
    } else {
      complete(*second);
    }
    if (with_finish) {
      run.adaptWidth(first);
      run.adaptWidth(*second);
    }
    // Compared under one kernel, the configured one (an adapted width can be so narrow that
    // rejecting every loop closure looks cheapest).
    const RobustOptions& common = options.robust;
    first.objective = robustObjective(first.graph, common);
    second->objective = robustObjective(second->graph, common);
    if (second->objective < first.objective) best = &*second;
    // Start 3, when pairs held some: the first start's loop closures without the held ones.  Why:
    // from dead reckoning, a right loop closure that closes a long loop starts far off and, held
    // or not, may never gather weight (kitti_00 with 1000 random wrong ones: 15 of its 137 right
    // ones ended rejected, 4.0 m), while the first start took the wrong ones the odometry over long
    // spans could not refute.  Without them its long loops close and the rest are weighed on that
    // map (0.0001 m).
    if (with_finish && report->dead_reckoning_held > 0) {
      third = run.fromCorroboratedLoopClosures(graph, held);
      run.finishLeavingOut(*third, held, kStartWidthFactor * options.robust.width);
      run.adaptWidth(*third);
      third->objective = robustObjective(third->graph, common);
      // Kept only when it explains the measurements better at the narrowest width any start's
      // residuals called for, not at the configured one: a group of mutually consistent wrong
      // loop closures passes the pair test and bends this start, and where the declared
      // covariances are far too large (parking-garage) the configured width prices that bend
      // below the rejections of the other starts (100 grouped: 488 against 2,990 at width 10;
      // at 0.016, 230 against 6.1).
      RobustOptions narrow = common;
      narrow.width = std::min({first.width, second->width, third->width});
      if (robustObjective(third->graph, narrow) <
          std::min(robustObjective(first.graph, narrow), robustObjective(second->graph, narrow)))
        best = &*third;
    }
    for (const Candidate* c : {&first, &*second, third ? &*third : nullptr})
      if (c && c != best) report->candidate_finish_iterations += c->finish.iterations;
  }
  if (with_finish && best == &first) run.finishFurther(first);
  report->robust_width = with_finish ? run.adaptWidth(*best) : options.robust.width;
  // Right loop closures the kept map reached without pulling towards them stay rejected at any
  // width; those the map predicts are counted in full once, then weighed again.
  if (with_finish && second) {
    const std::vector<char> predicted =
        run.predictedRejected(graph, *best, in_subset, &report->predicted_rejected);
    if (report->predicted_rejected > 0) report->predicted_readmitted = run.readmitPredicted(*best, predicted);
  }
  report->toro_seconds = 0.0;  // the phases interleave; see the history
  if (with_finish) report->finish = best->finish;
  const bool kept_third = third && best == &*third;
  report->robust_start = best == &first ? RobustStart::kOdometryConsistent
                         : kept_third   ? RobustStart::kCorroborated
                                        : RobustStart::kDeadReckoning;
  std::ostringstream why;
  why << "kept the start from "
      << (best == &first ? "the odometry-consistent loop closures"
          : kept_third   ? "the odometry-consistent loop closures that nearby ones corroborate"
                         : "dead reckoning");
  if (best != &first && report->dead_reckoning_held > 0)
    why << " (its first finish without " << report->dead_reckoning_held
        << " loop closure(s) that the odometry refutes, nearby ones contradict or nothing near them "
           "corroborates)";
  if (second) {
    why << " (robust objective " << best->objective << "; the other start" << (third ? "s" : "") << ": ";
    const char* separator = "";
    for (const Candidate* c : {&first, &*second, third ? &*third : nullptr})
      if (c && c != best) {
        why << separator << c->objective;
        separator = ", ";
      }
    why << ")";
  } else {
    why << " (none of its loop closures rejected: dead reckoning was not needed)";
  }
  if (report->predicted_rejected > 0)
    why << "; " << report->predicted_rejected << " rejected loop closure(s) the map predicts "
        << (report->predicted_readmitted ? "counted in full once, then weighed again"
                                         : "tried in full and left (no lower robust cost)");
  why << "; its TORO phase: " << best->reason;
  report->switch_reason = why.str();
  copyPoses(best->graph, graph);
}

}  // namespace detail
}  // namespace toro
