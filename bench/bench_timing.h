// What every benchmark measures time with: process CPU seconds beside the wall clock (the machine
// is shared, so CPU time is the figure a neighbour's load disturbs least) and medians of repeats.
#pragma once

#include <time.h>

#include <algorithm>
#include <vector>

namespace toro_bench {

inline double cpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

inline double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace toro_bench
