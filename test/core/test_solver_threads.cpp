// setSolverThreads: the count is validated, kept, read back by the runtimes themselves (OpenBLAS,
// OpenMP) and applied by every finish in the thread it runs in; a finish with one thread starts
// no thread, while with the libraries' defaults it starts OpenMP's team (measured in a fresh child
// process of this executable, where no OpenMP team exists yet).
#include <dlfcn.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/sparse_finisher.h"

using namespace toro;

namespace {

using IntGetter = int (*)();

// The runtimes' own getters (nullptr when the runtime is not loaded), to read back what they use.
IntGetter getter(const char* name) { return reinterpret_cast<IntGetter>(dlsym(RTLD_DEFAULT, name)); }

const std::string kSmallGrid = std::string(TORO_TEST_DATA_DIR) + "/smallGrid3D.g2o";

// A supernodal finish of smallGrid3D (750 unknowns: CHOLMOD's OpenMP loops run, they need > 128).
FinishReport finishSmallGrid() {
  PoseGraph graph = readGraph(kSmallGrid);
  FinishOptions options;
  options.linear_solver = LinearSolverType::kCholmodSupernodal;
  return LevenbergMarquardt(options).optimize(graph);
}

std::size_t threadsOfThisProcess() {
  std::size_t n = 0;
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/task")) {
    (void)entry;
    ++n;
  }
  return n;
}

const char* kChildVariable = "TORO_SOLVER_THREADS_CHILD";

// Runs this executable's ChildProcess test alone in a new process with the given count and returns
// the threads its finish started (-1 if the child failed).
int threadsStartedInAChild(int count) {
  const std::string out = std::filesystem::temp_directory_path() /
                          ("toro_solver_threads_" + std::to_string(::getpid()) + "_" + std::to_string(count));
  const std::string command = std::string(kChildVariable) + "=" + std::to_string(count) + " " +
                              std::filesystem::read_symlink("/proc/self/exe").string() +
                              " --gtest_filter=SolverThreads.ChildProcess > " + out + " 2>&1";
  const int status = std::system(command.c_str());
  int started = -1;
  if (FILE* f = std::fopen(out.c_str(), "r")) {
    char line[512];
    while (std::fgets(line, sizeof line, f))
      if (std::sscanf(line, "threads started by the finish: %d", &started) == 1) break;
    std::fclose(f);
  }
  std::filesystem::remove(out);
  return WIFEXITED(status) && WEXITSTATUS(status) == 0 ? started : -1;
}

}  // namespace

TEST(SolverThreads, CountsAreValidated) {
  EXPECT_EQ(validateSolverThreads(0), "");
  EXPECT_EQ(validateSolverThreads(kMaxSolverThreads), "");
  EXPECT_NE(validateSolverThreads(-1).find("got -1"), std::string::npos);
  EXPECT_NE(validateSolverThreads(kMaxSolverThreads + 1), "");
  EXPECT_THROW(setSolverThreads(-1), std::invalid_argument);
}

TEST(SolverThreads, TheRuntimesReadBackTheCountAndZeroKeepsIt) {
  const IntGetter blas = getter("openblas_get_num_threads");
  const IntGetter omp_threads = getter("omp_get_max_threads");
  const IntGetter omp_dynamic = getter("omp_get_dynamic");
  ASSERT_TRUE(omp_threads && omp_dynamic) << "libgomp is CHOLMOD's dependency; it should be loaded";
  for (int n : {3, 1}) {
    const SolverThreadSettings set = setSolverThreads(n);
    EXPECT_EQ(set.threads, n);
    EXPECT_EQ(solverThreads(), n);
    EXPECT_TRUE(set.openmp_set);
    EXPECT_EQ(omp_threads(), n);
    EXPECT_EQ(omp_dynamic(), 1);  // the only run-time bound on CHOLMOD's num_threads(4) loops
    EXPECT_EQ(set.openblas_set, blas != nullptr);
    if (blas) {
      EXPECT_EQ(blas(), n);
    }
  }
  // 0 leaves everything as it is: the last count stays in force.
  const SolverThreadSettings kept = setSolverThreads(0);
  EXPECT_EQ(kept.threads, 1);
  EXPECT_FALSE(kept.openmp_set);
  EXPECT_EQ(solverThreads(), 1);
  EXPECT_EQ(omp_threads(), 1);
}

// OpenMP's count is a per-thread setting: a finish in another thread (the node's worker, a
// background finish) must apply it there itself.
TEST(SolverThreads, AFinishAppliesTheCountInTheThreadItRunsIn) {
  const IntGetter omp_threads = getter("omp_get_max_threads");
  ASSERT_NE(omp_threads, nullptr);
  setSolverThreads(3);  // neither OpenMP's default here (the CPUs) nor 1
  int before = 0, after = 0;
  std::thread worker([&] {
    before = omp_threads();
    finishSmallGrid();
    after = omp_threads();
  });
  worker.join();
  EXPECT_NE(before, 3) << "a new thread starts with OpenMP's defaults; this test then proves nothing";
  EXPECT_EQ(after, 3);
  setSolverThreads(kDefaultSolverThreads);
}

TEST(SolverThreads, OneThreadFinishStartsNoThreadLibraryDefaultsDo) {
  EXPECT_EQ(threadsStartedInAChild(1), 0);
  const IntGetter procs = getter("omp_get_num_procs");
  if (!procs || procs() < 2 || std::getenv("OMP_NUM_THREADS") || std::getenv("OMP_THREAD_LIMIT"))
    GTEST_SKIP() << "the control needs 2+ CPUs and OpenMP's defaults";
  // The control: the same count sees the team CHOLMOD's loops start with the libraries' defaults.
  EXPECT_GT(threadsStartedInAChild(0), 0);
}

// Only as the child of the test above (the variable names the count).
TEST(SolverThreads, ChildProcess) {
  const char* count = std::getenv(kChildVariable);
  if (!count) GTEST_SKIP() << "runs only as a child of OneThreadFinishStartsNoThreadLibraryDefaultsDo";
  setSolverThreads(std::atoi(count));
  const std::size_t threads_before = threadsOfThisProcess();
  ASSERT_GT(finishSmallGrid().iterations, 0u);
  std::printf("threads started by the finish: %d\n", static_cast<int>(threadsOfThisProcess() - threads_before));
}
