// Benchmark of the TORO optimiser core (issue 2): per dataset, time per iteration, time for N
// iterations (median of several runs, default options, initial guess chained on the tree), g2o chi2
// and SE-Sync objective at checkpoints (computed outside the timed region), peak memory; plus a
// large synthetic graph.  2D files run in SE(2) (the default for them) and, interleaved, through
// the 3D code on the same file (issue 11: the planar mode's speed-up).  Each dataset runs in its own child
// process so that its peak resident memory (ru_maxrss from wait4) is its own.  Writes a Markdown report to
// stdout, progress to stderr.
//
//   bench_toro [--datasets DIR] [--runs 5] [--iterations 100] [--checkpoints 10,50,100]
//              [--only NAME[,NAME...]] [--synthetic-nodes 100000] [--synthetic-constraints 200000]
//              [--synthetic-iterations 10] [--synthetic-runs 3] [--no-synthetic] [--no-datasets]
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bench_report.h"
#include "bench_timing.h"
#include "synthetic_graph.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/tree_optimizer.h"

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using toro_bench::ChildOutcome;
using toro_bench::num;
using toro_bench::Settings;
using toro_bench::Values;

double secondsBetween(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// CPU time of this (single-threaded) process: unlike wall time it hardly grows when other jobs
// compete for the cores, so the report shows both.
using toro_bench::cpuSeconds;
using toro_bench::median;

// ------------------------------------------------------------------------------------------------
// Command line
// ------------------------------------------------------------------------------------------------

std::vector<std::string> splitList(const std::string& text) {
  std::vector<std::string> parts;
  std::stringstream in(text);
  std::string part;
  while (std::getline(in, part, ',')) {
    if (!part.empty()) parts.push_back(part);
  }
  return parts;
}

int positiveInt(const std::string& flag, const std::string& text) {
  std::size_t used = 0;
  int value = 0;
  try {
    value = std::stoi(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || value <= 0) {
    throw std::invalid_argument(flag + " needs a positive integer, got '" + text + "'");
  }
  return value;
}

Settings parseArgs(int argc, char** argv) {
  Settings s;
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(flag + " needs a value");
      return argv[++i];
    };
    if (flag == "--datasets")
      s.datasets_dir = value();
    else if (flag == "--runs")
      s.runs = positiveInt(flag, value());
    else if (flag == "--iterations")
      s.iterations = positiveInt(flag, value());
    else if (flag == "--only")
      s.only = splitList(value());
    else if (flag == "--synthetic-nodes")
      s.synthetic_options.nodes = positiveInt(flag, value());
    else if (flag == "--synthetic-constraints")
      s.synthetic_options.constraints = positiveInt(flag, value());
    else if (flag == "--synthetic-iterations")
      s.synthetic_iterations = positiveInt(flag, value());
    else if (flag == "--synthetic-runs")
      s.synthetic_runs = positiveInt(flag, value());
    else if (flag == "--no-synthetic")
      s.synthetic = false;
    else if (flag == "--no-datasets")
      s.datasets = false;
    else if (flag == "--child-dataset")
      s.child_dataset = value();
    else if (flag == "--child-synthetic")
      s.child_synthetic = true;
    else if (flag == "--checkpoints") {
      s.checkpoints.clear();
      for (const auto& c : splitList(value())) s.checkpoints.push_back(positiveInt(flag, c));
      std::sort(s.checkpoints.begin(), s.checkpoints.end());
    } else {
      throw std::invalid_argument("unknown option '" + flag +
                                  "' (see the comment at the top of bench_toro.cpp)");
    }
  }
  return s;
}

// Arguments that a child needs to repeat the parent's settings.
std::vector<std::string> childArgs(const Settings& s) {
  std::string checkpoints;
  for (int c : s.checkpoints) checkpoints += (checkpoints.empty() ? "" : ",") + std::to_string(c);
  return {"--runs",
          std::to_string(s.runs),
          "--iterations",
          std::to_string(s.iterations),
          "--checkpoints",
          checkpoints,
          "--synthetic-nodes",
          std::to_string(s.synthetic_options.nodes),
          "--synthetic-constraints",
          std::to_string(s.synthetic_options.constraints),
          "--synthetic-iterations",
          std::to_string(s.synthetic_iterations),
          "--synthetic-runs",
          std::to_string(s.synthetic_runs)};
}

// ------------------------------------------------------------------------------------------------
// Child side: measure one dataset (or the synthetic graph) and print one RESULT line.
// ------------------------------------------------------------------------------------------------

void printValues(const Values& values) {
  std::cout << "RESULT";
  for (const auto& [key, value] : values) std::cout << '\t' << key << '=' << value;
  std::cout << std::endl;
}

// Error measures at 0 and at each checkpoint, from one extra (untimed) run.
void measureCheckpoints(const toro::PoseGraph& graph, const Settings& s, Values& out) {
  toro::TreeOptimizer optimizer;
  optimizer.setGraph(graph, toro::InitialGuess::kChainOnTree);
  out["chi2_0"] = num(toro::g2oChi2(optimizer.graph()), 10);
  out["sesync_0"] = num(toro::seSyncObjective(optimizer.graph()), 10);
  int done = 0;
  for (int checkpoint : s.checkpoints) {
    for (; done < checkpoint; ++done) optimizer.iterate();
    out["chi2_" + std::to_string(checkpoint)] = num(toro::g2oChi2(optimizer.graph()), 10);
    out["sesync_" + std::to_string(checkpoint)] = num(toro::seSyncObjective(optimizer.graph()), 10);
  }
}

// A 2D file through TORO in SE(2) and through the 3D code (Parameterization::kSpatial), timed runs
// of the two interleaved (first one, then the other, by turns) so that both see the same load; the
// setup is outside the timed region.  Small files get more runs: a run of a few milliseconds is at
// the mercy of one context switch.
struct GroupRuns {
  toro::Parameterization group;
  std::vector<double> iterate_s, cpu_iterate_s, final_chi2;
  void run(const toro::PoseGraph& graph, int iterations) {
    toro::TreeOptimizerOptions options;
    options.parameterization = group;
    toro::TreeOptimizer optimizer(options);
    optimizer.setGraph(graph, toro::InitialGuess::kChainOnTree);
    const double c0 = cpuSeconds();
    const auto t0 = Clock::now();
    for (int k = 0; k < iterations; ++k) optimizer.iterate();
    iterate_s.push_back(secondsBetween(t0, Clock::now()));
    cpu_iterate_s.push_back(cpuSeconds() - c0);
    final_chi2.push_back(toro::g2oChi2(optimizer.graph()));
  }
};

// Runs of at least this much time each are enough at s.runs; shorter ones are repeated up to
// kSmallFileRuns times.
constexpr double kLongRunSeconds = 0.05;
constexpr int kSmallFileRuns = 25;

void comparePlanarWith3D(const toro::PoseGraph& graph, const Settings& s, double typical_run_s, Values& out) {
  GroupRuns planar{toro::Parameterization::kPlanar, {}, {}, {}};
  GroupRuns spatial{toro::Parameterization::kSpatial, {}, {}, {}};
  const int runs = typical_run_s >= kLongRunSeconds ? s.runs : std::max(s.runs, kSmallFileRuns);
  for (int run = 0; run < runs; ++run) {
    GroupRuns& first = run % 2 == 0 ? planar : spatial;
    GroupRuns& second = run % 2 == 0 ? spatial : planar;
    first.run(graph, s.iterations);
    second.run(graph, s.iterations);
  }
  const auto fastest = [](const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); };
  const double per = 1000.0 / s.iterations;
  out["comparison_runs"] = std::to_string(runs);
  out["planar_per_iteration_ms"] = num(per * median(planar.iterate_s));
  out["planar_cpu_per_iteration_ms"] = num(per * median(planar.cpu_iterate_s));
  out["spatial_per_iteration_ms"] = num(per * median(spatial.iterate_s));
  out["spatial_cpu_per_iteration_ms"] = num(per * median(spatial.cpu_iterate_s));
  out["cpu_ratio"] = num(median(spatial.cpu_iterate_s) / median(planar.cpu_iterate_s), 3);
  // Under load the fastest run of each is the least disturbed one.
  out["cpu_ratio_best"] = num(fastest(spatial.cpu_iterate_s) / fastest(planar.cpu_iterate_s), 3);
  out["wall_ratio"] = num(median(spatial.iterate_s) / median(planar.iterate_s), 3);
  out["planar_chi2_final"] = num(planar.final_chi2[0], 10);
  out["spatial_chi2_final"] = num(spatial.final_chi2[0], 10);
}

int runDatasetChild(const Settings& s) {
  std::vector<double> read_s, setup_s, iterate_s, whole_s, cpu_iterate_s, cpu_whole_s, final_chi2;
  toro::PoseGraph graph;
  bool planar = false;
  for (int run = 0; run < s.runs; ++run) {
    const double c0 = cpuSeconds();
    const auto t0 = Clock::now();
    graph = toro::readGraph(s.child_dataset);
    const auto t1 = Clock::now();
    toro::TreeOptimizer optimizer;  // default options: SE(2) for a 2D file
    optimizer.setGraph(graph, toro::InitialGuess::kChainOnTree);
    planar = optimizer.planar();
    const auto t2 = Clock::now();
    const double c2 = cpuSeconds();
    for (int k = 0; k < s.iterations; ++k) optimizer.iterate();
    const auto t3 = Clock::now();
    const double c3 = cpuSeconds();
    cpu_iterate_s.push_back(c3 - c2);
    cpu_whole_s.push_back(c3 - c0);
    read_s.push_back(secondsBetween(t0, t1));
    setup_s.push_back(secondsBetween(t1, t2));
    iterate_s.push_back(secondsBetween(t2, t3));
    whole_s.push_back(secondsBetween(t0, t3));
    final_chi2.push_back(toro::g2oChi2(optimizer.graph()));  // outside the timed region
  }
  Values out;
  if (planar) comparePlanarWith3D(graph, s, median(iterate_s), out);
  out["dimension"] = graph.dimension() == toro::GraphDimension::k2D ? "2D" : "3D";
  out["nodes"] = std::to_string(graph.numNodes());
  out["constraints"] = std::to_string(graph.numConstraints());
  out["read_s"] = num(median(read_s));
  out["setup_s"] = num(median(setup_s));
  out["iterate_s"] = num(median(iterate_s));
  out["iterate_min_s"] = num(*std::min_element(iterate_s.begin(), iterate_s.end()));
  out["iterate_max_s"] = num(*std::max_element(iterate_s.begin(), iterate_s.end()));
  out["per_iteration_ms"] = num(1000.0 * median(iterate_s) / s.iterations);
  out["whole_s"] = num(median(whole_s));
  out["cpu_iterate_s"] = num(median(cpu_iterate_s));
  out["cpu_whole_s"] = num(median(cpu_whole_s));
  // The optimiser is deterministic: every timed run must end at the same chi2.
  const bool same =
      std::all_of(final_chi2.begin(), final_chi2.end(), [&](double c) { return c == final_chi2[0]; });
  out["deterministic"] = same ? "yes" : "no";
  measureCheckpoints(graph, s, out);
  printValues(out);
  return 0;
}

int runSyntheticChild(const Settings& s) {
  const auto t0 = Clock::now();
  const toro::PoseGraph graph = toro_bench::makeSyntheticGraph(s.synthetic_options);
  const auto t1 = Clock::now();
  std::vector<double> setup_s, iteration_s;
  double chi2_initial = 0.0, chi2_final = 0.0;
  for (int run = 0; run < s.synthetic_runs; ++run) {
    toro::TreeOptimizer optimizer;
    const auto a = Clock::now();
    optimizer.setGraph(graph, toro::InitialGuess::kChainOnTree);
    setup_s.push_back(secondsBetween(a, Clock::now()));
    if (run == 0) chi2_initial = toro::g2oChi2(optimizer.graph());
    for (int k = 0; k < s.synthetic_iterations; ++k) {
      const auto b = Clock::now();
      optimizer.iterate();
      iteration_s.push_back(secondsBetween(b, Clock::now()));
    }
    if (run == 0) chi2_final = toro::g2oChi2(optimizer.graph());
  }
  Values out;
  out["nodes"] = std::to_string(graph.numNodes());
  out["constraints"] = std::to_string(graph.numConstraints());
  out["generate_s"] = num(secondsBetween(t0, t1));
  out["setup_s"] = num(median(setup_s));
  out["per_iteration_s"] = num(median(iteration_s));
  out["per_iteration_min_s"] = num(*std::min_element(iteration_s.begin(), iteration_s.end()));
  out["per_iteration_max_s"] = num(*std::max_element(iteration_s.begin(), iteration_s.end()));
  out["chi2_0"] = num(chi2_initial, 6);
  out["chi2_final"] = num(chi2_final, 6);
  printValues(out);
  return 0;
}

// ------------------------------------------------------------------------------------------------
// Parent side: one child process per measurement, then the report.
// ------------------------------------------------------------------------------------------------

Values parseResultLine(const std::string& line) {
  Values values;
  std::stringstream in(line.substr(std::string("RESULT\t").size()));
  std::string field;
  while (std::getline(in, field, '\t')) {
    const auto eq = field.find('=');
    if (eq != std::string::npos) values[field.substr(0, eq)] = field.substr(eq + 1);
  }
  return values;
}

ChildOutcome runChild(const std::vector<std::string>& args) {
  int fds[2];
  if (pipe(fds) != 0) return {{}, 0, "pipe() failed"};
  const pid_t pid = fork();
  if (pid < 0) return {{}, 0, "fork() failed"};
  if (pid == 0) {
    dup2(fds[1], STDOUT_FILENO);
    close(fds[0]);
    close(fds[1]);
    std::vector<char*> argv;
    static char self[] = "/proc/self/exe";
    argv.push_back(self);
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(self, argv.data());
    _exit(127);
  }
  close(fds[1]);
  std::string output;
  char buffer[4096];
  for (ssize_t n; (n = read(fds[0], buffer, sizeof buffer)) > 0;)
    output.append(buffer, static_cast<std::size_t>(n));
  close(fds[0]);
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  ChildOutcome outcome;
  outcome.max_rss_kib = usage.ru_maxrss;  // Linux: kibibytes
  std::stringstream lines(output);
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("RESULT\t", 0) == 0) outcome.values = parseResultLine(line);
    if (line.rfind("ERROR\t", 0) == 0) outcome.error = line.substr(6);
  }
  if (outcome.values.empty() && outcome.error.empty()) {
    outcome.error = "child exited with status " +
                    std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) +
                    (WIFSIGNALED(status) ? " (signal " + std::to_string(WTERMSIG(status)) + ")" : "");
  }
  return outcome;
}

// Dataset files in report order: 3D g2o, small 3D, TORO 3D, then 2D.
std::vector<std::string> listDatasets(const Settings& s) {
  const fs::path root(s.datasets_dir);
  const std::vector<std::pair<std::string, std::vector<std::string>>> groups = {{"", {".g2o"}},
                                                                                {"small", {".g2o", ".txt"}},
                                                                                {"toro", {".graph", ".txt"}},
                                                                                {"2d", {".g2o"}},
                                                                                {"toro/2d", {".graph"}}};
  std::vector<std::string> names;
  for (const auto& [folder, extensions] : groups) {
    const fs::path dir = root / folder;
    if (!fs::is_directory(dir)) continue;
    std::vector<std::string> found;
    for (const auto& entry : fs::directory_iterator(dir)) {
      const std::string ext = entry.path().extension().string();
      if (!entry.is_regular_file() ||
          std::find(extensions.begin(), extensions.end(), ext) == extensions.end())
        continue;
      found.push_back(folder.empty() ? entry.path().filename().string()
                                     : folder + "/" + entry.path().filename().string());
    }
    std::sort(found.begin(), found.end());
    names.insert(names.end(), found.begin(), found.end());
  }
  auto wanted = [&](const std::string& name) {
    if (s.only.empty()) return true;
    return std::any_of(s.only.begin(), s.only.end(),
                       [&](const std::string& o) { return name.find(o) != std::string::npos; });
  };
  names.erase(std::remove_if(names.begin(), names.end(), [&](const std::string& n) { return !wanted(n); }),
              names.end());
  return names;
}

int runParent(const Settings& s) {
  const std::vector<std::string> common = childArgs(s);
  if (s.datasets) {
    const std::vector<std::string> names = listDatasets(s);
    if (names.empty()) throw std::runtime_error("no dataset found under " + s.datasets_dir);
    std::map<std::string, ChildOutcome> results;
    for (const auto& name : names) {
      std::cerr << "bench_toro: " << name << " ..." << std::flush;
      std::vector<std::string> args = common;
      args.insert(args.end(), {"--child-dataset", (fs::path(s.datasets_dir) / name).string()});
      results[name] = runChild(args);
      std::cerr << (results[name].error.empty() ? " done" : " error: " + results[name].error) << "\n";
    }
    reportDatasets(s, names, results);
  }
  if (s.synthetic) {
    std::cerr << "bench_toro: synthetic graph ..." << std::flush;
    std::vector<std::string> args = common;
    args.push_back("--child-synthetic");
    const ChildOutcome r = runChild(args);
    std::cerr << " done\n";
    std::cout
        << "\n## Synthetic graph (seeded random walk on a 3D grid, loop closures to earlier visits of the "
           "same cell)\n\n";
    printSynthetic(s, r);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const Settings s = parseArgs(argc, argv);
    if (!s.child_dataset.empty()) return runDatasetChild(s);
    if (s.child_synthetic) return runSyntheticChild(s);
    return runParent(s);
  } catch (const std::exception& e) {
    // A child reports through its stdout pipe (the parent reads it); a user sees stderr.
    const bool child = std::any_of(argv + 1, argv + argc,
                                   [](const char* a) { return std::string(a).rfind("--child-", 0) == 0; });
    if (child) std::cout << "ERROR\t" << e.what() << std::endl;
    std::cerr << "bench_toro: " << e.what() << "\n";
    return 1;
  }
}
