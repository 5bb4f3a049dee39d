// toro_offline: the bundled sample (made at build time by graph_to_bag) through the node's
// Pipeline rebuilds the bag's graph node for node, beats raw odometry by a wide margin against
// the truth, and the command-line tool writes consistent outputs; bad bags give errors naming
// the bag and topic.
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <tuple>

#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <std_msgs/String.h>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/offline/graph_to_bag.h"
#include "toro_ros/offline/offline_output.h"
#include "toro_ros/offline/offline_runner.h"
#include "toro_ros/offline/sample_graph.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {
namespace {

namespace fs = std::filesystem;

const std::string kSample = std::string(TORO_SAMPLE_DIR) + "/sample";
const std::string kReplayConfig = std::string(TORO_SOURCE_DIR) + "/config/replay_sample.yaml";

OfflineOptions sampleOptions() {
  OfflineOptions o;
  o.bag_path = kSample + ".bag";
  o.config_path = kReplayConfig;
  o.truth_path = kSample + ".truth.g2o";
  o.progress = false;
  o.iteration_curve = false;
  return o;
}

TEST(OfflineRunner, SampleRebuildsTheBagsGraphNodeForNode) {
  OfflineRunner runner(sampleOptions());
  const OfflineRun run = runner.run();
  const toro::PoseGraph expected = toro::readGraph(kSample + ".odometry.g2o");
  const Sidecar stamps = readSidecar(sidecarPath(kSample + ".odometry.g2o"));
  const toro::PoseGraph& g = runner.pipeline().graph();
  ASSERT_EQ(g.numNodes(), expected.numNodes());
  ASSERT_EQ(g.numConstraints(), expected.numConstraints());
  const auto& records = runner.pipeline().keyframes().records();
  for (std::size_t i = 0; i < records.size(); ++i)
    EXPECT_EQ(records[i].stamp, stamps.keyframes[i].stamp) << i;
  // Constraints in a different order (loop closures arrive after later odometry): match by ends.
  for (const toro::Constraint& e : expected.constraints()) {
    const auto it = std::find_if(g.constraints().begin(), g.constraints().end(),
                                 [&](const toro::Constraint& c) { return c.from == e.from && c.to == e.to; });
    ASSERT_NE(it, g.constraints().end()) << e.from << " -> " << e.to;
    EXPECT_LT((it->measurement.translation() - e.measurement.translation()).norm(), 1e-9);
    EXPECT_LT(toro::relativePose(it->measurement, e.measurement).angle(), 1e-9);
    EXPECT_LT((it->information - e.information).norm() / e.information.norm(), 1e-6)
        << e.from << " -> " << e.to;
  }
  EXPECT_EQ(runner.pipeline().status().counters.loop_closures_refused, 0u);
  EXPECT_EQ(run.messages_by_topic.at("/loop_closure"), stamps.loop_closures.size());
}

// --duration then --start with autosave_path / load_path: the second run resumes the first's
// graph and, as no message is lost in between, ends with the same keyframes and constraints as
// one run over the whole bag.
TEST(OfflineRunner, SplitRunResumedFromTheAutosaveEqualsOneRun) {
  const fs::path dir = fs::temp_directory_path() / ("toro_offline_split_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string map = (dir / "map.g2o").string();
  const std::string config = (dir / "config.yaml").string();
  {
    std::ifstream in(kReplayConfig);
    std::ofstream out(config);
    out << in.rdbuf() << "\nautosave_path: " << map << "\nload_path: " << map << "\n";
  }
  OfflineOptions whole_options = sampleOptions();
  whole_options.final_iterations = 0;
  OfflineRunner whole(whole_options);
  const OfflineRun all = whole.run();

  OfflineOptions first_options = whole_options;
  first_options.config_path = config;
  first_options.duration_sec = all.bag_duration_sec / 2;
  OfflineRunner first(first_options);
  const OfflineRun part = first.run();
  EXPECT_LT(part.messages, all.messages);
  EXPECT_GT(part.messages, all.messages / 3);
  ASSERT_EQ(first.pipeline().autosave(), "");  // what toro_offline does at the end

  OfflineOptions second_options = first_options;
  second_options.duration_sec = 0;
  second_options.start_sec = first_options.duration_sec;
  OfflineRunner second(second_options);  // load_path: resumes the first run's graph
  ASSERT_EQ(second.pipeline().keyframes().size(), first.pipeline().keyframes().size());
  const OfflineRun rest = second.run();
  EXPECT_GE(part.messages + rest.messages, all.messages);  // the boundary message may be read twice
  const auto& a = whole.pipeline().keyframes().records();
  const auto& b = second.pipeline().keyframes().records();
  ASSERT_EQ(b.size(), a.size());
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_EQ(b[i].stamp, a[i].stamp) << i;
  EXPECT_EQ(second.pipeline().graph().numConstraints(), whole.pipeline().graph().numConstraints());
  EXPECT_EQ(second.pipeline().status().counters.loop_closures_applied +
                first.pipeline().status().counters.loop_closures_applied,
            whole.pipeline().status().counters.loop_closures_applied);
  fs::remove_all(dir);
}

TEST(OfflineRunner, SampleBeatsOdometryByAWideMarginAgainstTruth) {
  const OfflineOptions options = sampleOptions();
  OfflineRunner runner(options);
  const OfflineSummary s = summarize(runner, runner.run(), options);
  ASSERT_TRUE(s.has_score);
  EXPECT_EQ(s.score.corrected.poses, 144u);
  // Stated margin: at least 3x lower position RMSE than the odometry, and a chi2 10x lower.
  EXPECT_LT(s.score.corrected.rmse_m, s.score.odometry.rmse_m / 3) << describeSummary(s);
  EXPECT_LT(s.score.corrected.mean_rotation_rad, s.score.odometry.mean_rotation_rad / 3)
      << describeSummary(s);
  EXPECT_LT(s.chi2_corrected, s.chi2_odometry / 10) << describeSummary(s);
}

// The trace compared between runs (bench/compare_robust_runs.py): each sample is the robot where the
// node would have shown it, its map_T_odom then applied to that odometry message's pose, so another
// run's correction can be applied to the same odometry.
TEST(OfflineRunner, EachTraceSampleIsItsCorrectionAppliedToThatOdometryMessage) {
  const OfflineOptions options = sampleOptions();
  OfflineRunner runner(options);
  const OfflineRun run = runner.run();
  rosbag::Bag bag(options.bag_path, rosbag::bagmode::Read);
  std::vector<std::pair<double, toro::Vector3>> odometry;
  for (const rosbag::MessageInstance& m : rosbag::View(bag))
    if (const auto o = m.instantiate<nav_msgs::Odometry>())
      odometry.emplace_back(m.getTime().toSec(), poseFromMsg(o->pose.pose).translation());
  ASSERT_EQ(run.robot_in_map.size(), odometry.size());
  double largest_correction = 0.0;
  for (std::size_t i = 0; i < odometry.size(); ++i) {
    const OfflineRun::RobotInMap& r = run.robot_in_map[i];
    EXPECT_EQ(r.stamp_sec, odometry[i].first);
    EXPECT_LT((r.map_T_odom * odometry[i].second - r.position).norm(), 1e-9) << "sample " << i;
    largest_correction = std::max(largest_correction, r.map_T_odom.translation().norm());
  }
  EXPECT_GT(largest_correction, 0.1);  // the sample's odometry drifts: the correction is not the identity
}

// The optimality samples: the published map against the optimum of the graph so far, plain (every
// loop closure at full weight) and under the map's robust weights (what its finishes minimise).
// Neither optimum lies above its published value; without robust weights the two are the same.
TEST(OfflineRunner, OptimalitySamplesHoldThePlainAndTheWeightedOptimum) {
  const auto samples = [](const std::string& config) {
    OfflineOptions o = sampleOptions();
    o.config_path = config;
    o.optimality_every_sec = 5.0;
    OfflineRunner runner(o);
    return runner.run().optimality;
  };
  const auto robust = samples(kReplayConfig);
  ASSERT_GE(robust.size(), 5u);
  std::size_t with_loop_closures = 0;
  for (const OfflineRun::Optimality& s : robust) {
    EXPECT_LE(s.optimum_chi2, s.published_chi2 * (1 + 1e-9) + 1e-12) << s.stamp_sec;
    EXPECT_LE(s.weighted_optimum_chi2, s.published_weighted_chi2 * (1 + 1e-9) + 1e-12) << s.stamp_sec;
    // Weights only take information away: the weighted objective never exceeds the plain one.
    EXPECT_LE(s.published_weighted_chi2, s.published_chi2 * (1 + 1e-9) + 1e-12) << s.stamp_sec;
    with_loop_closures += s.optimum_chi2 > 1e-6;
  }
  EXPECT_GE(with_loop_closures, 3u);
  const fs::path plain_config =
      fs::temp_directory_path() / ("toro_offline_plain_" + std::to_string(::getpid()) + ".yaml");
  {
    std::ifstream in(kReplayConfig);
    std::ofstream out(plain_config);
    out << in.rdbuf() << "\nrobust_loop_closures: false\n";
  }
  const auto plain = samples(plain_config.string());
  fs::remove(plain_config);
  ASSERT_FALSE(plain.empty());
  for (const OfflineRun::Optimality& s : plain) {
    EXPECT_NEAR(s.published_weighted_chi2, s.published_chi2, 1e-9 * s.published_chi2 + 1e-12) << s.stamp_sec;
    EXPECT_NEAR(s.weighted_optimum_chi2, s.optimum_chi2, 1e-6 * s.optimum_chi2 + 1e-9) << s.stamp_sec;
  }
}

// Samples placed after loop closures (the curve target's "within 2 s after each loop closure"):
// each one comes at least the delay after the first loop closure since the previous sample, never
// closer to that sample than the period, and says how long ago the newest loop closure came.
TEST(OfflineRunner, OptimalitySamplesAfterLoopClosuresFollowThemAndKeepTheirSpacing) {
  OfflineOptions o = sampleOptions();
  o.optimality_every_sec = 5.0;
  o.optimality_after_loop_closure_sec = 2.0;
  OfflineRunner runner(o);
  const auto samples = runner.run().optimality;
  ASSERT_GE(samples.size(), 3u);
  // Message times of the bag's loop closures, from its first message on the input topics.
  rosbag::Bag bag(o.bag_path);
  rosbag::View inputs(bag, rosbag::TopicQuery(std::vector<std::string>{"/odom", "/loop_closure"}));
  std::vector<double> loop_closures;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery("/loop_closure")))
    loop_closures.push_back((m.getTime() - inputs.getBeginTime()).toSec());
  ASSERT_GE(loop_closures.size(), 5u);
  double previous = -1e9;
  for (const OfflineRun::Optimality& sample : samples) {
    const auto first_since = std::upper_bound(loop_closures.begin(), loop_closures.end(), previous);
    ASSERT_NE(first_since, loop_closures.end()) << sample.stamp_sec;
    EXPECT_GE(sample.stamp_sec, *first_since + 2.0 - 1e-9);
    EXPECT_GE(sample.stamp_sec, previous + 5.0 - 1e-9);
    const double newest =
        *(std::upper_bound(loop_closures.begin(), loop_closures.end(), sample.stamp_sec) - 1);
    EXPECT_NEAR(sample.since_loop_closure_sec, sample.stamp_sec - newest, 1e-6) << sample.stamp_sec;
    previous = sample.stamp_sec;
  }
  OfflineOptions no_period = o;
  no_period.optimality_every_sec = 0.0;
  EXPECT_NE(no_period.validate(), "");
}

// The printed summary says how many applied loop closures ended out of the map (weight below
// 0.5) and how many of them the support never released: "applied" alone reads as corrected.
TEST(OfflineRunner, SummaryNamesTheLoopClosuresThatEndedOutOfTheMap) {
  OfflineSummary s;
  s.status.counters.loop_closures_received = s.status.counters.loop_closures_applied = 5;
  EXPECT_EQ(describeSummary(s).find("weighted below 0.5"), std::string::npos);
  s.status.counters.loop_closures_held = 3;
  s.status.counters.loop_closures_released = 2;
  s.status.down_weighted.resize(2);
  EXPECT_NE(
      describeSummary(s).find("of them 2 weighted below 0.5 at the end (robust), 1 of those held since they "
                              "arrived"),
      std::string::npos)
      << describeSummary(s);
}

TEST(OfflineRunner, ConstantSpeedBagWithDefaultConfigStillCorrects) {
  // A bag whose keyframes are not on the node's keyframe grid (spacing from the speed): the node
  // picks its own keyframes and matches loop-closure stamps within its tolerance.
  const fs::path dir = fs::temp_directory_path() / ("toro_offline_speed_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  GraphToBagOptions g;
  g.input_path = std::string(TORO_SAMPLE_DIR) + "/sample_graph.g2o";
  g.ground_truth_path = g.input_path;
  g.output_bag = (dir / "speed.bag").string();
  g.speed_mps = 2.0;
  graphToBag(g);
  OfflineOptions o;
  o.bag_path = g.output_bag;
  o.truth_path = (dir / "speed.truth.g2o").string();
  o.progress = false;
  o.iteration_curve = false;
  OfflineRunner runner(o);
  const OfflineSummary s = summarize(runner, runner.run(), o);
  EXPECT_LT(s.score.corrected.rmse_m, s.score.odometry.rmse_m / 2) << describeSummary(s);
  fs::remove_all(dir);
}

TEST(OfflineRunner, WrongMessageTypeNamesBagAndTopic) {
  const fs::path bag_path =
      fs::temp_directory_path() / ("toro_offline_bad_" + std::to_string(::getpid()) + ".bag");
  {
    rosbag::Bag bag(bag_path.string(), rosbag::bagmode::Write);
    std_msgs::String s;
    s.data = "not odometry";
    bag.write("/odom", ros::Time(5.0), s);
  }
  OfflineOptions o;
  o.bag_path = bag_path.string();
  o.progress = false;
  OfflineRunner runner(o);
  try {
    runner.run();
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(bag_path.string()), std::string::npos) << what;
    EXPECT_NE(what.find("/odom"), std::string::npos) << what;
    EXPECT_NE(what.find("std_msgs/String"), std::string::npos) << what;
  }
  fs::remove(bag_path);
}

TEST(OfflineRunner, UnknownParameterKeyIsRefusedNamingTheFile) {
  const fs::path p = fs::temp_directory_path() / ("toro_offline_cfg_" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(p) << "keyframe_distanse_m: 0.5\n";
  try {
    loadNodeOptionsFile(p.string());
    FAIL() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("keyframe_distanse_m"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(p.string()), std::string::npos) << e.what();
  }
  fs::remove(p);
}

TEST(OfflineRunner, EveryShippedParameterFileLoads) {
  // config/*.yaml and bench/*.yaml are all node parameter files: no unknown key, no bad value.
  std::size_t files = 0;
  for (const char* dir : {"/config", "/bench"}) {
    for (const auto& entry : fs::directory_iterator(std::string(TORO_SOURCE_DIR) + dir)) {
      if (entry.path().extension() != ".yaml") continue;
      EXPECT_NO_THROW(loadNodeOptionsFile(entry.path().string())) << entry.path();
      ++files;
    }
  }
  EXPECT_GE(files, 3u);  // map_corrector, replay_sample, offline_period_0.1s
}

// The finish's threads: the config's finish_threads as the node sets them, --solver-threads first.
TEST(OfflineRunner, SetsTheFinishThreadsOfTheConfigOrTheCommandLine) {
  const fs::path config =
      fs::temp_directory_path() / ("toro_offline_threads_" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(config) << "finish_threads: 3\n";
  OfflineOptions o;
  o.bag_path = kSample + ".bag";
  o.config_path = config.string();
  OfflineRunner from_config(o);
  EXPECT_EQ(toro::solverThreads(), 3);
  o.solver_threads = 2;
  OfflineRunner from_option(o);
  EXPECT_EQ(toro::solverThreads(), 2);
  o.solver_threads = -1;
  EXPECT_THROW(OfflineRunner bad(o), std::invalid_argument);
  std::ofstream(config) << "finish_threads: -2\n";
  o.solver_threads.reset();
  EXPECT_THROW(OfflineRunner bad(o), std::invalid_argument);
  fs::remove(config);
  toro::setSolverThreads(toro::kDefaultSolverThreads);
}

TEST(ToroOfflineTool, SolverThreadsOptionIsParsedAndValidated) {
  const fs::path log = fs::temp_directory_path() / ("toro_offline_threads_" + std::to_string(::getpid()) + ".log");
  const auto run = [&](const std::string& args) {
    const std::string cmd = std::string(TORO_OFFLINE_BIN) + " " + args + " > " + log.string() + " 2>&1";
    const int status = std::system(cmd.c_str());
    std::ifstream in(log);
    std::stringstream text;
    text << in.rdbuf();
    return std::make_pair(WIFEXITED(status) ? WEXITSTATUS(status) : -1, text.str());
  };
  auto [code, text] = run(kSample + ".bag --solver-threads many");
  EXPECT_EQ(code, 2);
  EXPECT_NE(text.find("--solver-threads: expected an integer, got 'many'"), std::string::npos) << text;
  std::tie(code, text) = run(kSample + ".bag --solver-threads -1");
  EXPECT_EQ(code, 2);
  EXPECT_NE(text.find("solver threads must be in [0, 1024]"), std::string::npos) << text;
  std::tie(code, text) = run("--help");
  EXPECT_EQ(code, 0);
  EXPECT_NE(text.find("--solver-threads"), std::string::npos) << text;
  fs::remove(log);
}

TEST(ToroOfflineTool, WritesGraphBagAndSummaryThatAgree) {
  const fs::path out = fs::temp_directory_path() / ("toro_offline_tool_" + std::to_string(::getpid()));
  const std::string cmd = std::string(TORO_OFFLINE_BIN) + " " + kSample + ".bag --config " + kReplayConfig +
                          " --quiet --output-dir " + out.string() + " > " + (out.string() + ".log") + " 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  for (const char* f : {"corrected.g2o", "corrected.g2o.stamps", "corrected_poses.bag", "summary.json"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  // The summary's chi2 is the chi2 of the written graph.
  std::ifstream in(out / "summary.json");
  std::stringstream json;
  json << in.rdbuf();
  const std::string text = json.str();
  const auto at = text.find("\"chi2_corrected\": ");
  ASSERT_NE(at, std::string::npos);
  const double chi2 = std::stod(text.substr(at + 18));
  EXPECT_NEAR(chi2, toro::g2oChi2(toro::readGraph((out / "corrected.g2o").string())), 1e-6 * chi2);
  EXPECT_NE(text.find("\"score\""), std::string::npos) << "truth beside the bag was not picked up";
  // One corrected pose per keyframe in the output bag.
  rosbag::Bag bag((out / "corrected_poses.bag").string(), rosbag::bagmode::Read);
  EXPECT_EQ(rosbag::View(bag, rosbag::TopicQuery("/corrected_pose")).size(), 144u);
  EXPECT_EQ(rosbag::View(bag, rosbag::TopicQuery("/tf")).size(), 144u);
  // The plot script draws the summary into a PNG.
  const std::string plot = "/usr/bin/python3 " + std::string(TORO_SOURCE_DIR) +
                           "/scripts/plot_trajectory.py " + (out / "summary.json").string() + " -o " +
                           (out / "t.png").string() + " > /dev/null";
  ASSERT_EQ(std::system(plot.c_str()), 0) << plot;
  std::ifstream png(out / "t.png", std::ios::binary);
  char magic[8] = {};
  png.read(magic, 8);
  EXPECT_EQ(std::string(magic + 1, 3), "PNG");
  EXPECT_GT(fs::file_size(out / "t.png"), 20000u);
  fs::remove_all(out);
  fs::remove(out.string() + ".log");
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros
