// Autosave, load on start and the resume of a loaded map by new odometry (pipeline_persistence.cpp),
// plus the refusals that protect a resumed map.  The process-level kill -9 test is
// test/offline/test_resume_after_kill.cpp.
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/pipeline/persistence.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;
using toro_ros::testing::drain;
using toro_ros::testing::DriftScenario;
using toro_ros::testing::makeDriftingSquare;
using toro_ros::testing::odometryMsg;
using toro_ros::testing::trueLoopClosure;

namespace {

namespace fs = std::filesystem;

// A fresh directory, removed with everything in it at the end of the test.
struct TempDir {
  TempDir() {
    char t[] = "/tmp/toro_persistence_XXXXXX";
    path = mkdtemp(t);
  }
  ~TempDir() { fs::remove_all(path); }
  std::string file(const std::string& name) const { return path + "/" + name; }
  std::string path;
};

PipelineOptions options(const std::string& autosave_path = "", double period = 4.5) {
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.optimization.full_every_keyframes = 10;
  o.optimization.full_iterations = 10;
  o.persistence.autosave_path = autosave_path;
  o.persistence.autosave_period_sec = period;
  return o;
}

std::uint64_t count(const Pipeline& p, const std::string& reason) {
  const auto& c = p.status().counters.refused_by_reason;
  const auto it = c.find(reason);
  return it == c.end() ? 0 : it->second;
}

// Feeds odometry [from, to) and, at the end of lap 2, the loop closure to the start.
void feed(Pipeline& p, const DriftScenario& sc, std::size_t from, std::size_t to) {
  const std::size_t last = sc.odometry.size() - 1;
  for (std::size_t i = from; i < to; ++i) {
    p.handleOdometry(sc.odometry[i]);
    if (i == last) p.handleLoopClosure(trueLoopClosure(sc, 0, last));
    drain(p);
  }
}

double newestError(Pipeline& p, const DriftScenario& sc) {
  return (p.makeSnapshot()->keyframes.back().map_T_base.translation() - sc.truth.back().translation()).norm();
}

}  // namespace

TEST(Persistence, AutosaveEveryPeriodOfMessageTimeOnlyWhenTheGraphChanged) {
  TempDir dir;
  const std::string path = dir.file("auto.g2o");
  const DriftScenario sc = makeDriftingSquare();  // 40 s of odometry from t = 100 s
  Pipeline p(options(path, 4.5));
  feed(p, sc, 0, sc.odometry.size());
  // Saves when 4.5 s of message time passed since the last one: 8 in 40 s (the 9th would need 40.5).
  EXPECT_EQ(p.status().counters.autosaves, 8u);
  EXPECT_EQ(p.status().counters.autosave_failures, 0u);
  // What is on disk is a complete graph + sidecar no older than one period.
  Pipeline q(options());
  ASSERT_EQ(q.loadGraph(path), "");
  const double saved_newest = q.keyframes().newest().stamp.toSec();
  EXPECT_GE(saved_newest, sc.odometry.back().header.stamp.toSec() - 4.5 - 0.5);
  // No temporary files left behind.
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir.path)) files += e.is_regular_file();
  EXPECT_EQ(files, 2u);

  // Standing still for 20 s: the loop closure's correction at t = 140 is saved once, a period
  // after the last save; after that nothing changes and nothing is written.
  const ros::Time end = sc.odometry.back().header.stamp;
  const toro::Pose3 here = poseFromMsg(sc.odometry.back().pose.pose);
  for (int i = 1; i <= 200; ++i) p.handleOdometry(odometryMsg(end + ros::Duration(0.1 * i), here));
  EXPECT_EQ(p.status().counters.autosaves, 9u);
  // autosave() (the node's shutdown) writes only when something changed since the last save.
  EXPECT_EQ(p.autosave(), "");
  EXPECT_EQ(p.status().counters.autosaves, 9u);
  p.handleOdometry(
      odometryMsg(end + ros::Duration(21.0), toro::Pose3::fromRollPitchYaw(1, 0, 0, 0, 0, 0) * here));
  EXPECT_EQ(p.autosave(), "");
  EXPECT_EQ(p.status().counters.autosaves, 10u);
  Pipeline r(options());
  ASSERT_EQ(r.loadGraph(path), "");
  EXPECT_EQ(r.graph().numNodes(), p.graph().numNodes());
  EXPECT_EQ(r.graph().numConstraints(), p.graph().numConstraints());
}

TEST(Persistence, AutosaveFailureIsCountedAndWarnedAndTheRunGoesOn) {
  std::vector<std::string> warnings;
  const std::string path = "/nonexistent_toro_dir/auto.g2o";
  Pipeline p(options(path, 2.0), [&](const std::string& w) { warnings.push_back(w); });
  const DriftScenario sc = makeDriftingSquare(1);
  feed(p, sc, 0, sc.odometry.size());
  EXPECT_GE(p.status().counters.autosave_failures, 5u);  // every 2 s of 20 s (the graph always grew)
  EXPECT_EQ(p.status().counters.autosaves, 0u);
  EXPECT_GT(p.keyframes().size(), 20u);
  const auto failed = std::find_if(warnings.begin(), warnings.end(), [](const std::string& w) {
    return w.find("autosave failed") != std::string::npos;
  });
  ASSERT_NE(failed, warnings.end());
  EXPECT_NE(failed->find(path), std::string::npos) << *failed;
  EXPECT_NE(p.autosave(), "");
}

TEST(Persistence, LoadOnStartMissingIsANewMapMalformedThrowsWithTheLine) {
  TempDir dir;
  Pipeline p(options());
  EXPECT_EQ(loadOnStart(p, ""), "");
  const std::string missing = dir.file("none.g2o");
  EXPECT_NE(loadOnStart(p, missing).find("starting a new map"), std::string::npos);
  EXPECT_TRUE(p.graph().empty());

  const std::string bad = dir.file("bad.g2o");
  std::ofstream(bad) << "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 zero 1\n";
  try {
    loadOnStart(p, bad);
    FAIL() << "a malformed load_path must throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(bad + ":2"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(p.graph().empty());  // and nothing was half-loaded
}

// A run killed at sample `kill` restarts from its last autosave, and the replay goes on: with the
// whole replay fed again from its start (refused up to the saved keyframes) or only what came
// after the kill, the result matches the uninterrupted run.
TEST(Persistence, ResumeAfterAKillMatchesTheUninterruptedRun) {
  const DriftScenario sc = makeDriftingSquare();
  Pipeline whole(options());
  feed(whole, sc, 0, sc.odometry.size());
  const double whole_error = newestError(whole, sc);

  for (const bool replay_from_start : {true, false}) {
    SCOPED_TRACE(replay_from_start ? "replay from the start" : "replay goes on after the kill");
    TempDir dir;
    const std::string path = dir.file("auto.g2o");
    const std::size_t kill = 250;  // 25 s into the 40 s run; autosaves every 4.5 s
    {
      Pipeline killed(options(path, 4.5));
      feed(killed, sc, 0, kill);
      // Destroyed without autosave(): like kill -9, only the periodic saves are on disk.
    }
    Pipeline resumed(options(path, 4.5));
    ASSERT_NE(loadOnStart(resumed, path).find("resumed"), std::string::npos);
    const double saved_newest = resumed.keyframes().newest().stamp.toSec();
    const double kill_stamp = sc.odometry[kill - 1].header.stamp.toSec();
    EXPECT_LE(kill_stamp - saved_newest, 4.5 + 0.5);  // at most one period (+ a keyframe spacing) lost
    const std::size_t loaded = resumed.keyframes().size();
    feed(resumed, sc, replay_from_start ? 0 : kill, sc.odometry.size());

    std::size_t already_in = 0;
    for (std::size_t i = 0; i < kill; ++i) already_in += sc.odometry[i].header.stamp.toSec() <= saved_newest;
    EXPECT_EQ(count(resumed, "odometry: before the resumed map"), replay_from_start ? already_in : 0u);
    EXPECT_EQ(count(resumed, "odometry: out of order"), 0u);
    EXPECT_EQ(resumed.status().counters.time_jump_resets, 0u);
    EXPECT_EQ(resumed.status().counters.loop_closures_applied, 1u);
    // The saved keyframes keep their ids and stamps; the graph stays one chain.
    for (std::size_t i = 0; i < loaded; ++i)
      EXPECT_EQ(resumed.keyframes().records()[i].stamp, whole.keyframes().records()[i].stamp);
    EXPECT_EQ(resumed.graph().numConstraints(), resumed.graph().numNodes());  // chain + 1 loop closure
    // Keyframes lost with the kill: those made between the last autosave and the kill.
    EXPECT_LE(whole.keyframes().size() - resumed.keyframes().size(), 12u);
    const double error = newestError(resumed, sc);
    std::printf("newest keyframe error vs truth: uninterrupted %.4f m, resumed %.4f m\n", whole_error, error);
    EXPECT_LT(error, 0.1 + 1.5 * whole_error);
    // Poses of the keyframes both runs have (same stamps) agree.
    double worst = 0;
    for (std::size_t i = 0; i < loaded; ++i)
      worst = std::max(
          worst,
          (resumed.graph().node(i).pose.translation() - whole.graph().node(i).pose.translation()).norm());
    std::printf("largest position difference over the %zu saved keyframes: %.4f m\n", loaded, worst);
    EXPECT_LT(worst, 0.15);
  }
}

TEST(Persistence, LoopClosuresSentBeforeTheResumedMapAreRefused) {
  TempDir dir;
  const std::string path = dir.file("map.g2o");
  const DriftScenario sc = makeDriftingSquare();
  const std::size_t half = sc.odometry.size() / 2;
  {
    Pipeline p(options());
    feed(p, sc, 0, half);
    p.handleLoopClosure(trueLoopClosure(sc, 0, 40));
    drain(p);
    ASSERT_EQ(p.status().counters.loop_closures_applied, 1u);
    ASSERT_EQ(p.saveGraph(path), "");
  }
  Pipeline q(options());
  ASSERT_EQ(q.loadGraph(path), "");
  const std::size_t constraints = q.graph().numConstraints();
  q.handleLoopClosure(trueLoopClosure(sc, 0, 40));  // the same message again: already in
  EXPECT_EQ(count(q, "loop closure: before the resumed map"), 1u);
  EXPECT_EQ(q.graph().numConstraints(), constraints);
  feed(q, sc, half, sc.odometry.size());  // the second lap and its closing loop closure
  EXPECT_EQ(q.status().counters.loop_closures_applied, 1u);
  EXPECT_EQ(q.graph().numConstraints(), q.graph().numNodes() + 1);  // chain + 2 loop closures
}

TEST(Persistence, LastPoseJoinsANewOdometryFrameAtTheNewestSavedPose) {
  TempDir dir;
  const std::string path = dir.file("map.g2o");
  const DriftScenario sc = makeDriftingSquare(1);
  toro::Pose3 saved_pose;
  toro::NodeId saved_id = 0;
  {
    Pipeline p(options());
    feed(p, sc, 0, sc.odometry.size());
    saved_pose = p.graph().pose(p.keyframes().newest().id);
    saved_id = p.keyframes().newest().id;
    ASSERT_EQ(p.saveGraph(path), "");
  }
  PipelineOptions o = options();
  o.persistence.resume_link = ResumeLink::kLastPose;
  Pipeline q(o);
  ASSERT_EQ(q.loadGraph(path), "");
  // The robot restarted: its odometry starts again at the origin, later in time.
  const ros::Time t0 = sc.odometry.back().header.stamp + ros::Duration(60.0);
  q.handleOdometry(odometryMsg(t0, toro::Pose3()));
  ASSERT_EQ(q.keyframes().newest().id, saved_id + 1);
  const toro::Constraint& link = q.graph().constraints().back();
  EXPECT_EQ(link.from, saved_id);
  EXPECT_EQ(link.to, saved_id + 1);
  EXPECT_NEAR(link.measurement.angle(), 0.0, 1e-12);
  EXPECT_NEAR(link.measurement.translation().norm(), 0.0, 1e-12);
  // Default information of the link: 1 / 0.5^2 on translation.
  EXPECT_NEAR(link.information(0, 0), 1.0 / 0.25, 1e-9);
  // Two metres forward in the new frame: keyframes ahead of the saved pose by their new odometry.
  for (int i = 1; i <= 20; ++i)
    q.handleOdometry(
        odometryMsg(t0 + ros::Duration(0.1 * i), toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0)));
  ASSERT_GE(q.keyframes().newest().id, saved_id + 4);
  const toro::Pose3 ahead = q.keyframes().newest().odom_T_base;
  EXPECT_GT(ahead.translation().x(), 1.5);
  const toro::Pose3 newest = q.graph().pose(q.keyframes().newest().id);
  EXPECT_NEAR((newest.translation() - (saved_pose * ahead).translation()).norm(), 0.0, 1e-9);
  // map -> odom now maps the new odometry origin onto the saved pose.
  EXPECT_NEAR((q.makeSnapshot()->map_T_odom.translation() - saved_pose.translation()).norm(), 0.0, 1e-9);
}

TEST(Persistence, ContinueStepsFromTheSavedOdometryWithDefaultInformation) {
  TempDir dir;
  const std::string path = dir.file("map.g2o");
  const DriftScenario sc = makeDriftingSquare(1);
  const std::size_t cut = sc.odometry.size() / 2;
  {
    Pipeline p(options());
    feed(p, sc, 0, cut);
    ASSERT_EQ(p.saveGraph(path), "");
  }
  Pipeline q(options());
  ASSERT_EQ(q.loadGraph(path), "");
  const toro::NodeId saved = q.keyframes().newest().id;
  const toro::Pose3 saved_odom = q.keyframes().newest().odom_T_base;
  for (std::size_t i = cut; i < sc.odometry.size() && q.keyframes().newest().id == saved; ++i)
    q.handleOdometry(sc.odometry[i]);
  ASSERT_EQ(q.keyframes().newest().id, saved + 1);
  const toro::Constraint& c = q.graph().constraints().back();
  EXPECT_EQ(c.from, saved);
  const toro::Pose3 expected = toro::relativePose(saved_odom, q.keyframes().newest().odom_T_base);
  EXPECT_NEAR((c.measurement.translation() - expected.translation()).norm(), 0.0, 1e-12);
  // The saved covariance is not kept: defaults (1 / 0.05^2), not counted as an unusable covariance.
  EXPECT_NEAR(c.information(0, 0), 1.0 / (0.05 * 0.05), 1e-6);
  EXPECT_EQ(q.status().counters.odometry_steps_default, 0u);
}

TEST(Persistence, OdometryInAnotherFrameIsRefusedAndRepeatsAreLoggedSparsely) {
  std::vector<std::string> warnings;
  PipelineOptions o = options();
  o.odom_frame = "odom";
  Pipeline p(o, [&](const std::string& w) { warnings.push_back(w); });
  const DriftScenario sc = makeDriftingSquare(1);
  for (std::size_t i = 0; i < 100; ++i) {
    nav_msgs::Odometry m = sc.odometry[i];
    m.header.frame_id = "wheel_odom";
    p.handleOdometry(m);
  }
  EXPECT_EQ(count(p, "odometry: wrong frame"), 100u);
  EXPECT_TRUE(p.keyframes().empty());
  // Occurrences 1, 2, 4, ..., 64 are logged: 7 lines for 100 refusals, each naming both frames.
  ASSERT_EQ(warnings.size(), 7u);
  EXPECT_NE(warnings[0].find("'wheel_odom'"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[0].find("'odom'"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[6].find("occurrence 64"), std::string::npos) << warnings[6];
  // A leading slash is the same frame (tf2 ignores it), and an empty frame_id is accepted.
  nav_msgs::Odometry slash = sc.odometry[100];
  slash.header.frame_id = "/odom";
  p.handleOdometry(slash);
  nav_msgs::Odometry empty = sc.odometry[101];
  empty.header.frame_id = "";
  p.handleOdometry(empty);
  EXPECT_EQ(p.keyframes().size(), 1u);
  EXPECT_EQ(count(p, "odometry: wrong frame"), 100u);
}
