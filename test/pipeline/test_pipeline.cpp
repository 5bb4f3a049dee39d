#include <unistd.h>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <string>

#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;
using toro_ros::testing::drain;
using toro_ros::testing::DriftScenario;
using toro_ros::testing::makeDriftingSquare;
using toro_ros::testing::odometryMsg;
using toro_ros::testing::trueLoopClosure;

namespace {

PipelineOptions options() { return toro_ros::testing::roundsEvery10Keyframes(); }

double positionError(const Snapshot& s, const toro::Pose3& truth) {
  return (s.keyframes.back().map_T_base.translation() - truth.translation()).norm();
}

std::uint64_t count(const PipelineCounters& c, const std::string& reason) {
  const auto it = c.refused_by_reason.find(reason);
  return it == c.refused_by_reason.end() ? 0 : it->second;
}

}  // namespace

TEST(Pipeline, InvalidOptionsThrowWithTheReason) {
  PipelineOptions o;
  o.matcher.max_pending = 0;
  try {
    Pipeline p(o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_pending"), std::string::npos);
  }
}

TEST(Pipeline, KeyframesAreConsecutiveIdsWithOdometryConstraints) {
  Pipeline p(options());
  for (int i = 0; i <= 30; ++i)
    p.handleOdometry(
        odometryMsg(ros::Time(10 + 0.1 * i), toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0)));
  // 3 m at 0.5 m (strictly more than) per keyframe: 0, 0.6, 1.2, 1.8, 2.4, 3.0 -> 6 keyframes.
  ASSERT_EQ(p.keyframes().size(), 6u);
  for (std::size_t i = 0; i < 6; ++i) EXPECT_EQ(p.keyframes().records()[i].id, static_cast<toro::NodeId>(i));
  EXPECT_EQ(p.graph().numConstraints(), 5u);
  EXPECT_NEAR(p.graph().constraints()[2].measurement.translation().x(), 0.6, 1e-9);
  EXPECT_EQ(p.status().counters.odometry_messages, 31u);
}

TEST(Pipeline, MapToOdomIsCorrectedNewestTimesInverseOdometry) {
  // Plain least squares: the loop closure below contradicts the odometry on purpose, which the
  // robust weights (tested in test_pipeline_robust.cpp) would rightly discount.
  PipelineOptions o = options();
  o.robust.kernel = toro::RobustKernel::kNone;
  Pipeline p(o);
  const toro::Pose3 start = toro::Pose3::fromRollPitchYaw(5, 1, 0, 0, 0, 0.3);
  p.handleOdometry(odometryMsg(ros::Time(10), start));
  auto s = p.makeSnapshot();
  ASSERT_TRUE(s->has_map_T_odom);
  // The first keyframe defines the map where odometry is: map_T_odom = identity.
  EXPECT_NEAR(s->map_T_odom.translation().norm(), 0, 1e-12);
  EXPECT_NEAR(s->map_T_odom.angle(), 0, 1e-12);

  for (int i = 1; i <= 20; ++i)
    p.handleOdometry(
        odometryMsg(ros::Time(10 + i), start * toro::Pose3::fromRollPitchYaw(0.3 * i, 0, 0, 0, 0, 0.05 * i)));
  // A loop closure that contradicts the odometry moves the corrected poses away from it.
  LoopClosure lc;
  lc.id_from = 0;
  lc.id_to = static_cast<long>(p.keyframes().newest().id);
  lc.from_T_to = poseToMsg(toro::Pose3::fromRollPitchYaw(4, 2, 0, 0, 0, 0.5));
  p.handleLoopClosure(lc);
  drain(p);
  s = p.makeSnapshot();
  const toro::Pose3 expected = s->keyframes.back().map_T_base * p.keyframes().newest().odom_T_base.inverse();
  EXPECT_NEAR((s->map_T_odom.translation() - expected.translation()).norm(), 0, 1e-12);
  EXPECT_NEAR(toro::relativePose(s->map_T_odom, expected).angle(), 0, 1e-12);
  EXPECT_GT(s->map_T_odom.translation().norm(), 0.1);  // it did correct something
  // map_T_odom * odom_T_base(newest) reproduces the corrected newest pose.
  const toro::Pose3 back = s->map_T_odom * p.keyframes().newest().odom_T_base;
  EXPECT_NEAR((back.translation() - s->keyframes.back().map_T_base.translation()).norm(), 0, 1e-9);
}

TEST(Pipeline, DriftingSquareWithALoopClosureEndsNearTruth) {
  const DriftScenario sc = makeDriftingSquare();
  Pipeline p(options());
  for (const auto& m : sc.odometry) p.handleOdometry(m);
  const std::size_t last = sc.odometry.size() - 1;
  auto raw = p.makeSnapshot();
  const double raw_error = positionError(*raw, sc.truth[last]);
  ASSERT_GT(raw_error, 1.0);  // the scenario does drift
  p.handleLoopClosure(trueLoopClosure(sc, 0, last));
  EXPECT_EQ(p.status().counters.loop_closures_applied, 1u);
  drain(p);
  const auto s = p.makeSnapshot();
  const double corrected_error = positionError(*s, sc.truth[last]);
  std::cout << "newest keyframe position error: raw odometry " << raw_error << " m, corrected "
            << corrected_error << " m\n";
  EXPECT_LT(corrected_error, 0.1 * raw_error);
  EXPECT_GT(p.status().counters.optimization_passes, 1u);
}

TEST(Pipeline, UnknownStampRefusedAndFutureStampAppliedWhenOdometryReachesIt) {
  const DriftScenario sc = makeDriftingSquare(1);
  std::vector<std::string> warnings;
  Pipeline p(options(), [&](const std::string& w) { warnings.push_back(w); });
  const std::size_t half = sc.odometry.size() / 2;
  for (std::size_t i = 0; i < half; ++i) p.handleOdometry(sc.odometry[i]);

  LoopClosure unknown = trueLoopClosure(sc, 0, 5);
  unknown.stamp_from = ros::Time(50.0);  // before any odometry
  p.handleLoopClosure(unknown);
  EXPECT_EQ(p.status().counters.loop_closures_refused, 1u);
  EXPECT_EQ(count(p.status().counters, "loop closure: no keyframe within tolerance"), 1u);
  ASSERT_FALSE(warnings.empty());
  EXPECT_NE(warnings.back().find("50.000000000"), std::string::npos) << warnings.back();

  const std::size_t future = half + 17;  // odometry has not got there yet
  p.handleLoopClosure(trueLoopClosure(sc, 0, future));
  EXPECT_EQ(p.status().pending_loop_closures, 1u);
  EXPECT_EQ(p.status().counters.loop_closures_applied, 0u);
  for (std::size_t i = half; i < future; ++i) p.handleOdometry(sc.odometry[i]);
  EXPECT_EQ(p.status().pending_loop_closures, 1u);
  p.handleOdometry(sc.odometry[future]);
  EXPECT_EQ(p.status().pending_loop_closures, 0u);
  EXPECT_EQ(p.status().counters.loop_closures_applied, 1u);
  // It is attached to a keyframe made at exactly that stamp.
  const toro::Constraint& c = p.graph().constraints().back();
  EXPECT_EQ(p.keyframes().find(c.to)->stamp, sc.odometry[future].header.stamp);
}

TEST(Pipeline, TimeJumpBackwardsResetsSmallStepBackIsRefused) {
  std::vector<std::string> warnings;
  Pipeline p(options(), [&](const std::string& w) { warnings.push_back(w); });
  for (int i = 0; i < 20; ++i)
    p.handleOdometry(odometryMsg(ros::Time(100 + i), toro::Pose3::fromRollPitchYaw(i, 0, 0, 0, 0, 0)));
  const auto before = p.makeSnapshot();
  ASSERT_EQ(p.keyframes().size(), 20u);
  p.handleOdometry(odometryMsg(ros::Time(118.5), toro::Pose3()));  // 0.5 s back: out of order
  EXPECT_EQ(p.keyframes().size(), 20u);
  EXPECT_EQ(count(p.status().counters, "odometry: out of order"), 1u);
  p.handleOdometry(
      odometryMsg(ros::Time(50), toro::Pose3::fromRollPitchYaw(3, 0, 0, 0, 0, 0)));  // bag restarted
  EXPECT_EQ(p.status().counters.time_jump_resets, 1u);
  EXPECT_EQ(p.keyframes().size(), 1u);
  EXPECT_EQ(p.keyframes().newest().id, 0);
  EXPECT_EQ(p.makeSnapshot()->epoch, before->epoch + 1);
  EXPECT_NE(warnings.back().find("time jumped back"), std::string::npos);
}

TEST(Pipeline, ResetDropsPendingLoopClosuresAsRefused) {
  Pipeline p(options());
  p.handleOdometry(odometryMsg(ros::Time(10), toro::Pose3()));
  LoopClosure lc;
  lc.id_from = lc.id_to = -1;
  lc.stamp_from = ros::Time(10);
  lc.stamp_to = ros::Time(20);
  lc.from_T_to.orientation.w = 1;
  p.handleLoopClosure(lc);
  EXPECT_EQ(p.status().pending_loop_closures, 1u);
  p.reset("test");
  EXPECT_EQ(p.status().pending_loop_closures, 0u);
  EXPECT_EQ(count(p.status().counters, "loop closure: dropped by reset"), 1u);
  EXPECT_TRUE(p.graph().empty());
}

TEST(Pipeline, PausedRunsNoScheduledPassesButServiceOptimizeWorks) {
  const DriftScenario sc = makeDriftingSquare(1);
  Pipeline p(options());
  for (const auto& m : sc.odometry) p.handleOdometry(m);
  p.setPaused(true);
  p.handleLoopClosure(trueLoopClosure(sc, 0, sc.odometry.size() - 1));
  EXPECT_FALSE(p.runScheduledOptimization());
  EXPECT_EQ(p.status().counters.optimization_passes, 0u);
  const OptimizeResult r = p.optimize(5, "full");
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_EQ(r.iterations, 5);
  EXPECT_LT(r.chi2_after, 0.5 * r.chi2_before);
  EXPECT_NEAR(r.chi2_after, toro::g2oChi2(p.graph()), 1e-9);
  EXPECT_FALSE(p.optimize(1, "bogus").success);
  const OptimizeResult finish = p.optimize(0, "finish");
  ASSERT_TRUE(finish.success) << finish.message;
  EXPECT_NEAR(finish.chi2_before, r.chi2_after, 1e-9 * (1 + r.chi2_after));
  EXPECT_LT(finish.chi2_after, finish.chi2_before);
  EXPECT_NEAR(finish.chi2_after, toro::g2oChi2(p.graph()), 1e-9 * (1 + finish.chi2_after));
}

TEST(Pipeline, SaveThenLoadGivesTheSameGraph) {
  const DriftScenario sc = makeDriftingSquare(1);
  Pipeline p(options());
  for (const auto& m : sc.odometry) p.handleOdometry(m);
  p.handleLoopClosure(trueLoopClosure(sc, 0, sc.odometry.size() - 1));
  drain(p);
  char dir_template[] = "/tmp/toro_pipeline_XXXXXX";
  ASSERT_NE(mkdtemp(dir_template), nullptr);
  const std::string path = std::string(dir_template) + "/map.g2o";
  ASSERT_EQ(p.saveGraph(path), "");

  Pipeline q(options());
  ASSERT_EQ(q.loadGraph(path), "");
  ASSERT_EQ(q.graph().numNodes(), p.graph().numNodes());
  ASSERT_EQ(q.graph().numConstraints(), p.graph().numConstraints());
  for (std::size_t i = 0; i < p.graph().numNodes(); ++i) {
    EXPECT_EQ(q.graph().node(i).id, p.graph().node(i).id);
    EXPECT_NEAR((q.graph().node(i).pose.translation() - p.graph().node(i).pose.translation()).norm(), 0,
                1e-12);
    EXPECT_EQ(q.keyframes().records()[i].stamp, p.keyframes().records()[i].stamp);
  }
  EXPECT_NEAR(toro::g2oChi2(q.graph()), toro::g2oChi2(p.graph()), 1e-9 * (1 + toro::g2oChi2(p.graph())));
  const auto sp = p.makeSnapshot(), sq = q.makeSnapshot();
  EXPECT_NEAR((sp->map_T_odom.translation() - sq->map_T_odom.translation()).norm(), 0, 1e-9);
  std::size_t loops = 0;
  for (const auto& e : sq->edges) loops += e.loop_closure;
  EXPECT_EQ(loops, 1u);

  // Loading continues the graph: the next odometry makes keyframe max id + 1.
  const auto next = toro::Pose3::fromRollPitchYaw(2, 0, 0, 0, 0, 0) * p.keyframes().newest().odom_T_base;
  q.handleOdometry(odometryMsg(p.keyframes().newest().stamp + ros::Duration(1.0), next));
  EXPECT_EQ(q.keyframes().newest().id, p.keyframes().newest().id + 1);

  EXPECT_NE(q.loadGraph(std::string(dir_template) + "/missing.g2o"), "");
  EXPECT_EQ(q.keyframes().size(), p.keyframes().size() + 1);  // a failed load changes nothing
  std::remove(path.c_str());
  std::remove((path + ".stamps").c_str());
  rmdir(dir_template);
}

TEST(Pipeline, SaveAndLoadInToroFormatAndWithoutSidecar) {
  const DriftScenario sc = makeDriftingSquare(1);
  Pipeline p(options());
  for (const auto& m : sc.odometry) p.handleOdometry(m);
  p.handleLoopClosure(trueLoopClosure(sc, 0, sc.odometry.size() - 1));
  drain(p);
  char dir_template[] = "/tmp/toro_pipeline_XXXXXX";
  ASSERT_NE(mkdtemp(dir_template), nullptr);
  const std::string path = std::string(dir_template) + "/map.graph";  // TORO format by extension
  ASSERT_EQ(p.saveGraph(path), "");
  {
    std::ifstream in(path);
    std::string tag;
    in >> tag;
    EXPECT_EQ(tag, "VERTEX3");
  }
  Pipeline q(options());
  ASSERT_EQ(q.loadGraph(path), "");
  ASSERT_EQ(q.graph().numNodes(), p.graph().numNodes());
  for (std::size_t i = 0; i < p.graph().numNodes(); ++i) {
    EXPECT_LT((q.graph().node(i).pose.translation() - p.graph().node(i).pose.translation()).norm(), 1e-9);
    EXPECT_LT(toro::relativePose(q.graph().node(i).pose, p.graph().node(i).pose).angle(), 1e-9);
  }
  // Without the sidecar: no stamps, and loop closures recognised as the non-consecutive edges.
  std::remove((path + ".stamps").c_str());
  Pipeline r(options());
  ASSERT_EQ(r.loadGraph(path), "");
  EXPECT_TRUE(r.keyframes().newest().stamp.isZero());
  std::size_t loops = 0;
  // The snapshot must outlive the loop: ranging over makeSnapshot()->edges would read the edges of
  // a temporary already destroyed (found by the ASan build).
  const std::shared_ptr<const Snapshot> snapshot = r.makeSnapshot();
  for (const auto& e : snapshot->edges) loops += e.loop_closure;
  EXPECT_EQ(loops, 1u);
  std::remove(path.c_str());
  rmdir(dir_template);
}

TEST(Pipeline, LoopClosureNamingTheNewestOdometryIsAppliedAtOnce) {
  const DriftScenario sc = makeDriftingSquare();
  Pipeline p(PipelineOptions{});
  for (const auto& m : sc.odometry) p.handleOdometry(m);
  const std::size_t before = p.keyframes().size();
  p.handleLoopClosure(trueLoopClosure(sc, 0, sc.odometry.size() - 1));
  EXPECT_EQ(p.status().pending_loop_closures, 0u);
  EXPECT_EQ(p.status().counters.loop_closures_applied, 1u);
  EXPECT_EQ(p.keyframes().newest().stamp, sc.odometry.back().header.stamp);
  EXPECT_LE(p.keyframes().size(), before + 1);
}

TEST(Pipeline, WithoutLoopClosureKeyframesKeyframingDependsOnOdometryAlone) {
  const DriftScenario sc = makeDriftingSquare();
  PipelineOptions o;
  o.matcher.create_keyframes = false;
  Pipeline p(o), reference(o);
  for (const auto& m : sc.odometry) {
    p.handleOdometry(m);
    reference.handleOdometry(m);
  }
  // Names the newest odometry, which is not a keyframe: nothing is made for it.
  const LoopClosure lc = trueLoopClosure(sc, 0, sc.odometry.size() - 1);
  ASSERT_FALSE(p.keyframes().nearest(lc.stamp_to, 0.0).has_value());
  p.handleLoopClosure(lc);
  EXPECT_EQ(p.keyframes().size(), reference.keyframes().size());
  EXPECT_EQ(p.status().pending_loop_closures, 1u);
  // The last keyframe (made while turning) is within tolerance; the loop closure is settled on it
  // once odometry is far enough past the stamp that no later keyframe could be nearer.
  const auto nearest = p.keyframes().nearest(lc.stamp_to, o.matcher.stamp_tolerance_sec);
  ASSERT_TRUE(nearest.has_value());
  const ros::Time late = lc.stamp_to + ros::Duration(o.matcher.stamp_tolerance_sec + 0.01);
  p.handleOdometry(odometryMsg(late, poseFromMsg(sc.odometry.back().pose.pose)));
  EXPECT_EQ(p.status().pending_loop_closures, 0u);
  EXPECT_EQ(p.status().counters.loop_closures_applied, 1u);
  EXPECT_EQ(p.graph().constraints().back().to, *nearest);
}
