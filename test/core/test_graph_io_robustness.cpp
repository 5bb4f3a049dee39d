// Corrupted graph files give a ParseError with a line number inside the file, or a graph whose
// every node and constraint is valid; never another exception, never a crash.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <sstream>
#include <string>

#include "toro_ros/core/graph_io.h"

using namespace toro;

namespace {

const char* const kBaseTexts[] = {
    "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0.1 1\nVERTEX_SE3:QUAT 2 2 0 0 0 0 0 1\n"
    "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.1 1 10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 40 0 0 40 0 40\n"
    "EDGE_SE3:QUAT 1 2 1 0 0 0 0 -0.1 1 10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 40 0 0 40 0 40\nFIX 0\n",
    "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.2\nEDGE_SE2 0 1 1 0 0.2 5 0 0 5 0 50\n"
    "EDGE_SE2 1 0 -1 0 -0.2 5 0.1 0.2 5 0.3 50\n",
    "VERTEX3 0 0 0 0 0 0 0\nVERTEX3 1 1 0 0 0.1 0.2 0.3\n"
    "EDGE3 0 1 1 0 0 0.1 0.2 0.3 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 100 0 0 100 0 100\nEDGE3 1 0 -1 0 0 0 0 0\n",
    "# w\nVERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 10 0 0\nEQUIV 0 1\nEDGE 1 0 -1 0 0 1 0 1 "
    "10 0 0\n",
};

// Characters that make plausible and implausible edits: digits, signs, exponents, words that
// parse as inf/nan, separators, line breaks, a NUL and a high byte.
const std::string kAlphabet = std::string("0123456789-+.eE naifINFX \t\n#:_") + std::string(1, '\0') + "\xff";

std::string corrupt(std::string text, std::mt19937& rng) {
  std::uniform_int_distribution<int> edits(1, 3), kind(0, 2);
  const int n = edits(rng);
  for (int k = 0; k < n && !text.empty(); ++k) {
    std::uniform_int_distribution<std::size_t> at(0, text.size() - 1);
    const std::size_t pos = at(rng);
    std::uniform_int_distribution<std::size_t> pick(0, kAlphabet.size() - 1);
    switch (kind(rng)) {
      case 0:
        text[pos] = kAlphabet[pick(rng)];
        break;
      case 1:
        text.erase(pos, 1);
        break;
      default:
        text.insert(pos, 1, kAlphabet[pick(rng)]);
        break;
    }
  }
  return text;
}

std::size_t lineCount(const std::string& text) {
  return std::count(text.begin(), text.end(), '\n') + (text.empty() || text.back() == '\n' ? 0 : 1);
}

}  // namespace

TEST(GraphIoRobustness, CorruptedFilesFailCleanlyOrGiveValidGraphs) {
  std::mt19937 rng(2024);
  std::size_t errors = 0, graphs = 0;
  for (const char* base : kBaseTexts) {
    for (int trial = 0; trial < 400; ++trial) {
      const std::string text = corrupt(base, rng);
      std::istringstream in(text);
      try {
        const PoseGraph g = readGraph(in, "fuzz.txt");
        ++graphs;
        for (const Node& node : g.nodes()) EXPECT_TRUE(node.pose.isFinite()) << text;
        for (const Constraint& c : g.constraints()) {
          EXPECT_TRUE(checkInformation(c.information).empty()) << text;
          EXPECT_TRUE(c.measurement.isFinite()) << text;
          EXPECT_NE(c.from, c.to) << text;
        }
      } catch (const ParseError& e) {
        ++errors;
        EXPECT_GE(e.line(), 1u) << e.what();
        EXPECT_LE(e.line(), lineCount(text)) << e.what();
        EXPECT_EQ(std::string(e.what()).rfind("fuzz.txt:" + std::to_string(e.line()) + ": ", 0), 0u)
            << e.what();
      } catch (const std::exception& e) {
        ADD_FAILURE() << "unexpected exception " << e.what() << " for:\n" << text;
      }
    }
  }
  // Both outcomes occur, so the corruption is neither always harmless nor always fatal.
  EXPECT_GT(errors, 100u);
  EXPECT_GT(graphs, 100u);
}

TEST(GraphIoRobustness, HugeQuaternionIsNormalisedWithoutOverflow) {
  std::istringstream in("VERTEX_SE3:QUAT 0 0 0 0 0 0 1e300 1e300\n");
  const PoseGraph g = readGraph(in, "huge.g2o");
  EXPECT_NEAR(g.pose(0).rotation().w(), std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(g.pose(0).rotation().z(), std::sqrt(0.5), 1e-15);
}
