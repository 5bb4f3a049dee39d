// Sweeps the translational learning-rate constant (TreeOptimizerOptions::translation_gamma) over
// graph files and prints g2o chi2 after 10, 50 and 100 iterations, to choose its default by
// measurement on many graphs rather than one.  Output kept in bench/translation_gamma_sweep.md.
//
//   bench_gamma_sweep FILE... [--values 1,0.3,0.1,0.03]
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/tree_optimizer.h"

int main(int argc, char** argv) {
  std::vector<std::string> files;
  std::vector<double> values{1.0, 0.3, 0.1, 0.03};
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg == "--values" && a + 1 < argc) {
      values.clear();
      std::stringstream list(argv[++a]);
      for (std::string v; std::getline(list, v, ',');) values.push_back(std::atof(v.c_str()));
    } else {
      files.push_back(arg);
    }
  }
  std::printf("| file | translation_gamma | chi2 @10 | chi2 @50 | chi2 @100 |\n|---|---|---|---|---|\n");
  for (const std::string& file : files) {
    try {
      const toro::PoseGraph graph = toro::readGraph(file);
      for (double value : values) {
        toro::TreeOptimizerOptions options;
        options.translation_gamma = value;
        toro::TreeOptimizer optimizer(options);
        optimizer.setGraph(graph);
        double chi2[3] = {0, 0, 0};
        for (int i = 1; i <= 100; ++i) {
          optimizer.iterate();
          if (i == 10) chi2[0] = toro::g2oChi2(optimizer.graph());
          if (i == 50) chi2[1] = toro::g2oChi2(optimizer.graph());
        }
        chi2[2] = toro::g2oChi2(optimizer.graph());
        std::printf("| %s | %g | %.6g | %.6g | %.6g |\n", file.c_str(), value, chi2[0], chi2[1], chi2[2]);
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "%s\n", e.what());
      return 1;
    }
  }
  return 0;
}
