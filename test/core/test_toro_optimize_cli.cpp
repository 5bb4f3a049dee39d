// Runs the built toro_optimize binary (path from CMake) on the bundled smallGrid3D.g2o and on bad
// input, and checks exit codes and what it prints.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <random>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/planar.h"
#include "toro_ros/core/random_draws.h"

namespace {

namespace fs = std::filesystem;

struct Result {
  int exit_code;
  std::string out;
  std::string err;
};

class ToroOptimizeCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("toro_optimize_cli_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  Result run(const std::string& arguments) const {
    const fs::path out = dir_ / "stdout.txt", err = dir_ / "stderr.txt";
    const std::string command =
        std::string(TORO_OPTIMIZE_BIN) + " " + arguments + " > " + out.string() + " 2> " + err.string();
    const int status = std::system(command.c_str());
    return Result{WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(out), slurp(err)};
  }

  static std::string slurp(const fs::path& path) {
    std::ifstream in(path);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  }

  fs::path dir_;
};

const std::string kSmallGrid = std::string(TORO_TEST_DATA_DIR) + "/smallGrid3D.g2o";

// The number after `key` on the first line containing `line_start` (NaN if absent).
double numberAfter(const std::string& text, const std::string& line_start, const std::string& key) {
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.find(line_start) == std::string::npos) continue;
    const std::size_t at = line.find(key);
    if (at == std::string::npos) continue;
    return std::stod(line.substr(at + key.size()));
  }
  return std::nan("");
}

std::vector<std::string> linesStartingWith(const std::string& text, const std::string& prefix) {
  std::vector<std::string> out;
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.rfind(prefix, 0) == 0) out.push_back(line);
  }
  return out;
}

// A 2D g2o file: a planar robot driving two laps of a 12 x 8 m rectangle, noisy odometry, loop
// closures between the laps.
void writePlanarLaps(const fs::path& path) {
  std::vector<toro::Pose3> truth;
  toro::Pose3 pose;
  for (int lap = 0; lap < 2; ++lap)
    for (int side = 0; side < 4; ++side)
      for (int step = 0; step < (side % 2 ? 8 : 12); ++step) {
        truth.push_back(pose);
        pose =
            pose * toro::Pose3::fromRollPitchYaw(1, 0, 0, 0, 0, step == (side % 2 ? 7 : 11) ? M_PI / 2 : 0);
      }
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  toro::PoseGraph g;
  g.setDimension(toro::GraphDimension::k2D);
  for (std::size_t i = 0; i < truth.size(); ++i) g.addNode(static_cast<toro::NodeId>(i), toro::Pose3());
  toro::Matrix6 info = toro::Matrix6::Zero();
  info.diagonal() << 400, 400, 1, 1, 1, 4 * 2500;
  info = toro::projectInformationToPlane(info);
  const auto add = [&](std::size_t a, std::size_t b) {
    const auto d = toro::drawLastFirst<3>(n, rng);
    const toro::Pose3 noise = toro::Pose3::fromRollPitchYaw(0.05 * d[0], 0.05 * d[1], 0, 0, 0, 0.02 * d[2]);
    g.addConstraint(toro::Constraint{static_cast<toro::NodeId>(a), static_cast<toro::NodeId>(b),
                                     toro::relativePose(truth[a], truth[b]) * noise, info});
  };
  for (std::size_t i = 0; i + 1 < truth.size(); ++i) add(i, i + 1);
  for (std::size_t i = 0; i < truth.size() / 2; i += 4) add(i, i + truth.size() / 2);
  toro::writeGraph(g, path.string());
}

}  // namespace

TEST_F(ToroOptimizeCli, PlanarIsTheDefaultFor2DFilesAndTheSameAsThe3DCode) {
  const fs::path input = dir_ / "laps2d.g2o";
  writePlanarLaps(input);
  Result planar = run("-q --mode toro -i 30 " + input.string());
  ASSERT_EQ(planar.exit_code, 0) << planar.err;
  EXPECT_NE(planar.out.find("initial guess chain, planar (TORO in SE(2))"), std::string::npos) << planar.out;
  Result spatial = run("-q --mode toro -i 30 --no-planar " + input.string());
  ASSERT_EQ(spatial.exit_code, 0) << spatial.err;
  EXPECT_NE(spatial.out.find("initial guess chain, TORO in SE(3)"), std::string::npos) << spatial.out;
  const double before = numberAfter(planar.out, "before", "g2o chi2");
  const double after = numberAfter(planar.out, "after", "g2o chi2");
  EXPECT_LT(after, 0.1 * before) << planar.out;
  // One algorithm in two groups (10 significant digits printed).
  EXPECT_NEAR(numberAfter(spatial.out, "after", "g2o chi2"), after, 1e-8 * after) << spatial.out;
  // With the finish: the same optimum, and the written file is 2D either way.
  for (const std::string flag : {"", "--no-planar "}) {
    const fs::path output = dir_ / "finished.g2o";
    const Result r = run("-q " + flag + "-o " + output.string() + " " + input.string());
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const std::string text = slurp(output);
    EXPECT_NE(text.find("VERTEX_SE2 "), std::string::npos) << flag;
    EXPECT_EQ(text.find("SE3"), std::string::npos) << flag;
    const toro::PoseGraph written = toro::readGraph(output.string());
    EXPECT_NEAR(toro::g2oChi2(written), numberAfter(r.out, "after", "g2o chi2"), 1e-8 * after) << flag;
    toro::PoseGraph reference = toro::readGraph(input.string());
    toro::optimizeGraph(reference, toro::OptimizeOptions{});
    EXPECT_NEAR(toro::g2oChi2(written), toro::g2oChi2(reference), 1e-6 * toro::g2oChi2(reference)) << flag;
  }
}

TEST_F(ToroOptimizeCli, PlanarProjectsA3DInputAndWritesA2DFile) {
  const fs::path output = dir_ / "planar.g2o";
  Result r = run("--planar -o " + output.string() + " " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("projected onto the plane (--planar): z, roll and pitch dropped"), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("planar (TORO in SE(2))"), std::string::npos) << r.out;
  const std::string text = slurp(output);
  EXPECT_NE(text.find("EDGE_SE2 "), std::string::npos);
  EXPECT_EQ(text.find("SE3"), std::string::npos);
  const toro::PoseGraph written = toro::readGraph(output.string());
  ASSERT_EQ(written.dimension(), toro::GraphDimension::k2D);
  ASSERT_EQ(written.numNodes(), 125u);
  ASSERT_EQ(written.numConstraints(), 297u);
  const double after = numberAfter(r.out, "after", "g2o chi2");
  EXPECT_NEAR(toro::g2oChi2(written), after, 1e-8 * after);
  // The planar optimum of the projection, computed in this process.
  toro::PoseGraph reference = toro::projectToPlane(toro::readGraph(kSmallGrid));
  toro::optimizeGraph(reference, toro::OptimizeOptions{});
  EXPECT_NEAR(after, toro::g2oChi2(reference), 1e-6 * toro::g2oChi2(reference));
  for (const toro::Node& n : written.nodes()) {
    const toro::Pose3& p = reference.pose(n.id);
    EXPECT_NEAR((n.pose.translation() - p.translation()).norm(), 0.0, 1e-6) << n.id;
    EXPECT_TRUE(toro::isExactlyPlanar(p)) << n.id;
  }
  // The "before" line measures the projection (2D chi2 of the file's poses projected).
  r = run("-q --planar --mode toro -i 0 --initial-guess file " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double projected_chi2 = toro::g2oChi2(toro::projectToPlane(toro::readGraph(kSmallGrid)));
  EXPECT_NEAR(numberAfter(r.out, "before", "g2o chi2"), projected_chi2, 1e-8 * projected_chi2) << r.out;
  EXPECT_NE(projected_chi2, toro::g2oChi2(toro::readGraph(kSmallGrid)));
  r = run("--planar --no-planar " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err, "toro_optimize: --planar and --no-planar exclude each other (see --help)\n");
}

TEST_F(ToroOptimizeCli, OptimisesReportsEveryIterationAndWritesTheResult) {
  const fs::path output = dir_ / "result.g2o";
  const Result r = run("--mode toro -i 5 -o " + output.string() + " " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.err.empty()) << r.err;
  EXPECT_NE(r.out.find("125 vertices, 297 edges"), std::string::npos) << r.out;
  EXPECT_EQ(linesStartingWith(r.out, "tree ").size(), 5u) << r.out;

  const double before = numberAfter(r.out, "before", "g2o chi2");
  const double after = numberAfter(r.out, "after", "g2o chi2");
  ASSERT_TRUE(std::isfinite(before) && std::isfinite(after)) << r.out;
  EXPECT_LT(after, before);
  // The printed final chi2 is the chi2 of the written graph (g2o at 17 digits is exact).
  const toro::PoseGraph written = toro::readGraph(output.string());
  EXPECT_NEAR(toro::g2oChi2(written), after, 1e-8 * after);
  EXPECT_EQ(written.numNodes(), 125u);
  EXPECT_EQ(written.numConstraints(), 297u);
  // The last per-iteration line reports the same chi2 as the summary.
  const std::string last = linesStartingWith(r.out, "tree ").back();
  std::istringstream fields(last);
  std::string phase;
  double iteration = 0, seconds = 0, chi2 = 0;
  fields >> phase >> iteration >> seconds >> chi2;
  EXPECT_EQ(iteration, 5);
  EXPECT_NEAR(chi2, after, 1e-7 * after);
}

TEST_F(ToroOptimizeCli, QuietPrintsOnlyTheSummary) {
  const Result r = run("--mode toro -q -i 3 --initial-guess file " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(linesStartingWith(r.out, "tree ").empty()) << r.out;
  ASSERT_EQ(linesStartingWith(r.out, "summary:").size(), 1u) << r.out;
  EXPECT_NE(r.out.find("3 iterations, initial guess file"), std::string::npos) << r.out;
  // With the file's poses the chi2 before is the chi2 of the file as given.
  const double file_chi2 = toro::g2oChi2(toro::readGraph(kSmallGrid));
  EXPECT_NEAR(numberAfter(r.out, "before", "g2o chi2"), file_chi2, 1e-9 * file_chi2);  // printed to 10 digits
}

TEST_F(ToroOptimizeCli, DefaultModeRunsTreeThenFinishToTheBestKnownChi2) {
  const fs::path output = dir_ / "finished.g2o";
  const Result r = run("-o " + output.string() + " " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> tree = linesStartingWith(r.out, "tree ");
  const std::vector<std::string> finish = linesStartingWith(r.out, "finish ");
  ASSERT_FALSE(tree.empty()) << r.out;
  ASSERT_FALSE(finish.empty()) << r.out;
  EXPECT_LT(r.out.find(tree.back()), r.out.find(finish.front()));  // the tree phase comes first
  EXPECT_NE(r.out.find("mode    toro+finish"), std::string::npos) << r.out;
  // REFERENCE.md (B): best known g2o chi2 of smallGrid3D.g2o.
  const double after = numberAfter(r.out, "after", "g2o chi2");
  EXPECT_NEAR(after, 458.154, 1e-4 * 458.154) << r.out;
  EXPECT_NEAR(toro::g2oChi2(toro::readGraph(output.string())), after, 1e-8 * after);
  std::istringstream last(finish.back());
  std::string phase;
  double iteration = 0, seconds = 0, chi2 = 0;
  last >> phase >> iteration >> seconds >> chi2;
  EXPECT_NEAR(chi2, after, 1e-7 * after);
}

TEST_F(ToroOptimizeCli, FinishOnlyFromTheFilePosesAndBadFinishOptions) {
  Result r = run("-q --mode finish --initial-guess file " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("finish: 0 tree iterations"), std::string::npos) << r.out;
  EXPECT_NEAR(numberAfter(r.out, "after", "g2o chi2"), 458.154, 1e-4 * 458.154) << r.out;
  r = run("--mode newton " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err, "toro_optimize: --mode must be toro, finish or toro+finish, got 'newton' (see --help)\n");
  r = run("--switch-decrease -1 " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--switch-decrease needs a non-negative number"), std::string::npos) << r.err;
  r = run("--finish-iterations 0 " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("finish: max_iterations must be at least 1"), std::string::npos) << r.err;
}

// --solver-threads reaches the finish (its summary names the count in force) and is validated.
TEST_F(ToroOptimizeCli, SolverThreadsDefaultIsOneAndTheOptionIsParsed) {
  Result r = run("-q --mode finish --initial-guess file " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("solver threads 1)"), std::string::npos) << r.out;
  r = run("-q --solver-threads 2 --mode finish --initial-guess file " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("solver threads 2)"), std::string::npos) << r.out;
  // The same minimum whatever the threads.
  EXPECT_NEAR(numberAfter(r.out, "after", "g2o chi2"), 458.154, 1e-4 * 458.154) << r.out;
  r = run("-q --solver-threads 0 --mode finish --initial-guess file " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("solver threads library defaults)"), std::string::npos) << r.out;
  r = run("--solver-threads -1 " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err, "toro_optimize: --solver-threads needs a non-negative integer, got '-1' (see --help)\n");
  r = run("--solver-threads 5000 " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--solver-threads needs at most 1024, got 5000"), std::string::npos) << r.err;
  r = run("--help");
  EXPECT_NE(r.out.find("--solver-threads N"), std::string::npos);
}

TEST_F(ToroOptimizeCli, MalformedFileGivesFileLineMessageAndNonZeroExit) {
  const fs::path bad = dir_ / "bad.g2o";
  std::ofstream(bad) << "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
                        "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 abc 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n";
  const Result r = run(bad.string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(r.err,
            "toro_optimize: " + bad.string() + ":3: EDGE_SE3:QUAT field 9 (qw): 'abc' is not a number\n");
  EXPECT_TRUE(r.out.empty()) << r.out;
}

TEST_F(ToroOptimizeCli, BadArgumentsAndMissingFile) {
  Result r = run("-i many " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err, "toro_optimize: -i needs a non-negative integer, got 'many' (see --help)\n");
  r = run("--toro-info-order sideways " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--toro-info-order must be translation-first or rotation-first"), std::string::npos);
  r = run((dir_ / "missing.g2o").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("missing.g2o: cannot open for reading: No such file or directory"), std::string::npos)
      << r.err;
  r = run("--help");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out.rfind("usage: toro_optimize", 0), 0u);
}

// smallGrid3D with two wrong loop closures appended: far-apart nodes claimed to be in one place,
// turned upside down, with confident covariances.
void writeSmallGridWithWrongLoopClosures(const fs::path& path) {
  std::ifstream in(kSmallGrid);
  std::ofstream out(path);
  out << in.rdbuf();
  out << "EDGE_SE3:QUAT 3 120 0 0 0 1 0 0 0 100 0 0 0 0 0 100 0 0 0 0 100 0 0 0 400 0 0 400 0 400\n";
  out << "EDGE_SE3:QUAT 7 98 0.5 0 0 0 1 0 0 100 0 0 0 0 0 100 0 0 0 0 100 0 0 0 400 0 0 400 0 400\n";
}

TEST_F(ToroOptimizeCli, RobustRejectsAddedWrongLoopClosuresAndWritesThem) {
  const toro::PoseGraph g = toro::readGraph(kSmallGrid);
  const fs::path input = dir_ / "with_wrong.g2o";
  writeSmallGridWithWrongLoopClosures(input);
  const fs::path rejected = dir_ / "rejected.txt";
  const fs::path robust_out = dir_ / "robust.g2o", plain_out = dir_ / "plain.g2o";
  Result r = run("-q --robust --rejected-out " + rejected.string() + " -o " + robust_out.string() + " " +
                 input.string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("robust  kernel dcs"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(": 2 of 175 loop closures rejected"), std::string::npos) << r.out;
  std::ifstream lines(rejected);
  std::string all((std::istreambuf_iterator<char>(lines)), std::istreambuf_iterator<char>());
  EXPECT_EQ(all, "3 120\n7 98\n");
  // The robust result is the clean file's optimum; the plain one is bent by the wrong ones.
  r = run("-q -o " + plain_out.string() + " " + input.string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  toro::PoseGraph clean = g;
  const toro::PoseGraph robust = toro::readGraph(robust_out.string());
  toro::PoseGraph clean_result = toro::readGraph(kSmallGrid);
  r = run("-q -o " + (dir_ / "clean.g2o").string() + " " + kSmallGrid);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  clean_result = toro::readGraph((dir_ / "clean.g2o").string());
  EXPECT_LT(toro::alignedPositionRmse(robust, clean_result), 1e-3);
  EXPECT_GT(toro::alignedPositionRmse(toro::readGraph(plain_out.string()), clean_result), 0.05);
  // Options that make no sense are refused.
  r = run("--rejected-out " + rejected.string() + " " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--rejected-out needs --robust"), std::string::npos) << r.err;
  r = run("--robust-kernel tukey " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--robust-kernel must be dcs, cauchy or huber"), std::string::npos) << r.err;
  r = run("--robust-width -1 " + kSmallGrid);
  EXPECT_EQ(r.exit_code, 2);
  (void)clean;
}

TEST_F(ToroOptimizeCli, RobustRunPrintsOneTimelineFromTheOdometryStart) {
  // --robust tries more than one start here (the wrong loop closures make the first one's map
  // suspect).  The report is still one run: one header, times from the first start on, never
  // negative or going back, and "before" is the robust initial guess (the odometry chained), not
  // the map of a later start.  (Setup and "before" were once taken from the last start: the
  // lines after it began below zero and the first start's work was left out of the time.)
  const fs::path input = dir_ / "with_wrong.g2o";
  writeSmallGridWithWrongLoopClosures(input);
  const Result r = run("--robust " + input.string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(linesStartingWith(r.out, "phase ").size(), 1u) << r.out;
  const std::vector<std::string> starts = linesStartingWith(r.out, "start ");
  ASSERT_GE(starts.size(), 2u) << r.out;  // the dead-reckoning start ran as well
  double previous = 0.0;
  std::size_t timed = 0;
  std::istringstream lines(r.out);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.rfind("start ", 0) != 0 && line.rfind("tree ", 0) != 0 && line.rfind("finish ", 0) != 0)
      continue;
    std::istringstream fields(line);
    std::string phase;
    double iteration = 0, seconds = 0;
    fields >> phase >> iteration >> seconds;
    EXPECT_GE(seconds, previous) << line;
    previous = seconds;
    ++timed;
  }
  EXPECT_GT(timed, starts.size());
  // The optimisation time covers every line's.
  EXPECT_GE(numberAfter(r.out, "time", "optimisation"), previous - 1e-6) << r.out;
  const Result odometry = run("-q --mode toro -i 0 --initial-guess odometry " + input.string());
  ASSERT_EQ(odometry.exit_code, 0) << odometry.err;
  const double odometry_chi2 = numberAfter(odometry.out, "before", "g2o chi2");
  EXPECT_NEAR(numberAfter(r.out, "before", "g2o chi2"), odometry_chi2, 1e-9 * odometry_chi2) << r.out;
  // The first start line is that same map.
  std::istringstream first(starts.front());
  std::string phase;
  double iteration = 0, seconds = 0, chi2 = 0;
  first >> phase >> iteration >> seconds >> chi2;
  EXPECT_EQ(seconds, 0.0);
  EXPECT_NEAR(chi2, odometry_chi2, 1e-7 * odometry_chi2);
}
