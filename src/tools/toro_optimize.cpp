// toro_optimize: optimise a pose-graph file (g2o or TORO, 2D or 3D) with TORO and report the
// error measures of ../shared/datasets/REFERENCE.md before, during and after.
//
// Structure: parseArguments() fills CliOptions; optimise() reads the graph and runs
// toro::optimizeGraph() (the core's TORO-then-finish driver, the same code the node runs), whose
// per-iteration callback prints one line per iteration of either phase; then it prints the
// summary and writes the output.  Every failure is an exception caught in run(): one line on
// stderr, non-zero exit.
#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <unistd.h>

#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/planar.h"
#include "toro_ros/core/tree_optimizer.h"

namespace {

constexpr const char* kProgram = "toro_optimize";
constexpr int kExitBadInput = 1;
constexpr int kExitBadArguments = 2;

constexpr const char* kUsage =
    "usage: toro_optimize [options] INPUT\n"
    "Optimises a pose graph with TORO (tree parameterisation + stochastic gradient descent; in SE(3),\n"
    "or in SE(2) for 2D files and with --planar),\n"
    "then by default with a sparse Levenberg-Marquardt finish on the g2o chi2.\n"
    "INPUT: g2o (VERTEX_SE3:QUAT/EDGE_SE3:QUAT, VERTEX_SE2/EDGE_SE2) or TORO (VERTEX3/EDGE3,\n"
    "VERTEX2/EDGE2); format by extension (.g2o, .graph), otherwise by the first data line.\n"
    "options:\n"
    "  -i N                      TORO iterations at most (default 100); in --mode toro exactly N\n"
    "                            (0 there only measures / converts)\n"
    "  --mode toro|finish|toro+finish\n"
    "                            TORO only, the finish only (from the initial guess), or TORO until\n"
    "                            the switch-over rule fires and then the finish (default toro+finish)\n"
    "  --switch-decrease R       end the TORO phase once an iteration lowers the g2o chi2 by less\n"
    "                            than the fraction R (default 0.2; 0: always run -i iterations)\n"
    "  --finish-iterations N     finish iterations at most (default 100)\n"
    "  --finish-tolerance R      stop the finish when a step lowers chi2 by less than the fraction R\n"
    "                            (default 1e-7)\n"
    "  --linear-solver cholmod-supernodal|cholmod-simplicial|eigen-ldlt\n"
    "                            sparse Cholesky of the finish (default cholmod-supernodal)\n"
    "  --solver-threads N        threads of the finish's linear algebra: OpenBLAS and OpenMP (CHOLMOD's\n"
    "                            loops) get at most N (default 1: measured fastest beside other work\n"
    "                            on a 2-core machine, bench/finish_load_results.md; 0 leaves the\n"
    "                            libraries' own settings and the OMP_* / OPENBLAS_* variables)\n"
    "  -o OUTPUT                 write the result; format by extension (.graph/.toro: TORO, else g2o)\n"
    "  --initial-guess chain|odometry|file\n"
    "                            chain the measurements along the tree (default without --robust),\n"
    "                            chain the odometry (consecutive ids) and reach the rest through\n"
    "                            loop closures (default with --robust), or keep the file's poses\n"
    "                            (files without VERTEX lines always chain)\n"
    "  --robust                  robust loop closures (constraints between non-consecutive ids) in\n"
    "                            both phases: each one's information is scaled by a weight from its\n"
    "                            residual, so wrong ones cannot bend the map (off by default: on a\n"
    "                            clean file the result is then the plain maximum-likelihood optimum)\n"
    "  --robust-kernel dcs|cauchy|huber\n"
    "                            the weight function (default dcs: Dynamic Covariance Scaling);\n"
    "                            implies --robust\n"
    "  --robust-width W          the kernel's width phi in chi2 units (default 10; narrowed to the\n"
    "                            residuals found: 10x the 99th percentile of the accepted loop\n"
    "                            closures' chi2); implies --robust\n"
    "  --rejected-out FILE       write the loop closures whose final weight is below 0.5, one\n"
    "                            'from to' pair a line (needs --robust)\n"
    "  --planar                  optimise in the plane (TORO in SE(2), the finish on x, y, theta);\n"
    "                            a 3D input is projected first: z, roll and pitch are dropped, and\n"
    "                            of its information only the x, y, yaw block is kept; the result is a\n"
    "                            2D graph (-o writes 2D tags).  The default for 2D files\n"
    "  --no-planar               TORO's 3D code even on a 2D file (to compare; the file stays 2D and\n"
    "                            its finish planar)\n"
    "  --gamma G                 rotational learning rate of iteration k is 1/(G k) (default 1 for\n"
    "                            --mode toro, 0.1 before the finish: larger steps find the best\n"
    "                            basin on big-noise graphs;\n"
    "                            the translational rate has its own constant, tree_optimizer.h)\n"
    "  --toro-info-order translation-first|rotation-first\n"
    "                            order of the EDGE3 information matrix, for reading and writing\n"
    "                            (default translation-first, as g2o and HOG-Man read it)\n"
    "  -q                        quiet: only the final summary (no per-iteration metrics)\n"
    "  --help                    this text\n"
    "Per-iteration lines: phase, iteration, optimisation seconds so far (metric time excluded),\n"
    "g2o chi2, SE-Sync objective, largest rotational (rad) and translational residual; finish\n"
    "lines give the g2o chi2 and the damping lambda (SE-Sync and residuals only at the end).\n";

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CliOptions {
  std::string input;
  std::string output;
  std::size_t iterations = 100;
  toro::OptimizeMode mode = toro::OptimizeMode::kToroThenFinish;
  double switch_decrease = toro::OptimizeOptions{}.switch_relative_decrease;
  std::size_t finish_iterations = toro::FinishOptions{}.max_iterations;
  double finish_tolerance = toro::FinishOptions{}.relative_decrease_tolerance;
  toro::LinearSolverType linear_solver = toro::FinishOptions{}.linear_solver;
  std::size_t solver_threads = toro::kDefaultSolverThreads;
  bool chain_guess = true;
  bool odometry_guess = false;   // --initial-guess odometry (the default with --robust)
  bool guess_given = false;
  toro::RobustOptions robust;    // kernel kNone: off
  std::string rejected_out;
  std::optional<double> gamma;  // unset: the mode's default
  // --planar / --no-planar; kFromGraph (neither): SE(2) for 2D files.
  toro::Parameterization parameterization = toro::Parameterization::kFromGraph;
  toro::ToroInformationOrder toro_order = toro::ToroInformationOrder::kTranslationFirst;
  bool quiet = false;
  bool help = false;
};

std::size_t parseCount(const std::string& flag, const std::string& text) {
  std::size_t value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size()) {
    throw UsageError(flag + " needs a non-negative integer, got '" + text + "'");
  }
  return value;
}

double parsePositive(const std::string& flag, const std::string& text) {
  double value = 0.0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(value) || value <= 0.0) {
    throw UsageError(flag + " needs a positive number, got '" + text + "'");
  }
  return value;
}

double parseNonNegative(const std::string& flag, const std::string& text) {
  double value = 0.0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(value) || value < 0.0) {
    throw UsageError(flag + " needs a non-negative number, got '" + text + "'");
  }
  return value;
}

toro::LinearSolverType parseLinearSolver(const std::string& text) {
  for (auto type : {toro::LinearSolverType::kCholmodSupernodal, toro::LinearSolverType::kCholmodSimplicial,
                    toro::LinearSolverType::kSimplicialLDLT}) {
    if (text == toro::linearSolverName(type)) return type;
  }
  throw UsageError("--linear-solver must be cholmod-supernodal, cholmod-simplicial or eigen-ldlt, got '" +
                   text + "'");
}

CliOptions parseArguments(const std::vector<std::string>& args) {
  CliOptions o;
  for (std::size_t k = 0; k < args.size(); ++k) {
    const std::string& a = args[k];
    const auto value = [&]() -> const std::string& {
      if (k + 1 >= args.size()) throw UsageError(a + " needs a value");
      return args[++k];
    };
    if (a == "--help" || a == "-h") {
      o.help = true;
    } else if (a == "-q") {
      o.quiet = true;
    } else if (a == "-i") {
      o.iterations = parseCount(a, value());
    } else if (a == "-o") {
      o.output = value();
    } else if (a == "--mode") {
      const std::string& v = value();
      if (!toro::parseOptimizeMode(v, &o.mode)) {
        throw UsageError("--mode must be toro, finish or toro+finish, got '" + v + "'");
      }
    } else if (a == "--switch-decrease") {
      o.switch_decrease = parseNonNegative(a, value());
    } else if (a == "--finish-iterations") {
      o.finish_iterations = parseCount(a, value());
    } else if (a == "--finish-tolerance") {
      o.finish_tolerance = parseNonNegative(a, value());
    } else if (a == "--linear-solver") {
      o.linear_solver = parseLinearSolver(value());
    } else if (a == "--solver-threads") {
      o.solver_threads = parseCount(a, value());
      if (o.solver_threads > toro::kMaxSolverThreads)
        throw UsageError(a + " needs at most " + std::to_string(toro::kMaxSolverThreads) + ", got " + std::to_string(o.solver_threads));
    } else if (a == "--gamma") {
      o.gamma = parsePositive(a, value());
    } else if (a == "--initial-guess") {
      const std::string& v = value();
      if (v != "chain" && v != "file" && v != "odometry")
        throw UsageError("--initial-guess must be chain, odometry or file, got '" + v + "'");
      o.chain_guess = v != "file";
      o.odometry_guess = v == "odometry";
      o.guess_given = true;
    } else if (a == "--robust") {
      if (!o.robust.enabled()) o.robust.kernel = toro::RobustKernel::kDcs;
    } else if (a == "--robust-kernel") {
      const std::string& v = value();
      const auto kernel = toro::robustKernelFromString(v);
      if (!kernel || *kernel == toro::RobustKernel::kNone)
        throw UsageError("--robust-kernel must be dcs, cauchy or huber, got '" + v + "'");
      o.robust.kernel = *kernel;
    } else if (a == "--robust-width") {
      o.robust.width = parsePositive(a, value());
      if (!o.robust.enabled()) o.robust.kernel = toro::RobustKernel::kDcs;
    } else if (a == "--planar" || a == "--no-planar") {
      const auto p = a == "--planar" ? toro::Parameterization::kPlanar : toro::Parameterization::kSpatial;
      if (o.parameterization != toro::Parameterization::kFromGraph && o.parameterization != p)
        throw UsageError("--planar and --no-planar exclude each other");
      o.parameterization = p;
    } else if (a == "--rejected-out") {
      o.rejected_out = value();
    } else if (a == "--toro-info-order") {
      const std::string& v = value();
      if (v != "translation-first" && v != "rotation-first") {
        throw UsageError("--toro-info-order must be translation-first or rotation-first, got '" + v + "'");
      }
      o.toro_order = v == "translation-first" ? toro::ToroInformationOrder::kTranslationFirst
                                              : toro::ToroInformationOrder::kRotationFirst;
    } else if (a.size() > 1 && a[0] == '-') {
      throw UsageError("unknown option '" + a + "'");
    } else if (o.input.empty()) {
      o.input = a;
    } else {
      throw UsageError("more than one input file ('" + o.input + "' and '" + a + "')");
    }
  }
  if (!o.help && o.input.empty()) throw UsageError("no input file");
  if (!o.rejected_out.empty() && !o.robust.enabled()) throw UsageError("--rejected-out needs --robust");
  if (o.robust.enabled() && !o.guess_given) o.odometry_guess = true;
  return o;
}

// Fails before a long optimisation rather than after it when the result cannot be written.
void checkOutputDirectory(const std::string& output) {
  if (output.empty()) return;
  std::filesystem::path dir = std::filesystem::path(output).parent_path();
  if (dir.empty()) dir = ".";
  if (!std::filesystem::is_directory(dir) || ::access(dir.c_str(), W_OK) != 0) {
    throw std::runtime_error("cannot write '" + output + "': directory '" + dir.string() +
                             "' does not exist or is not writable");
  }
}

// ---- measuring -------------------------------------------------------------------------------

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

struct Measures {
  double chi2 = 0.0;
  double se_sync = 0.0;
  toro::ToroError toro;
};

Measures measure(const toro::PoseGraph& graph) {
  return Measures{toro::g2oChi2(graph), toro::seSyncObjective(graph), toro::toroError(graph)};
}

// Time is split so that the optimisation time reported is the optimiser's alone.
struct RunLog {
  double setup_seconds = 0.0;
  double optimise_seconds = 0.0;
  double measure_seconds = 0.0;
  std::size_t iterations = 0;
};

void printHeader() {
  std::printf("%-6s %6s %10s %14s %14s %13s %13s\n", "phase", "iter", "time[s]", "g2o chi2", "SE-Sync",
              "max rot[rad]", "max trans");
}

void printLine(const char* phase, std::size_t iteration, double seconds, const Measures& m) {
  std::printf("%-6s %6zu %10.6f %14.8g %14.8g %13.6g %13.6g\n", phase, iteration, seconds, m.chi2, m.se_sync,
              m.toro.max_rotation, m.toro.max_translation);
  std::fflush(stdout);
}

// The finish's state lives inside the solver, so its lines carry chi2 and the damping only.
void printFinishLine(const toro::OptimizeIteration& it, double seconds) {
  std::printf("%-6s %6zu %10.6f %14.8g %14s %13s %13s  lambda %.3g%s\n", "finish", it.iteration, seconds,
              it.chi2, "-", "-", "-", it.lambda, it.accepted ? "" : " (step rejected)");
  std::fflush(stdout);
}

toro::OptimizeOptions optimizeOptions(const CliOptions& o) {
  toro::OptimizeOptions options;
  options.mode = o.mode;
  options.initial_guess = !o.chain_guess    ? toro::InitialGuess::kFromGraph
                          : o.odometry_guess ? toro::InitialGuess::kChainOdometry
                                             : toro::InitialGuess::kChainOnTree;
  options.robust = o.robust;
  // Without --gamma: TORO's own default alone, the basin-finding one before the finish.
  options.toro.gamma = o.gamma ? *o.gamma
                               : (o.mode == toro::OptimizeMode::kToro ? toro::TreeOptimizerOptions{}.gamma
                                                                      : toro::kToroGammaBeforeFinish);
  options.toro.parameterization = o.parameterization;
  options.toro_max_iterations = o.iterations;
  options.toro_min_iterations = std::min(options.toro_min_iterations, o.iterations);
  // TORO alone runs exactly -i iterations, as it always did.
  options.switch_relative_decrease = o.mode == toro::OptimizeMode::kToro ? 0.0 : o.switch_decrease;
  options.finish.max_iterations = o.finish_iterations;
  options.finish.relative_decrease_tolerance = o.finish_tolerance;
  options.finish.linear_solver = o.linear_solver;
  const std::string invalid = options.validate();
  if (!invalid.empty()) throw UsageError(invalid);
  if (o.mode != toro::OptimizeMode::kToro && o.linear_solver != toro::LinearSolverType::kSimplicialLDLT &&
      !toro::cholmodAvailable()) {
    throw UsageError(std::string("--linear-solver ") + toro::linearSolverName(o.linear_solver) +
                     " is not built in");
  }
  return options;
}

// ---- the run ---------------------------------------------------------------------------------

void printMeasures(const char* label, const Measures& m) {
  std::printf(
      "  %-7s g2o chi2 %.10g   SE-Sync %.10g   TORO error %.6g   max rotation %.6g rad   "
      "max translation %.6g\n",
      label, m.chi2, m.se_sync, m.toro.sum, m.toro.max_rotation, m.toro.max_translation);
}

// The group TORO runs in, as TreeOptimizer decides it (Parameterization).
const char* groupName(toro::Parameterization p, const toro::PoseGraph& graph) {
  const bool planar =
      p == toro::Parameterization::kPlanar ||
      (p == toro::Parameterization::kFromGraph && graph.dimension() == toro::GraphDimension::k2D);
  return planar ? "planar (TORO in SE(2))" : "TORO in SE(3)";
}

void printSummary(const CliOptions& o, const toro::PoseGraph& graph, const Measures& before,
                  const Measures& after, const RunLog& log, const toro::OptimizeReport& result) {
  std::printf("summary: %s, %zu nodes, %zu constraints, %zu iterations, initial guess %s, %s\n",
              o.input.c_str(), graph.numNodes(), graph.numConstraints(), log.iterations,
              !o.chain_guess     ? "file"
              : o.odometry_guess ? "odometry"
                                 : "chain",
              groupName(o.parameterization, graph));
  if (o.robust.enabled()) {
    std::printf("  robust  kernel %s, width %g (given %g): %zu of %zu loop closures rejected (weight < %g)\n",
                toro::robustKernelName(o.robust.kernel), result.robust_width > 0 ? result.robust_width : o.robust.width,
                o.robust.width, result.rejected_loop_closures, result.loop_closures, toro::kRejectedWeight);
  }
  std::printf("  mode    %s: %zu tree iterations", toro::optimizeModeName(o.mode), result.toro_iterations);
  if (o.mode == toro::OptimizeMode::kToroThenFinish)
    std::printf(" (switch: %s)", result.switch_reason.c_str());
  if (o.mode != toro::OptimizeMode::kToro) {
    const int threads = toro::solverThreads();
    const std::string threads_text = threads > 0 ? std::to_string(threads) : "library defaults";
    std::printf(", %zu finish iterations (stop: %s, linear solver %s, solver threads %s)", result.finish.iterations,
                toro::finishStopName(result.finish.stop), toro::linearSolverName(o.linear_solver),
                threads_text.c_str());
    if (result.finish.repaired_information > 0) {
      std::printf(", warning: %zu information matrices repaired", result.finish.repaired_information);
    }
  }
  std::printf("\n");
  printMeasures("before", before);
  printMeasures("after", after);
  const double per_iteration = log.iterations ? log.optimise_seconds / double(log.iterations) : 0.0;
  std::printf("  time    setup %.4f s, optimisation %.4f s (%.3f ms/iteration), ", log.setup_seconds,
              log.optimise_seconds, 1e3 * per_iteration);
  if (o.quiet) {
    std::printf("per-iteration metrics off (-q)\n");
  } else {
    std::printf("per-iteration metrics %.4f s (not included)\n", log.measure_seconds);
  }
}

// --rejected-out: one "from to" line per loop closure whose final weight is below kRejectedWeight.
void writeRejected(const std::string& path, const toro::PoseGraph& graph, const toro::OptimizeReport& result) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) throw std::runtime_error("cannot write '" + path + "'");
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    const toro::Constraint& k = graph.constraints()[c];
    if (toro::isLoopClosure(k) && result.weights[c] < toro::kRejectedWeight)
      std::fprintf(f, "%lld %lld\n", k.from, k.to);
  }
  if (std::fclose(f) != 0) throw std::runtime_error("cannot write '" + path + "'");
}

// Chaining is forced when the file gives no pose for some node.
bool decideChain(const CliOptions& o, const toro::ReadReport& report) {
  if (o.chain_guess) return true;
  if (!report.has_vertices || !report.nodes_without_vertex.empty()) {
    if (!o.quiet) std::printf("note: some nodes have no VERTEX line; the initial guess is chained instead\n");
    return true;
  }
  return false;
}

int optimise(CliOptions o) {
  checkOutputDirectory(o.output);
  checkOutputDirectory(o.rejected_out);
  toro::ReadOptions read_options;
  read_options.toro_information_order = o.toro_order;
  toro::ReadReport report;
  toro::PoseGraph graph = toro::readGraph(o.input, read_options, &report);
  if (!o.quiet) std::printf("%s\n", toro::describeReport(report).c_str());
  if (o.parameterization == toro::Parameterization::kPlanar &&
      graph.dimension() != toro::GraphDimension::k2D) {
    // Here rather than inside the optimiser, so that "before" already measures the planar graph.
    graph = toro::projectToPlane(graph);
    if (!o.quiet) std::printf("projected onto the plane (--planar): z, roll and pitch dropped\n");
  }
  if (graph.numConstraints() == 0)
    throw std::runtime_error(o.input + ": no constraints, nothing to optimise");
  o.chain_guess = decideChain(o, report);

  const toro::OptimizeOptions options = optimizeOptions(o);
  toro::setSolverThreads(static_cast<int>(o.solver_threads));
  // Before the first finish, while no other thread can be inside the BLAS.
  const toro::BlasKernels blas = toro::selectBlasKernels(/*may_switch=*/true);
  if (!o.quiet && blas.unusual) std::printf("%s\n", blas.note.c_str());
  toro::PoseGraph estimate = graph;
  RunLog log;
  Measures before;
  bool started = false;  // the first start (setup time, "before") was seen
  // Times printed are the optimiser's: setup (tree, initial guess) and callback time excluded.
  const auto on_iteration = [&](const toro::OptimizeIteration& it) {
    const Clock::time_point measure_start = Clock::now();
    if (it.phase == toro::OptimizePhase::kStart && !started) {
      started = true;
      log.setup_seconds = it.seconds;
      before = measure(*it.estimate);
      if (!o.quiet) {
        printHeader();
        printLine("start", 0, 0.0, before);
      }
    } else if (!o.quiet) {
      const double seconds = it.seconds - log.setup_seconds - log.measure_seconds;
      if (it.phase == toro::OptimizePhase::kStart) {
        // --robust tries more than one start: each begins with a line of its own.
        printLine("start", 0, seconds, measure(*it.estimate));
      } else if (it.phase == toro::OptimizePhase::kToro) {
        printLine("tree", it.iteration, seconds, measure(*it.estimate));
      } else {
        printFinishLine(it, seconds);
      }
    }
    log.measure_seconds += secondsSince(measure_start);
  };
  const toro::OptimizeReport result = toro::optimizeGraph(estimate, options, on_iteration);
  log.iterations = result.toro_iterations + result.finish.iterations;
  log.optimise_seconds = result.seconds - log.setup_seconds - log.measure_seconds;
  printSummary(o, graph, before, measure(estimate), log, result);
  if (!o.rejected_out.empty()) writeRejected(o.rejected_out, estimate, result);
  if (!o.output.empty()) {
    toro::WriteOptions write_options;
    write_options.toro_information_order = o.toro_order;
    toro::writeGraph(estimate, o.output, write_options);
    if (!o.quiet) std::printf("wrote %s\n", o.output.c_str());
  }
  return 0;
}

int run(int argc, char** argv) {
  try {
    const CliOptions options = parseArguments(std::vector<std::string>(argv + 1, argv + argc));
    if (options.help) {
      std::cout << kUsage;
      return 0;
    }
    return optimise(options);
  } catch (const UsageError& e) {
    std::cerr << kProgram << ": " << e.what() << " (see --help)\n";
    return kExitBadArguments;
  } catch (const std::exception& e) {
    std::cerr << kProgram << ": " << e.what() << '\n';
    return kExitBadInput;
  }
}

}  // namespace

int main(int argc, char** argv) { return run(argc, argv); }
