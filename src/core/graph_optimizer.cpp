#include "toro_ros/core/graph_optimizer.h"

#include "graph_optimizer_detail.h"

#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "toro_ros/core/metrics.h"
#include "toro_ros/core/planar.h"

namespace toro {

namespace detail {

std::string runToroPhase(TreeOptimizer& toro, const OptimizeOptions& options, double chi2,
                         const Recorder& record, OptimizeReport* report) {
  for (std::size_t k = 1; k <= options.toro_max_iterations; ++k) {
    const IterationStats stats = toro.iterate();
    const double next = robustObjective(toro.graph(), options.robust);
    ++report->toro_iterations;
    record(OptimizePhase::kToro, k, next, stats.learning_rate, true, &toro.graph());
    const double relative_decrease = chi2 > 0.0 ? (chi2 - next) / chi2 : 0.0;
    chi2 = next;
    if (k >= options.toro_min_iterations && options.switch_relative_decrease > 0.0 &&
        relative_decrease < options.switch_relative_decrease) {
      std::ostringstream s;
      s << "relative chi2 decrease " << relative_decrease << " < " << options.switch_relative_decrease
        << " after " << k << " iterations";
      return s.str();
    }
  }
  return "iteration budget of " + std::to_string(options.toro_max_iterations) + " reached";
}

}  // namespace detail

using detail::Recorder;
using detail::copyPoses;
using detail::secondsSince;
using detail::Clock;

const char* optimizeModeName(OptimizeMode mode) {
  switch (mode) {
    case OptimizeMode::kToro:
      return "toro";
    case OptimizeMode::kFinish:
      return "finish";
    case OptimizeMode::kToroThenFinish:
      return "toro+finish";
  }
  return "unknown";
}

bool parseOptimizeMode(const std::string& text, OptimizeMode* mode) {
  for (OptimizeMode m : {OptimizeMode::kToro, OptimizeMode::kFinish, OptimizeMode::kToroThenFinish}) {
    if (text == optimizeModeName(m)) {
      *mode = m;
      return true;
    }
  }
  return false;
}

const char* optimizePhaseName(OptimizePhase phase) {
  switch (phase) {
    case OptimizePhase::kStart:
      return "start";
    case OptimizePhase::kToro:
      return "toro";
    case OptimizePhase::kFinish:
      return "finish";
  }
  return "unknown";
}

std::string OptimizeOptions::validate() const {
  std::string out;
  auto add = [&out](const std::string& what) { out += (out.empty() ? "" : "; ") + what; };
  if (toro_min_iterations > toro_max_iterations)
    add("toro_min_iterations must not exceed toro_max_iterations");
  if (!(switch_relative_decrease >= 0.0) || !std::isfinite(switch_relative_decrease)) {
    add("switch_relative_decrease must be finite and >= 0");
  }
  const std::string toro_problem = toro.validate();
  if (!toro_problem.empty()) add("toro: " + toro_problem);
  const std::string finish_problem = finish.validate();
  if (!finish_problem.empty()) add("finish: " + finish_problem);
  return out;
}

OptimizeReport optimizeGraph(PoseGraph& graph, const OptimizeOptions& options,
                             const OptimizeCallback& callback) {
  const std::string problem = options.validate();
  if (!problem.empty()) throw std::invalid_argument("OptimizeOptions: " + problem);
  // A planar TORO phase on a 3D graph: the whole run (finish, metrics, result) is the projection's.
  if (options.toro.parameterization == Parameterization::kPlanar && graph.dimension() != GraphDimension::k2D)
    graph = projectToPlane(graph);
  FinishOptions finish_options = options.finish;
  finish_options.robust = options.robust;
  TreeOptimizerOptions toro_options = options.toro;
  toro_options.robust = options.robust;
  // Constructed first so that an unavailable linear solver is reported before any work.
  const LevenbergMarquardt finisher(finish_options);

  OptimizeReport report;
  const Clock::time_point start = Clock::now();
  const Recorder record{&report, &callback, start};

  const bool need_tree =
      options.mode != OptimizeMode::kFinish || options.initial_guess == InitialGuess::kChainOnTree;
  if (options.robust.enabled() && options.initial_guess == InitialGuess::kChainOdometry &&
      options.mode != OptimizeMode::kFinish && graph.numNodes() > 0) {
    detail::optimizeRobustly(graph, options, record, &report);
  } else if (need_tree && graph.numNodes() > 0) {
    TreeOptimizer toro(toro_options);
    toro.setGraph(graph, options.initial_guess);
    report.initial_chi2 = robustObjective(toro.graph(), options.robust);
    record(OptimizePhase::kStart, 0, report.initial_chi2, 0.0, true, &toro.graph());
    if (options.mode != OptimizeMode::kFinish) {
      report.switch_reason = detail::runToroPhase(toro, options, report.initial_chi2, record, &report);
    }
    copyPoses(toro.graph(), graph);
    report.toro_seconds = secondsSince(start);
  } else {
    report.initial_chi2 = robustObjective(graph, options.robust);
    record(OptimizePhase::kStart, 0, report.initial_chi2, 0.0, true, &graph);
  }

  if (options.mode != OptimizeMode::kToro && report.robust_start == RobustStart::kNone) {
    report.finish = finisher.optimize(graph, [&](const FinishIteration& it) {
      record(OptimizePhase::kFinish, it.iteration, it.chi2, it.lambda, it.accepted, nullptr);
    });
  }
  RobustOptions final_robust = options.robust;
  if (report.robust_width > 0.0) final_robust.width = report.robust_width;
  report.final_chi2 = robustObjective(graph, final_robust);
  report.seconds = secondsSince(start);
  report.weights = robustWeights(graph, final_robust);
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    if (!isLoopClosure(graph.constraints()[c])) continue;
    ++report.loop_closures;
    if (report.weights[c] < kRejectedWeight) ++report.rejected_loop_closures;
  }
  return report;
}

}  // namespace toro
