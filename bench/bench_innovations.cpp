// How well a graph's loop closures fit the chi-square model that the node's innovation test assumes
// (issues 10 and 14).  Per dataset: its optimum (optimizeGraph, default settings, every loop
// closure counted), then each loop closure's leave-one-out innovation chi2: the finish run on the
// graph without it, from that optimum, reports e^T (Sigma_z + J H^-1 J^T)^-1 e for it (the rise of
// the optimum's chi2 it brings), what LoopClosureSupport::releasePredicted compares with the 0.99
// chi-square quantile times the a-posteriori variance factor (chi2 / (dof x loop closures)).
// Divided by that factor, a right loop closure's innovation follows chi-square with dof degrees of
// freedom if its declared covariance has the right shape; the table says how far each file's
// loop closures are from that: the fraction above the 0.99 quantile (1 % for the model) and the
// empirical quantiles beside the model's.  Writes Markdown to stdout.
//
//   bench_innovations [--datasets DIR] [--only NAME[,NAME]] [--stride N] [--solver-threads N]
// --stride N: every N-th loop closure only (default 1: all; each costs a finish of the whole graph).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <sstream>
#include <string>
#include <vector>

#include "bench_timing.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"

namespace {

using Clock = std::chrono::steady_clock;
using namespace toro;

// Finish iterations of each leave-one-out solve: from the full optimum the graph without one loop
// closure is a small step away (the innovation is evaluated at the end of the run).
constexpr std::size_t kLeaveOneOutIterations = 3;

const char* const kDefaultDatasets[] = {
    "2d/intel.g2o",     "2d/MIT.g2o",         "2d/CSAIL.g2o",     "2d/kitti_00.g2o",
    "2d/kitti_02.g2o",  "2d/kitti_05.g2o",    "2d/manhattan.g2o", "2d/manhattanOlson3500.g2o",
    "2d/city10000.g2o", "parking-garage.g2o", "sphere2500.g2o",
};

double quantile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const double x = p * static_cast<double>(v.size() - 1);
  const std::size_t i = static_cast<std::size_t>(std::floor(x));
  const std::size_t j = std::min(i + 1, v.size() - 1);
  return v[i] + (x - static_cast<double>(i)) * (v[j] - v[i]);
}

void runDataset(const std::string& dir, const std::string& file, std::size_t stride) {
  const Clock::time_point start = Clock::now();
  const double cpu_start = toro_bench::cpuSeconds();
  PoseGraph graph = readGraph(dir + "/" + file);
  optimizeGraph(graph, OptimizeOptions{});
  const double chi2 = g2oChi2(graph);
  std::vector<std::size_t> loop_closures;
  for (std::size_t c = 0; c < graph.numConstraints(); ++c)
    if (isLoopClosure(graph.constraints()[c])) loop_closures.push_back(c);
  const double dof = graph.dimension() == GraphDimension::k2D ? 3.0 : 6.0;
  if (loop_closures.empty()) {
    std::printf("| %s | no loop closure |\n", file.c_str());
    return;
  }
  const double variance_factor = chi2 / (dof * static_cast<double>(loop_closures.size()));
  FinishOptions options;
  options.max_iterations = kLeaveOneOutIterations;
  const LevenbergMarquardt finish(options);
  std::vector<double> normalised;
  for (std::size_t k = 0; k < loop_closures.size(); k += stride) {
    PoseGraph rest = keepConstraints(graph, [&](std::size_t c) { return c != loop_closures[k]; });
    const FinishReport r = finish.optimize(rest, {}, {graph.constraints()[loop_closures[k]]});
    if (r.innovation_chi2.empty() || !(r.innovation_chi2[0] >= 0.0)) continue;
    normalised.push_back(r.innovation_chi2[0] / variance_factor);
  }
  const double q99 = chiSquareQuantile(0.99, dof);
  const double above = static_cast<double>(
      std::count_if(normalised.begin(), normalised.end(), [&](double x) { return x > q99; }));
  double mean = 0.0;
  for (double x : normalised) mean += x;
  mean /= std::max<std::size_t>(1, normalised.size());
  std::printf(
      "| %s | %zu / %zu | %.4g | %.2f (%g) | %.1f %% | %.1f (%.1f) | %.1f (%.1f) | %.1f (%.1f) | %.1f | %.1f "
      "/ %.1f |\n",
      file.c_str(), normalised.size(), loop_closures.size(), variance_factor, mean, dof,
      100.0 * above / std::max<std::size_t>(1, normalised.size()), quantile(normalised, 0.9),
      chiSquareQuantile(0.9, dof), quantile(normalised, 0.99), q99, quantile(normalised, 0.999),
      chiSquareQuantile(0.999, dof),
      normalised.empty() ? 0.0 : *std::max_element(normalised.begin(), normalised.end()),
      std::chrono::duration<double>(Clock::now() - start).count(), toro_bench::cpuSeconds() - cpu_start);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  std::string dir = "../shared/datasets";
  std::vector<std::string> only;
  std::size_t stride = 1;
  int threads = 1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const char* v = i + 1 < argc ? argv[i + 1] : nullptr;
    if (a == "--datasets" && v) {
      dir = v;
      ++i;
    } else if (a == "--only" && v) {
      std::stringstream names(v);
      for (std::string n; std::getline(names, n, ',');) only.push_back(n);
      ++i;
    } else if (a == "--stride" && v && std::atoi(v) > 0) {
      stride = static_cast<std::size_t>(std::atoi(v));
      ++i;
    } else if (a == "--solver-threads" && v && std::atoi(v) >= 0) {
      threads = std::atoi(v);
      ++i;
    } else {
      std::fprintf(stderr,
                   "usage: bench_innovations [--datasets DIR] [--only NAME[,NAME]] [--stride N] "
                   "[--solver-threads N]\n");
      return 2;
    }
  }
  if (threads > 0) setSolverThreads(threads);
  std::printf(
      "| dataset | loop closures tested / all | variance factor | mean innovation / factor (dof) | above the "
      "0.99 "
      "quantile | 0.9 quantile (model) | 0.99 quantile (model) | 0.999 quantile (model) | largest | wall / "
      "CPU s |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const char* file : kDefaultDatasets) {
    const std::string f = file;
    const std::string name = f.substr(f.find_last_of('/') + 1, f.rfind('.') - f.find_last_of('/') - 1);
    if (!only.empty() && std::find(only.begin(), only.end(), name) == only.end()) continue;
    try {
      runDataset(dir, f, stride);
    } catch (const std::exception& e) {
      std::printf("| %s | skipped: %s |\n", file, e.what());
    }
  }
  return 0;
}
