// Internal: the pieces of optimizeGraph() shared by the plain driver (graph_optimizer.cpp) and the
// robust strategy (robust_optimizer.cpp).
#pragma once

#include <chrono>
#include <string>

#include "toro_ros/core/graph_optimizer.h"

namespace toro {
namespace detail {

using Clock = std::chrono::steady_clock;

inline double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Copies the poses of `source` (same node ids) into `target`.
inline void copyPoses(const PoseGraph& source, PoseGraph& target) {
  for (const Node& n : source.nodes()) target.setPose(n.id, n.pose);
}

// Appends one line to a report's history and passes it to the caller's callback (if any).
struct Recorder {
  OptimizeReport* report;
  const OptimizeCallback* callback;
  Clock::time_point start;
  void operator()(OptimizePhase phase, std::size_t iteration, double chi2, double lambda, bool accepted,
                  const PoseGraph* estimate) const {
    OptimizeIteration it{phase, iteration, chi2, lambda, accepted, secondsSince(start), estimate};
    report->history.push_back(it);
    if (callback != nullptr && *callback) (*callback)(it);
  }
};

// Runs TORO iterations on `toro` until the switch-over rule fires (on the robust objective when
// options.robust is enabled); returns the reason.
std::string runToroPhase(TreeOptimizer& toro, const OptimizeOptions& options, double objective,
                         const Recorder& record, OptimizeReport* report);

// The robust strategy of OptimizeOptions::robust with initial_guess kChainOdometry, modes kToro
// and kToroThenFinish (robust_optimizer.cpp).  Fills the report's phases; poses into `graph`.
void optimizeRobustly(PoseGraph& graph, const OptimizeOptions& options, const Recorder& record,
                      OptimizeReport* report);

}  // namespace detail
}  // namespace toro
