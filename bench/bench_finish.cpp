// Benchmark of the sparse finish and of TORO-then-finish (issue 3).  Per case: median of N runs
// of optimizeGraph() (file reading outside the timed region, reported separately), wall and CPU
// time, iterations of both phases, final g2o chi2 and its relative difference to the best known
// value of REFERENCE.md (B).  Then a comparison of the sparse Cholesky back ends on the finish
// alone.  Writes Markdown to stdout.
//
//   bench_finish [--datasets DIR] [--runs 5] [--only NAME] [--solver-threads N] [--planar-comparison 1]
// --solver-threads: as toro_optimize (default 1: setSolverThreads(1); 0: runtime defaults).
// --planar-comparison 1: instead of the cases above, every 2D file with a best known chi2 through
// TORO-then-finish twice, with TORO in SE(2) (the default for 2D files) and with the 3D code
// (issue 11: same chi2 after the finish).
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "bench_timing.h"
#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"

namespace {

using Clock = std::chrono::steady_clock;
using namespace toro;

using toro_bench::cpuSeconds;
using toro_bench::median;

struct Case {
  const char* file;
  OptimizeMode mode;
  InitialGuess guess;
  double reference;       // REFERENCE.md (B)
  double tolerance;       // relative
  double target_seconds;  // 0: none
  LinearSolverType solver = LinearSolverType::kCholmodSupernodal;
  Parameterization toro_group = Parameterization::kFromGraph;
};

struct Outcome {
  double wall = 0, cpu = 0, read = 0, chi2 = 0, factorization = 0;
  std::size_t toro_iterations = 0, finish_iterations = 0;
};

Outcome runCase(const std::string& dir, const Case& c, int runs) {
  const Clock::time_point read_start = Clock::now();
  const PoseGraph original = readGraph(dir + "/" + c.file);
  Outcome out;
  out.read = std::chrono::duration<double>(Clock::now() - read_start).count();
  OptimizeOptions options;
  options.mode = c.mode;
  options.initial_guess = c.guess;
  options.finish.linear_solver = c.solver;
  options.toro.parameterization = c.toro_group;
  std::vector<double> wall, cpu, factorization;
  for (int r = 0; r < runs; ++r) {
    PoseGraph g = original;
    const double cpu_start = cpuSeconds();
    const Clock::time_point start = Clock::now();
    const OptimizeReport report = optimizeGraph(g, options);
    wall.push_back(std::chrono::duration<double>(Clock::now() - start).count());
    cpu.push_back(cpuSeconds() - cpu_start);
    factorization.push_back(
        report.finish.iterations ? report.finish.factorization_seconds / report.finish.iterations : 0.0);
    out.chi2 = report.final_chi2;
    out.toro_iterations = report.toro_iterations;
    out.finish_iterations = report.finish.iterations;
  }
  out.wall = median(wall);
  out.cpu = median(cpu);
  out.factorization = median(factorization);
  return out;
}

const char* guessName(InitialGuess g) { return g == InitialGuess::kChainOnTree ? "chained" : "file"; }

void printRow(const Case& c, const Outcome& o) {
  const double rel = std::abs(o.chi2 - c.reference) / c.reference;
  const bool ok_value = rel <= c.tolerance;
  const bool ok_time = c.target_seconds <= 0.0 || o.wall <= c.target_seconds;
  std::printf("| %s | %s | %s | %s | %s | %zu | %zu | %.3f | %.3f | %.4f | %.4f | %.10g | %.1e %s | %s |\n",
              c.file, optimizeModeName(c.mode), guessName(c.guess), parameterizationName(c.toro_group),
              linearSolverName(c.solver), o.toro_iterations, o.finish_iterations, o.wall, o.cpu,
              o.factorization, o.read, o.chi2, rel, ok_value ? "ok" : "MISSED",
              c.target_seconds > 0 ? (ok_time ? "ok" : "over") : "-");
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  std::string dir = TORO_DATASETS_DIR;
  int runs = 5;
  std::string only;
  int solver_threads = kDefaultSolverThreads;
  bool planar_comparison = false;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--datasets")
      dir = argv[i + 1];
    else if (key == "--runs")
      runs = std::max(1, std::atoi(argv[i + 1]));
    else if (key == "--only")
      only = argv[i + 1];
    else if (key == "--solver-threads")
      solver_threads = std::atoi(argv[i + 1]);
    else if (key == "--planar-comparison")
      planar_comparison = std::atoi(argv[i + 1]) != 0;
    else {
      std::fprintf(stderr, "unknown option %s\n", key.c_str());
      return 2;
    }
  }
  const auto kToroFinish = OptimizeMode::kToroThenFinish;
  const auto kFinish = OptimizeMode::kFinish;
  const auto kChain = InitialGuess::kChainOnTree;
  const auto kFile = InitialGuess::kFromGraph;
  std::vector<Case> cases = {
      {"sphere2500.g2o", kToroFinish, kChain, 727.150, 1e-4, 0.3},
      {"sphere2500.g2o", kFinish, kFile, 727.150, 1e-4, 0.3},
      {"parking-garage.g2o", kToroFinish, kChain, 1.23869, 1e-4, 0.12},
      {"parking-garage.g2o", kFinish, kFile, 1.23869, 1e-4, 0.12},
      {"sphere_bignoise_vertex3.g2o", kFinish, kFile, 743862.7, 1e-3, 0.0},
      {"sphere_bignoise_vertex3.g2o", kToroFinish, kChain, 743862.7, 1e-3, 0.0},
      {"2d/MIT.g2o", kToroFinish, kChain, 41.1633, 1e-4, 0.0},
      {"2d/intel.g2o", kToroFinish, kChain, 45.0047, 1e-4, 0.0},
      {"2d/manhattanOlson3500.g2o", kToroFinish, kChain, 146.077, 1e-4, 0.0},
  };
  for (LinearSolverType s : {LinearSolverType::kCholmodSimplicial, LinearSolverType::kSimplicialLDLT}) {
    cases.push_back({"sphere2500.g2o", kFinish, kFile, 727.150, 1e-4, 0.3, s});
    cases.push_back({"parking-garage.g2o", kFinish, kFile, 1.23869, 1e-4, 0.12, s});
  }
  if (planar_comparison) {
    // REFERENCE.md (B), best known chi2 of every 2D file; the tolerance of the cases above.
    const std::vector<std::pair<const char*, double>> planar_files = {{"2d/CSAIL.g2o", 40.5551},
                                                                      {"2d/MIT.g2o", 41.1633},
                                                                      {"2d/ais2klinik.g2o", 172.816},
                                                                      {"2d/city10000.g2o", 511.985},
                                                                      {"2d/intel.g2o", 45.0047},
                                                                      {"2d/intel_g2o-vertigo.g2o", 546.461},
                                                                      {"2d/kitti_00.g2o", 98.322},
                                                                      {"2d/kitti_02.g2o", 78.7643},
                                                                      {"2d/kitti_05.g2o", 157.104},
                                                                      {"2d/manhattan.g2o", 3549.04},
                                                                      {"2d/manhattanOlson3500.g2o", 146.077}};
    cases.clear();
    for (const auto& [file, reference] : planar_files) {
      for (Parameterization group : {Parameterization::kPlanar, Parameterization::kSpatial}) {
        cases.push_back(
            {file, kToroFinish, kChain, reference, 1e-4, 0.0, LinearSolverType::kCholmodSupernodal, group});
      }
    }
  }
  std::string threads = "runtime defaults";
  if (solver_threads > 0) {
    const SolverThreadSettings set = setSolverThreads(solver_threads);
    threads = "setSolverThreads(" + std::to_string(solver_threads) + "): OpenBLAS " +
              (set.openblas_set ? "set" : "not loaded") + ", OpenMP " + (set.openmp_set ? "set" : "not loaded");
  }
  // As toro_optimize (OPENBLAS_CORETYPE in the environment keeps the library's or the user's choice).
  const BlasKernels blas = selectBlasKernels(/*may_switch=*/true);
  std::printf("runs per case: %d (median); solver threads: %s; OPENBLAS_NUM_THREADS=%s; %s\n\n", runs,
              threads.c_str(),
              std::getenv("OPENBLAS_NUM_THREADS") ? std::getenv("OPENBLAS_NUM_THREADS") : "(unset)",
              blas.note.c_str());
  std::printf(
      "| file | mode | start | TORO group | linear solver | TORO it. | finish it. | wall s | CPU s | "
      "factorise+solve s/it. | read s | final chi2 | rel. diff | time target |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (const Case& c : cases) {
    if (!only.empty() && only != c.file) continue;
    const bool slow = std::string(c.file).find("bignoise") != std::string::npos;
    printRow(c, runCase(dir, c, slow ? std::min(runs, 1) : runs));
  }
  return 0;
}
