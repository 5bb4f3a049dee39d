// selectBlasKernels: OpenBLAS's generic kernels are replaced by the ones the CPU can run only when
// OpenBLAS fell back to them, never against the user's OPENBLAS_CORETYPE, and the finish gives the
// same optimum with the kernels switched in the middle of a process.
#include <dlfcn.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"

using namespace toro;

namespace {

const std::string kSmallGrid = std::string(TORO_TEST_DATA_DIR) + "/smallGrid3D.g2o";

// The kernels OpenBLAS runs, read from the library itself ("" when the BLAS is not OpenBLAS).
std::string openBlasCore() {
  using NameGetter = char* (*)();
  const auto get = reinterpret_cast<NameGetter>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  return get && get() ? std::string(get()) : std::string();
}

// A supernodal finish of smallGrid3D (its dense supernodes go through the BLAS).
double finishedChi2() {
  PoseGraph graph = readGraph(kSmallGrid);
  FinishOptions options;
  options.linear_solver = LinearSolverType::kCholmodSupernodal;
  LevenbergMarquardt(options).optimize(graph);
  return g2oChi2(graph);
}

const char* kChildVariable = "TORO_BLAS_KERNELS_CHILD";

// Runs this executable's ChildProcess test alone with OPENBLAS_CORETYPE=`coretype` and returns the
// kernels it reported in use after selectBlasKernels(true) ("?" if the child failed).
std::string kernelsInAChild(const std::string& coretype) {
  const std::string out = std::filesystem::temp_directory_path() /
                          ("toro_blas_kernels_" + std::to_string(::getpid()) + "_" + coretype);
  const std::string command = std::string(kChildVariable) + "=1 OPENBLAS_CORETYPE=" + coretype + " " +
                              std::filesystem::read_symlink("/proc/self/exe").string() +
                              " --gtest_filter=BlasKernels.ChildProcess > " + out + " 2>&1";
  const int status = std::system(command.c_str());
  std::string in_use = "?";
  if (FILE* f = std::fopen(out.c_str(), "r")) {
    char line[512], name[64];
    while (std::fgets(line, sizeof line, f))
      if (std::sscanf(line, "kernels in use: %63s", name) == 1) in_use = name;
    std::fclose(f);
  }
  std::filesystem::remove(out);
  return WIFEXITED(status) && WEXITSTATUS(status) == 0 ? in_use : "?";
}

}  // namespace

TEST(BlasKernels, OnlyAGenericFallbackOnACpuWithAvx2IsReplaced) {
  CpuVectorFeatures avx512;
  avx512.avx = avx512.avx2_fma = avx512.avx512 = true;
  CpuVectorFeatures avx2 = avx512;
  avx2.avx512 = false;
  CpuVectorFeatures sse;  // a CPU without AVX: the generic kernels are its own
  EXPECT_EQ(betterBlasCore("Prescott", avx512, nullptr), "SkylakeX");
  EXPECT_EQ(betterBlasCore("Prescott", avx2, nullptr), "Haswell");
  EXPECT_EQ(betterBlasCore("Nehalem", avx2, nullptr), "Haswell");
  EXPECT_EQ(betterBlasCore("Prescott", sse, nullptr), "");
  // A CPU OpenBLAS recognised keeps its choice, even where another would run.
  EXPECT_EQ(betterBlasCore("Haswell", avx512, nullptr), "");
  EXPECT_EQ(betterBlasCore("Zen", avx512, nullptr), "");
  EXPECT_EQ(betterBlasCore("SkylakeX", avx512, nullptr), "");
  // The user's word, whatever it is, stands; an empty variable is no word.
  EXPECT_EQ(betterBlasCore("Prescott", avx512, "Prescott"), "");
  EXPECT_EQ(betterBlasCore("Prescott", avx512, "Haswell"), "");
  EXPECT_EQ(betterBlasCore("Prescott", avx512, ""), "SkylakeX");
  // Not OpenBLAS.
  EXPECT_EQ(betterBlasCore("", avx512, nullptr), "");
}

TEST(BlasKernels, SwitchedKernelsGiveTheSameFinishAndTheLibraryReportsThem) {
  if (std::getenv(kChildVariable)) GTEST_SKIP() << "parent only";
  const std::string loaded = openBlasCore();
  if (loaded.empty()) GTEST_SKIP() << "the BLAS of this process is not OpenBLAS";
  const char* user = std::getenv("OPENBLAS_CORETYPE");
  const std::string expected_switch = betterBlasCore(loaded, cpuVectorFeatures(), user);
  const double before = finishedChi2();

  const BlasKernels k = selectBlasKernels(/*may_switch=*/true);
  EXPECT_EQ(k.loaded, loaded);
  EXPECT_EQ(k.in_use, openBlasCore());  // what the library itself says
  if (!expected_switch.empty() && dlsym(RTLD_DEFAULT, "gotoblas_dynamic_init")) {
    EXPECT_EQ(k.in_use, expected_switch);
    EXPECT_TRUE(k.unusual);
    EXPECT_NE(k.note.find("selected for the CPU"), std::string::npos) << k.note;
  } else {
    EXPECT_EQ(k.in_use, loaded);
  }
  // The variable is the user's again (children choose for themselves).
  EXPECT_EQ(std::getenv("OPENBLAS_CORETYPE") != nullptr, user != nullptr);
  // Once per process: a later call reports the same.
  const BlasKernels again = selectBlasKernels(/*may_switch=*/true);
  EXPECT_EQ(again.in_use, k.in_use);
  EXPECT_EQ(again.loaded, k.loaded);

  // The same optimum with the new kernels (rounding differs, the minimum does not).
  const double after = finishedChi2();
  EXPECT_NEAR(after, before, 1e-9 * before);
}

TEST(BlasKernels, TheUsersCoreTypeIsKept) {
  if (std::getenv(kChildVariable)) GTEST_SKIP() << "parent only";
  if (openBlasCore().empty()) GTEST_SKIP() << "the BLAS of this process is not OpenBLAS";
  // Prescott is the generic fallback this module replaces; asked for by the user, it stays.
  EXPECT_EQ(kernelsInAChild("Prescott"), "Prescott");
  if (cpuVectorFeatures().avx2_fma) {
    EXPECT_EQ(kernelsInAChild("Haswell"), "Haswell");
  }
}

TEST(BlasKernels, ChildProcess) {
  if (!std::getenv(kChildVariable)) GTEST_SKIP() << "run by TheUsersCoreTypeIsKept";
  const BlasKernels k = selectBlasKernels(/*may_switch=*/true);
  std::printf("kernels in use: %s\n", k.in_use.c_str());
  EXPECT_NE(k.note.find("OPENBLAS_CORETYPE="), std::string::npos) << k.note;
  EXPECT_GT(finishedChi2(), 0.0);
}
