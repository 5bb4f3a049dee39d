#include "toro_ros/core/blas_kernels.h"

#include <dlfcn.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <mutex>
#include <string_view>

namespace toro {

namespace {

using NameGetter = char* (*)();
using Action = void (*)();

// OpenBLAS's names of its x86 kernels that use no AVX (driver/others/dynamic.c): what it falls back
// to on a CPU it does not know.
constexpr std::array<std::string_view, 16> kKernelsWithoutAvx = {
    "Prescott",  "Core2",  "Penryn", "Dunnington", "Nehalem",   "Atom",   "Katmai", "Coppermine",
    "Northwood", "Banias", "Athlon", "Opteron",    "Barcelona", "Bobcat", "Nano",   "Opteron(SSE3)"};

struct OpenBlasEntryPoints {
  NameGetter corename = nullptr;  // openblas_get_corename: the kernels in use
  Action dynamic_quit = nullptr;  // gotoblas_dynamic_quit / _init: its own kernel selection, run
  Action dynamic_init = nullptr;  // at load (reads OPENBLAS_CORETYPE); only in DYNAMIC_ARCH builds
};

OpenBlasEntryPoints openBlas() {
  OpenBlasEntryPoints e;
  e.corename = reinterpret_cast<NameGetter>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  e.dynamic_quit = reinterpret_cast<Action>(dlsym(RTLD_DEFAULT, "gotoblas_dynamic_quit"));
  e.dynamic_init = reinterpret_cast<Action>(dlsym(RTLD_DEFAULT, "gotoblas_dynamic_init"));
  return e;
}

std::string coreName(const OpenBlasEntryPoints& e) {
  if (!e.corename) return "";
  const char* name = e.corename();
  return name ? std::string(name) : std::string();
}

// What the first call found and did, for the reports of later calls.
struct ProcessRecord {
  bool done = false;
  std::string loaded;
  std::string better;     // betterBlasCore for this CPU, whatever OPENBLAS_CORETYPE says
  bool switched = false;  // the first call made OpenBLAS select `better`
};

}  // namespace

CpuVectorFeatures cpuVectorFeatures() {
  CpuVectorFeatures f;
#if defined(__x86_64__) || defined(__i386__)
  // libgcc's checks include the OS's (XCR0): registers it does not save count as absent.
  __builtin_cpu_init();
  f.avx = __builtin_cpu_supports("avx");
  f.avx2_fma = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  f.avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512cd") &&
             __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq") &&
             __builtin_cpu_supports("avx512vl");
#endif
  return f;
}

std::string betterBlasCore(const std::string& loaded, const CpuVectorFeatures& cpu,
                           const char* user_coretype) {
  if (user_coretype && *user_coretype) return "";
  if (std::find(kKernelsWithoutAvx.begin(), kKernelsWithoutAvx.end(), loaded) == kKernelsWithoutAvx.end())
    return "";
  if (!cpu.avx2_fma) return "";  // an old CPU's own kernels, or one OpenBLAS rightly judged
  return cpu.avx512 ? "SkylakeX" : "Haswell";
}

BlasKernels selectBlasKernels(bool may_switch) {
  static std::mutex mutex;
  static ProcessRecord record;
  const std::lock_guard<std::mutex> lock(mutex);
  const OpenBlasEntryPoints blas = openBlas();
  BlasKernels out;
  if (!blas.corename) {
    out.note = "BLAS kernels: the system BLAS is not OpenBLAS (or not loaded); left as it is";
    return out;
  }
  if (!record.done) {
    record.done = true;
    record.loaded = coreName(blas);
    const CpuVectorFeatures cpu = cpuVectorFeatures();
    record.better = betterBlasCore(record.loaded, cpu, nullptr);
    const char* user = std::getenv("OPENBLAS_CORETYPE");
    const bool wanted = !betterBlasCore(record.loaded, cpu, user).empty();
    if (wanted && may_switch && blas.dynamic_quit && blas.dynamic_init) {
      // Its own selection again, as at load with the variable set; the variable is put back (unset,
      // or set and empty) so that child processes make their own choice.
      const bool was_set = user != nullptr;
      ::setenv("OPENBLAS_CORETYPE", record.better.c_str(), 1);
      blas.dynamic_quit();
      blas.dynamic_init();
      if (was_set) {
        ::setenv("OPENBLAS_CORETYPE", "", 1);
      } else {
        ::unsetenv("OPENBLAS_CORETYPE");
      }
      record.switched = true;
    }
  }
  out.loaded = record.loaded;
  out.in_use = coreName(blas);
  const char* user = std::getenv("OPENBLAS_CORETYPE");
  if (record.switched) {
    out.unusual = true;
    out.note = "BLAS kernels: OpenBLAS " + out.in_use + " (it loaded its generic " + out.loaded +
               " kernels on this CPU, which it does not know; selected for the CPU's " +
               (record.better == "SkylakeX" ? "AVX-512" : "AVX2") + ")";
  } else if (user && *user) {
    out.note = "BLAS kernels: OpenBLAS " + out.in_use + " (OPENBLAS_CORETYPE=" + user + ")";
  } else if (!record.better.empty()) {
    out.unusual = true;
    out.note = "BLAS kernels: OpenBLAS " + out.in_use +
               ", its generic kernels on this CPU, which it does not know; the finish runs ~1.3x "
               "faster with OPENBLAS_CORETYPE=" +
               record.better + " in the environment" +
               (blas.dynamic_quit && blas.dynamic_init
                    ? std::string(" (not switched inside a shared process: a nodelet)")
                    : std::string(" (this OpenBLAS cannot select kernels at run time)"));
  } else {
    out.note = "BLAS kernels: OpenBLAS " + out.in_use + " (its own choice for this CPU)";
  }
  return out;
}

}  // namespace toro
