// Shared datasets with wrong loop closures from bench_robust's generator, solved as
// `toro_optimize --robust` solves them and compared with the clean file's optimum: the batch
// robust tests of test_robust.cpp and test_pairwise_consistency.cpp.
#pragma once

#include <cstdint>
#include <string>

#include "shared_datasets.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/outlier_generator.h"
#include "toro_ros/core/robust_kernel.h"
#include "toro_ros/core/sparse_finisher.h"

namespace toro_test {

// `graph` with wrong loop closures from bench_robust's generator (grouped ones moved along `clean`).
inline toro::GraphWithOutliers withOutliers(const toro::PoseGraph& graph, const toro::PoseGraph& clean,
                                            toro::OutlierKind kind, std::size_t count, std::uint32_t seed,
                                            std::size_t group_size = 10) {
  toro::OutlierOptions oo;
  oo.kind = kind;
  oo.count = count;
  oo.seed = seed;
  oo.group_size = group_size;
  return toro::addOutliers(graph, oo, &clean);
}

// optimizeGraph as `toro_optimize --robust` runs it: DCS at the default width, from the odometry.
inline toro::OptimizeOptions robustOptions() {
  toro::OptimizeOptions o;
  o.robust = toro::RobustOptions{toro::RobustKernel::kDcs, toro::kDefaultRobustWidth};
  o.initial_guess = toro::InitialGuess::kChainOdometry;
  return o;
}

struct SolvedWithOutliers {
  toro::PoseGraph result;
  toro::OptimizeReport report;
  double rmse_to_clean = 0.0;
  std::size_t wrong_accepted = 0, right_rejected = 0;
};

// `file` (under the shared datasets) with `count` wrong loop closures of `kind` (seed 1), solved by
// robustOptions(): the result, its report, its RMSE to the clean optimum after a rigid alignment,
// the wrong ones accepted and the right ones rejected (weight against kRejectedWeight).
inline SolvedWithOutliers solveWithOutliers(const std::string& file, toro::OutlierKind kind,
                                            std::size_t count) {
  // As the programs do: with the libraries' own thread counts the finish waits for its threads
  // whenever the machine is busy (28 s instead of 0.7 s beside a build).
  toro::setSolverThreads(toro::kDefaultSolverThreads);
  const toro::PoseGraph original = toro::readGraph(datasetPath(file));
  toro::PoseGraph clean = original;
  toro::optimizeGraph(clean, toro::OptimizeOptions{});
  const toro::GraphWithOutliers bad = withOutliers(original, clean, kind, count, 1);
  SolvedWithOutliers s{bad.graph, {}, 0.0, 0, 0};
  s.report = toro::optimizeGraph(s.result, robustOptions());
  s.rmse_to_clean = toro::alignedPositionRmse(s.result, clean);
  for (std::size_t c : bad.outliers) s.wrong_accepted += s.report.weights[c] >= toro::kRejectedWeight;
  for (std::size_t c = 0; c < original.numConstraints(); ++c)
    s.right_rejected +=
        toro::isLoopClosure(original.constraints()[c]) && s.report.weights[c] < toro::kRejectedWeight;
  return s;
}

}  // namespace toro_test
