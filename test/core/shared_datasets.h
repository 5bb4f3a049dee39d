// The shared datasets (../shared/datasets beside the repository) are not part of the package: tests
// that read them skip, saying so, when a checkout has no such folder beside it.
#pragma once

#include <fstream>
#include <string>

namespace toro_test {

inline std::string datasetPath(const std::string& name) { return std::string(TORO_DATASETS_DIR) + "/" + name; }

inline bool datasetsAvailable() { return std::ifstream(datasetPath("README.md")).good(); }

}  // namespace toro_test

// Use at the top of a test body that reads the shared datasets.
#define TORO_REQUIRE_DATASETS()                                                              \
  do {                                                                                       \
    if (!toro_test::datasetsAvailable()) GTEST_SKIP() << "no datasets at " << TORO_DATASETS_DIR; \
  } while (0)
