// Benchmark of robust loop closures (issue 10): each dataset with wrong loop closures added by
// toro::addOutliers (random, local, grouped; seeded), optimised by optimizeGraph with robust loop
// closures, against the clean file's optimum (non-robust, default settings).  Per case: position
// RMSE against the clean optimum after a rigid alignment, right loop closures rejected (final
// weight < 0.5), wrong ones accepted, wall and CPU time and their ratio to the clean solve (median
// of --runs).  Also --robust on the clean file: chi2 against the non-robust optimum.
// Writes Markdown to stdout.
//
//   bench_robust [--datasets DIR] [--only NAME[,NAME]] [--kinds random,local,grouped]
//                [--counts 100,500,1000] [--grouped-counts 100] [--kernel dcs] [--width W]
//                [--runs 3] [--seed S] [--guess odometry|chain] [--dump DIR [--dump-only]]
// --dump DIR writes every graph with outliers (and the clean optimum) to DIR; with --dump-only
// nothing else is solved (for bench/run_robust_offline.sh).
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bench_timing.h"
#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/outlier_generator.h"

namespace {

using Clock = std::chrono::steady_clock;
using namespace toro;

using toro_bench::cpuSeconds;
using toro_bench::median;

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

struct Settings {
  std::string datasets = TORO_DATASETS_DIR;
  std::vector<std::string> only;
  std::vector<std::string> kinds{"random", "local", "grouped"};
  std::vector<std::size_t> counts{100, 500, 1000};
  std::vector<std::size_t> grouped_counts{100};
  RobustOptions robust{RobustKernel::kDcs};  // the product defaults (width, adaptation)
  int runs = 3;
  std::uint32_t seed = 1;
  InitialGuess guess = InitialGuess::kChainOdometry;
  std::string dump;        // directory to write each graph with outliers to (empty: none)
  bool dump_only = false;  // --dump-only: write the graphs (and the clean optimum), solve nothing else
};

struct Timed {
  PoseGraph graph;
  OptimizeReport report;
  double wall = 0, cpu = 0;
};

Timed solve(const PoseGraph& input, const OptimizeOptions& options, int runs) {
  std::vector<double> walls, cpus;
  Timed out;
  for (int r = 0; r < runs; ++r) {
    PoseGraph g = input;
    const double c0 = cpuSeconds();
    const Clock::time_point t0 = Clock::now();
    OptimizeReport report = optimizeGraph(g, options);
    walls.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
    cpus.push_back(cpuSeconds() - c0);
    out.graph = std::move(g);
    out.report = std::move(report);
  }
  out.wall = median(walls);
  out.cpu = median(cpus);
  return out;
}

struct Dataset {
  const char* name;
  const char* file;
};

const Dataset kDatasets[] = {
    {"sphere2500", "sphere2500.g2o"},
    {"parking-garage", "parking-garage.g2o"},
    {"manhattan", "2d/manhattan.g2o"},
    {"intel", "2d/intel.g2o"},
    {"city10000", "2d/city10000.g2o"},
    {"CSAIL", "2d/CSAIL.g2o"},
    {"MIT", "2d/MIT.g2o"},
    {"intel-vertigo", "2d/intel_g2o-vertigo.g2o"},
    {"manhattanOlson3500", "2d/manhattanOlson3500.g2o"},
    {"kitti_00", "2d/kitti_00.g2o"},
    {"kitti_02", "2d/kitti_02.g2o"},
    {"kitti_05", "2d/kitti_05.g2o"},
    {"ais2klinik", "2d/ais2klinik.g2o"},
};

void runDataset(const Settings& s, const Dataset& d) {
  PoseGraph original;
  try {
    original = readGraph(s.datasets + "/" + d.file);
  } catch (const std::exception& e) {
    std::printf("| %s | (not read: %s) |\n", d.name, e.what());
    return;
  }
  OptimizeOptions plain;
  const Timed clean = solve(original, plain, s.runs);
  if (s.dump_only) {
    writeGraph(clean.graph, s.dump + "/" + d.name + "_optimum.g2o");
    writeGraph(original, s.dump + "/" + d.name + "_clean.g2o");
    for (const std::string& kind_name : s.kinds) {
      const OutlierKind kind = *outlierKindFromString(kind_name);
      for (std::size_t count : kind == OutlierKind::kGrouped ? s.grouped_counts : s.counts) {
        OutlierOptions o;
        o.kind = kind;
        o.count = count;
        o.seed = s.seed;
        writeGraph(addOutliers(original, o, &clean.graph).graph,
                   s.dump + "/" + d.name + "_" + kind_name + "_" + std::to_string(count) + ".g2o");
      }
    }
    std::printf("| %s | written to %s |\n", d.name, s.dump.c_str());
    return;
  }
  OptimizeOptions robust = plain;
  robust.robust = s.robust;
  robust.initial_guess = s.guess;
  const Timed clean_robust = solve(original, robust, s.runs);
  const double clean_chi2 = g2oChi2(clean.graph);
  const double robust_chi2 = g2oChi2(clean_robust.graph);
  std::size_t right = 0;
  for (const Constraint& c : original.constraints()) right += isLoopClosure(c) ? 1 : 0;
  std::size_t clean_rejected = 0;
  for (std::size_t c = 0; c < original.numConstraints(); ++c)
    if (isLoopClosure(original.constraints()[c]) && clean_robust.report.weights[c] < kRejectedWeight)
      ++clean_rejected;
  std::printf("| %s | clean | 0 | %.4g | %zu / %zu | - | %.3f (%.3f) | 1 | chi2 %.6g vs %.6g (%+.2e) |\n",
              d.name, alignedPositionRmse(clean_robust.graph, clean.graph), clean_rejected, right,
              clean_robust.wall, clean_robust.cpu, robust_chi2, clean_chi2,
              (robust_chi2 - clean_chi2) / clean_chi2);
  std::fflush(stdout);
  for (const std::string& kind_name : s.kinds) {
    const OutlierKind kind = *outlierKindFromString(kind_name);
    const std::vector<std::size_t>& counts = kind == OutlierKind::kGrouped ? s.grouped_counts : s.counts;
    for (std::size_t count : counts) {
      OutlierOptions o;
      o.kind = kind;
      o.count = count;
      o.seed = s.seed;
      const GraphWithOutliers bad = addOutliers(original, o, &clean.graph);
      if (!s.dump.empty()) {
        writeGraph(bad.graph, s.dump + "/" + d.name + "_" + kind_name + "_" + std::to_string(count) + ".g2o");
        writeGraph(clean.graph, s.dump + "/" + d.name + "_optimum.g2o");
      }
      const Timed result = solve(bad.graph, robust, s.runs);
      std::size_t rejected_right = 0, accepted_wrong = 0;
      for (std::size_t c = 0; c < original.numConstraints(); ++c)
        if (isLoopClosure(original.constraints()[c]) && result.report.weights[c] < kRejectedWeight)
          ++rejected_right;
      for (std::size_t c : bad.outliers)
        accepted_wrong += result.report.weights[c] >= kRejectedWeight ? 1 : 0;
      std::printf("| %s | %s | %zu | %.4g | %zu / %zu (%.2f %%) | %zu | %.3f (%.3f) | %.2f | %zu+%zu it |\n",
                  d.name, kind_name.c_str(), bad.outliers.size(),
                  alignedPositionRmse(result.graph, clean.graph), rejected_right, right,
                  right ? 100.0 * rejected_right / right : 0.0, accepted_wrong, result.wall, result.cpu,
                  result.wall / clean.wall, result.report.toro_iterations, result.report.finish.iterations);
      std::fflush(stdout);
    }
  }
}

int usage() {
  std::fprintf(
      stderr,
      "usage: bench_robust [--datasets DIR] [--only A,B] [--kinds random,local,grouped] [--counts 100,500]\n"
      "                    [--grouped-counts 100] [--kernel dcs|cauchy|huber] [--width W] [--runs N]\n"
      "                    [--seed S] [--guess odometry|chain] [--dump DIR [--dump-only]]\n");
  return 2;
}

int run(int argc, char** argv) {
  Settings s;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--dump-only") {
      s.dump_only = true;
      continue;
    }
    if (i + 1 >= argc) return usage();
    const std::string v = argv[++i];
    if (a == "--datasets")
      s.datasets = v;
    else if (a == "--only")
      s.only = split(v);
    else if (a == "--kinds")
      s.kinds = split(v);
    else if (a == "--counts" || a == "--grouped-counts") {
      std::vector<std::size_t> c;
      for (const std::string& x : split(v)) {
        char* end = nullptr;
        const unsigned long n = std::strtoul(x.c_str(), &end, 10);
        if (x.empty() || *end != '\0') throw std::invalid_argument(a + ": '" + x + "' is not a count");
        c.push_back(n);
      }
      (a == "--counts" ? s.counts : s.grouped_counts) = c;
    } else if (a == "--kernel") {
      const auto k = robustKernelFromString(v);
      if (!k) return usage();
      s.robust.kernel = *k;
    } else if (a == "--width")
      s.robust.width = std::stod(v);
    else if (a == "--runs")
      s.runs = std::stoi(v);
    else if (a == "--dump")
      s.dump = v;
    else if (a == "--seed")
      s.seed = static_cast<std::uint32_t>(std::stoul(v));
    else if (a == "--guess")
      s.guess = v == "chain" ? InitialGuess::kChainOnTree : InitialGuess::kChainOdometry;
    else
      return usage();
  }
  for (const std::string& k : s.kinds)
    if (!outlierKindFromString(k)) return usage();
  // The graphs are the point of --dump-only: make the directory rather than fail after the first solve.
  if (!s.dump.empty()) std::filesystem::create_directories(s.dump);
  setSolverThreads(kDefaultSolverThreads);  // as toro_optimize does (bench/finish_load_results.md)
  const BlasKernels blas = selectBlasKernels(/*may_switch=*/true);  // as toro_optimize does
  std::printf("kernel %s, width %g, seed %u, runs %d; %s\n\n", robustKernelName(s.robust.kernel),
              s.robust.width, s.seed, s.runs, blas.note.c_str());
  std::printf(
      "| dataset | outliers | count | RMSE vs clean optimum (m) | right rejected | wrong accepted | wall "
      "(cpu) s | x clean | note |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const Dataset& d : kDatasets) {
    if (!s.only.empty() && std::find(s.only.begin(), s.only.end(), d.name) == s.only.end()) continue;
    runDataset(s, d);
  }
  return 0;
}

}  // namespace

// Bad arguments (a count that is no number) and files that cannot be read or written end with the
// reason, not with an uncaught exception.
int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_robust: %s\n", e.what());
    return 1;
  }
}
