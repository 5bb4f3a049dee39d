// Report side of bench_toro: settings, the reference figures quoted beside the measurements, and
// the Markdown tables.  Header-only because CMakeLists.txt builds each bench/*.cpp into its own
// executable.
#pragma once

#include <algorithm>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "synthetic_graph.h"

namespace toro_bench {

using Values = std::map<std::string, std::string>;

struct Settings {
  std::string datasets_dir = TORO_DATASETS_DIR;
  int runs = 5;
  int iterations = 100;
  std::vector<int> checkpoints = {10, 50, 100};
  std::vector<std::string> only;
  bool datasets = true;
  bool synthetic = true;
  SyntheticOptions synthetic_options;
  int synthetic_iterations = 10;
  int synthetic_runs = 3;
  // Internal: what a child process measures.
  std::string child_dataset;
  bool child_synthetic = false;
};

// Reference figures quoted in the report (../shared/datasets/REFERENCE.md): best known g2o chi2
// and the SE-Sync objective optimum f*.  Display only; nothing is checked against them here.
struct Reference {
  double chi2;
  double sesync;
};
inline const std::map<std::string, Reference> kReferences = {
    {"sphere2500.g2o", {727.150, 1687.01}},
    {"parking-garage.g2o", {1.23869, 1.26252}},
    {"sphere_bignoise_vertex3.g2o", {743862.7, 2.96178e6}},
    {"smallGrid3D.g2o", {458.154, 1025.40}},
    {"small/tinyGrid3D.g2o", {6.72788, 18.5194}},
    {"small/pose3example.txt", {17781.79, 36680.2}},
    {"small/pose3example-grid.txt", {32.6110, 86.961}},
    {"2d/intel.g2o", {45.0047, 52.3482}},
    {"2d/intel_g2o-vertigo.g2o", {546.461, 798.002}},
    {"2d/CSAIL.g2o", {40.5551, 31.7037}},
    {"2d/MIT.g2o", {41.1633, 61.1541}},
    {"2d/manhattan.g2o", {3549.04, 6431.39}},
    {"2d/manhattanOlson3500.g2o", {146.077, 204.943}},
    {"2d/city10000.g2o", {511.985, 638.625}},
    {"2d/ais2klinik.g2o", {172.816, 188.502}},
    {"2d/kitti_00.g2o", {98.322, 125.694}},
    {"2d/kitti_02.g2o", {78.7643, 108.351}},
    {"2d/kitti_05.g2o", {157.104, 276.514}},
};

// Issue 2's targets and the original TORO 3D program's figures on this machine (from the issue).
struct Target {
  std::string dataset;
  double max_seconds;
  double original_seconds;
  double original_chi2;
  double original_sesync;  // < 0: not given
};
inline const std::vector<Target> kTargets = {
    {"sphere2500.g2o", 0.6, 1.9, 2655.0, 3591.0},
    {"parking-garage.g2o", 0.25, 0.7, 32.5, -1.0},
};

inline std::string num(double value, int significant = 4) {
  std::ostringstream out;
  out << std::setprecision(significant) << value;
  return out.str();
}

inline std::string fixed(double value, int decimals) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(decimals) << value;
  return out.str();
}

struct ChildOutcome {
  Values values;
  long max_rss_kib = 0;
  std::string error;  // empty when the child reported a result
};

inline std::string mib(long kib) { return fixed(kib / 1024.0, 1); }

inline std::string value(const Values& v, const std::string& key) {
  const auto it = v.find(key);
  return it == v.end() ? "—" : it->second;
}

inline std::string referenceCell(const std::string& name, bool chi2) {
  const auto it = kReferences.find(name);
  if (it == kReferences.end()) return "—";
  return num(chi2 ? it->second.chi2 : it->second.sesync, 6);
}

inline void printTimingTable(const Settings& s, const std::map<std::string, ChildOutcome>& results,
                             const std::vector<std::string>& names) {
  const std::string it = std::to_string(s.iterations);
  std::cout << "| dataset | dim | nodes | constraints | read (s) | setup (s) | per iteration (ms) | " << it
            << " iterations (s), median [min, max] | whole run: read + setup + " << it
            << " it. (s) | CPU time of the whole run (s) | peak RSS (MiB) "
               "|\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& name : names) {
    const ChildOutcome& r = results.at(name);
    if (!r.error.empty()) {
      std::cout << "| " << name << " | error: " << r.error << " ||||||||||\n";
      continue;
    }
    const Values& v = r.values;
    std::cout << "| " << name << " | " << value(v, "dimension") << " | " << value(v, "nodes") << " | "
              << value(v, "constraints") << " | " << value(v, "read_s") << " | " << value(v, "setup_s")
              << " | " << value(v, "per_iteration_ms") << " | " << value(v, "iterate_s") << " ["
              << value(v, "iterate_min_s") << ", " << value(v, "iterate_max_s") << "]"
              << (value(v, "deterministic") == "no" ? " (runs differ!)" : "") << " | " << value(v, "whole_s")
              << " | " << value(v, "cpu_whole_s") << " | " << mib(r.max_rss_kib) << " |\n";
  }
}

inline void printErrorTable(const Settings& s, const std::map<std::string, ChildOutcome>& results,
                            const std::vector<std::string>& names, const std::string& key,
                            const std::string& label, bool chi2) {
  std::cout << "| dataset | initial guess";
  for (int c : s.checkpoints) std::cout << " | after " << c;
  std::cout << " | " << label << " |\n|---|---:";
  for (std::size_t i = 0; i < s.checkpoints.size(); ++i) std::cout << "|---:";
  std::cout << "|---:|\n";
  for (const auto& name : names) {
    const ChildOutcome& r = results.at(name);
    if (!r.error.empty()) continue;
    std::cout << "| " << name << " | " << num(std::stod(value(r.values, key + "_0")), 6);
    for (int c : s.checkpoints)
      std::cout << " | " << num(std::stod(value(r.values, key + "_" + std::to_string(c))), 6);
    std::cout << " | " << referenceCell(name, chi2) << " |\n";
  }
}

inline void printTargets(const Settings& s, const std::map<std::string, ChildOutcome>& results) {
  const std::string last = s.checkpoints.empty() ? "" : std::to_string(s.checkpoints.back());
  std::cout << "| dataset | whole run, " << s.iterations
            << " it., wall (s) | its CPU time (s) | target (s) | original TORO (s) | chi2 after " << last
            << " | original TORO chi2 | SE-Sync after " << last
            << " | original TORO SE-Sync | time met (wall) | chi2 met "
               "|\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|\n";
  for (const Target& t : kTargets) {
    const auto it = results.find(t.dataset);
    if (it == results.end() || !it->second.error.empty()) {
      std::cout << "| " << t.dataset << " | not measured ||||||||||\n";
      continue;
    }
    const Values& v = it->second.values;
    const double whole = std::stod(value(v, "whole_s"));
    const double chi2 = std::stod(value(v, "chi2_" + last));
    std::cout << "| " << t.dataset << " | " << num(whole, 3) << " | "
              << num(std::stod(value(v, "cpu_whole_s")), 3) << " | " << t.max_seconds << " | "
              << t.original_seconds << " | " << num(chi2, 6) << " | " << t.original_chi2 << " | "
              << num(std::stod(value(v, "sesync_" + last)), 6) << " | "
              << (t.original_sesync < 0 ? "—" : num(t.original_sesync, 6)) << " | "
              << (whole <= t.max_seconds ? "yes" : "**no**") << " | "
              << (chi2 <= t.original_chi2 ? "yes" : "**no**") << " |\n";
  }
}

inline void printSynthetic(const Settings& s, const ChildOutcome& r) {
  if (!r.error.empty()) {
    std::cout << "Synthetic graph: error: " << r.error << "\n";
    return;
  }
  const Values& v = r.values;
  std::cout << "| nodes | constraints | generation (s) | setup (s) | per iteration (s), median [min, max] of "
            << s.synthetic_runs << " x " << s.synthetic_iterations << " | chi2 initial | chi2 after "
            << s.synthetic_iterations << " | peak RSS (MiB) |\n|---:|---:|---:|---:|---:|---:|---:|---:|\n"
            << "| " << value(v, "nodes") << " | " << value(v, "constraints") << " | "
            << value(v, "generate_s") << " | " << value(v, "setup_s") << " | " << value(v, "per_iteration_s")
            << " [" << value(v, "per_iteration_min_s") << ", " << value(v, "per_iteration_max_s") << "] | "
            << value(v, "chi2_0") << " | " << value(v, "chi2_final") << " | " << mib(r.max_rss_kib) << " |\n";
}

inline std::vector<std::string> namesOfDimension(const std::map<std::string, ChildOutcome>& results,
                                                 const std::vector<std::string>& names,
                                                 const std::string& dim) {
  std::vector<std::string> out;
  for (const auto& n : names) {
    const auto& r = results.at(n);
    if (value(r.values, "dimension") == dim || (dim == "3D" && !r.error.empty())) out.push_back(n);
  }
  return out;
}

// Issue 11's target: TORO in SE(2) at least this many times faster per iteration than the 3D code.
constexpr double kPlanarSpeedupTarget = 2.5;

inline void printPlanarComparison(const Settings& s, const std::map<std::string, ChildOutcome>& results,
                                  const std::vector<std::string>& names) {
  std::cout << "Each file's timed runs through both groups interleaved (" << s.runs
            << " pairs; 25 when one run takes less than 0.05 s), setup outside the timed region; per "
               "iteration = median run / "
            << s.iterations << ".\n\n";
  std::cout << "| dataset | nodes | constraints | 3D code: CPU per it. (ms) | SE(2): CPU per it. (ms) | "
               "ratio (CPU, medians) | ratio (CPU, fastest runs) | 3D code: wall per it. (ms) | SE(2): wall "
               "per it. (ms) | ratio (wall) | target >= "
            << kPlanarSpeedupTarget << " (CPU, medians) | chi2 after " << s.iterations
            << ", 3D code | chi2 after " << s.iterations
            << ", SE(2) |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|\n";
  for (const auto& name : names) {
    const ChildOutcome& r = results.at(name);
    if (!r.error.empty() || value(r.values, "cpu_ratio") == "—") continue;
    const Values& v = r.values;
    std::cout << "| " << name << " | " << value(v, "nodes") << " | " << value(v, "constraints") << " | "
              << value(v, "spatial_cpu_per_iteration_ms") << " | " << value(v, "planar_cpu_per_iteration_ms")
              << " | " << value(v, "cpu_ratio") << " | " << value(v, "cpu_ratio_best") << " | "
              << value(v, "spatial_per_iteration_ms") << " | "
              << value(v, "planar_per_iteration_ms") << " | " << value(v, "wall_ratio") << " | "
              << (std::stod(value(v, "cpu_ratio")) >= kPlanarSpeedupTarget ? "yes" : "**no**") << " | "
              << num(std::stod(value(v, "spatial_chi2_final")), 8) << " | "
              << num(std::stod(value(v, "planar_chi2_final")), 8) << " |\n";
  }
}

inline void reportDatasets(const Settings& s, const std::vector<std::string>& names,
                           const std::map<std::string, ChildOutcome>& results) {
  std::cout << "## Targets (issue 2)\n\n";
  printTargets(s, results);
  for (const std::string dim : {"3D", "2D"}) {
    const auto subset = namesOfDimension(results, names, dim);
    if (subset.empty()) continue;
    std::cout << "\n## " << dim << " datasets: time and memory\n\n";
    printTimingTable(s, results, subset);
    std::cout << "\n## " << dim << " datasets: g2o chi2 after k iterations\n\n";
    printErrorTable(s, results, subset, "chi2", "best known chi2", true);
    std::cout << "\n## " << dim << " datasets: SE-Sync objective after k iterations\n\n";
    printErrorTable(s, results, subset, "sesync", "optimum f*", false);
    if (dim == std::string("2D")) {
      std::cout << "\n## 2D datasets: TORO in SE(2) against the 3D code on the same file (issue 11)\n\n";
      printPlanarComparison(s, results, subset);
    }
  }
}

}  // namespace toro_bench
