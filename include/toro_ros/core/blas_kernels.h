// The dense kernels of the BLAS behind the finish.
//
// CHOLMOD's supernodal factorisation spends most of its time in the system BLAS (dgemm, dtrsm,
// dsyrk on the supernodes).  OpenBLAS, the BLAS Debian installs for it, picks its kernels when it is
// loaded, by CPU model; a CPU newer than the library gets its generic SSE3 ("Prescott") kernels even
// when it has AVX2 or AVX-512.  Debian 12's OpenBLAS 0.3.21 does so on an Emerald Rapids Xeon
// (family 6, model 207): the sphere2500 replay of bench/background_finish_results.md took 17.3 s
// there, 13.1 s with the AVX-512 kernels, the same map to the last digit.  OpenBLAS reads the
// OPENBLAS_CORETYPE environment variable at load to override its choice, which a user seldom knows
// to set; selectBlasKernels does the same from inside the process.
#pragma once

#include <string>

namespace toro {

// The CPU's vector extensions that decide which kernels can run (as the OS enables them).
struct CpuVectorFeatures {
  bool avx = false;
  bool avx2_fma = false;  // AVX2 and FMA3: OpenBLAS's "Haswell" kernels
  bool avx512 = false;    // AVX-512 F, CD, BW, DQ and VL: its "SkylakeX" kernels
};
CpuVectorFeatures cpuVectorFeatures();

// The OpenBLAS core type to select instead of `loaded` (OpenBLAS's name of the kernels it chose),
// or "" to keep them: only when `loaded` is one of its kernels without AVX while the CPU has AVX2
// and FMA (the generic fallback for a CPU it did not recognise; a CPU it recognised keeps the
// library's own choice), and never when the user set OPENBLAS_CORETYPE (`user_coretype`).
std::string betterBlasCore(const std::string& loaded, const CpuVectorFeatures& cpu,
                           const char* user_coretype);

struct BlasKernels {
  std::string loaded;  // the kernels OpenBLAS chose at load ("" when the BLAS is not OpenBLAS)
  std::string in_use;  // the kernels in use after the call
  std::string note;    // one line for the log: what is used and why
  // Worth a line where a program otherwise says little: the kernels were switched, or better ones
  // are left unused.
  bool unusual = false;
};

// Reads the kernels of the loaded OpenBLAS and, when `may_switch` and betterBlasCore names better
// ones, makes OpenBLAS select them (its own re-initialisation with OPENBLAS_CORETYPE set, as at
// load).  Switching is process-wide and must not run while any thread of the process is inside a
// BLAS call: programs that own their process call it with true at start, before any finish
// (toro_optimize, toro_offline, map_corrector_node); a nodelet, whose manager runs other code,
// passes false and gets the advice in the note instead.  Switches once per process; later calls
// report.  Looked up at run time (dlsym): with another BLAS, or an OpenBLAS without dynamic kernel
// selection, nothing changes and the note says so.
BlasKernels selectBlasKernels(bool may_switch);

}  // namespace toro
