// The background finish (MapOptimizer::takeFinishJob / runFinishJob / mergeFinish) driven through
// the Pipeline, as the node's worker and the offline runner drive it.
#include <gtest/gtest.h>

#include <cmath>

#include "drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {
namespace {

using testing::DriftScenario;
using testing::baseTestOptions;
using testing::drain;
using testing::makeDriftingSquare;
using testing::trueLoopClosure;

PipelineOptions finishOptions() {
  PipelineOptions o = baseTestOptions();
  o.optimization.full_iterations = 0;  // no rounds: what moves the map is the pass and the finish
  o.optimization.background_finish = true;
  o.optimization.finish_min_interval_sec = 0.0;
  return o;
}

// Feeds odometry samples [from, to) and drains the schedule after each.
void feed(Pipeline& p, const DriftScenario& sc, std::size_t from, std::size_t to) {
  for (std::size_t i = from; i < to; ++i) {
    p.handleOdometry(sc.odometry[i]);
    drain(p);
  }
}

// The optimum of `graph` by the plain (non-robust) finish from its poses.
toro::PoseGraph optimum(toro::PoseGraph graph) {
  toro::FinishOptions o;
  if (!toro::cholmodAvailable()) o.linear_solver = toro::LinearSolverType::kSimplicialLDLT;
  toro::LevenbergMarquardt(o).optimize(graph);
  return graph;
}

// Takes the finish job if one is due, runs it and merges it; whether all three happened.
bool finishIfDue(Pipeline& p) {
  std::optional<FinishJob> job = p.takeFinishJob();
  if (!job) return false;
  const FinishOutcome outcome = runFinishJob(std::move(*job));
  return outcome.success && p.mergeFinish(outcome);
}

double maxPositionDifference(const toro::PoseGraph& a, const toro::PoseGraph& b, std::size_t nodes) {
  double d = 0.0;
  for (std::size_t i = 0; i < nodes; ++i)
    d = std::max(d, (a.node(i).pose.translation() - b.node(i).pose.translation()).norm());
  return d;
}

TEST(BackgroundFinish, MergedFinishIsTheOptimumAndTorosPassWasNot) {
  const DriftScenario sc = makeDriftingSquare();
  Pipeline p(finishOptions());
  const std::size_t last = sc.odometry.size() - 1;
  feed(p, sc, 0, sc.odometry.size());
  EXPECT_FALSE(p.takeFinishJob());  // odometry alone: nothing to finish
  p.handleLoopClosure(trueLoopClosure(sc, 0, last));
  drain(p);
  const double after_pass = toro::g2oChi2(p.graph());
  const toro::PoseGraph best = optimum(p.graph());
  const double best_chi2 = toro::g2oChi2(best);
  ASSERT_GT(after_pass, best_chi2 * 1.01);  // one TORO pass stops above the optimum

  std::optional<FinishJob> job = p.takeFinishJob();
  ASSERT_TRUE(job);
  EXPECT_FALSE(p.takeFinishJob());  // one at a time
  const FinishOutcome outcome = runFinishJob(std::move(*job));
  ASSERT_TRUE(outcome.success) << outcome.error;
  EXPECT_TRUE(p.mergeFinish(outcome));
  // A background finish stops at a relative decrease of 1e-4 per iteration (kBackgroundRelativeDecrease).
  EXPECT_NEAR(toro::g2oChi2(p.graph()), best_chi2, 1e-4 * best_chi2);
  EXPECT_LT(maxPositionDifference(p.graph(), best, best.numNodes()), 1e-3);
  const PipelineStatus s = p.status();
  EXPECT_EQ(s.counters.finishes_started, 1u);
  EXPECT_EQ(s.counters.finishes_merged, 1u);
  ASSERT_TRUE(s.last_finish);
  EXPECT_TRUE(s.last_finish->merged);
  EXPECT_NEAR(s.last_finish->chi2_after, best_chi2, 1e-4 * best_chi2);
  EXPECT_NEAR(s.last_chi2, toro::g2oChi2(p.graph()), 1e-9 * best_chi2);
  EXPECT_FALSE(p.takeFinishJob());  // nothing new since
}

// Exactly: ids, poses, constraints (ends, measurement, information, kind), fixed nodes.
void expectSameGraph(const toro::PoseGraph& a, const toro::PoseGraph& b) {
  ASSERT_EQ(a.numNodes(), b.numNodes());
  ASSERT_EQ(a.numConstraints(), b.numConstraints());
  for (std::size_t v = 0; v < a.numNodes(); ++v) {
    ASSERT_EQ(a.node(v).id, b.node(v).id) << v;
    ASSERT_EQ(a.node(v).pose.translation(), b.node(v).pose.translation()) << v;
    ASSERT_EQ(a.node(v).pose.rotation().coeffs(), b.node(v).pose.rotation().coeffs()) << v;
  }
  for (std::size_t c = 0; c < a.numConstraints(); ++c) {
    const toro::Constraint &x = a.constraints()[c], &y = b.constraints()[c];
    ASSERT_EQ(x.from, y.from) << c;
    ASSERT_EQ(x.to, y.to) << c;
    ASSERT_EQ(x.measurement.translation(), y.measurement.translation()) << c;
    ASSERT_EQ(x.measurement.rotation().coeffs(), y.measurement.rotation().coeffs()) << c;
    ASSERT_EQ(x.information, y.information) << c;
    ASSERT_EQ(x.kind, y.kind) << c;
  }
  EXPECT_EQ(a.fixedNodes(), b.fixedNodes());
}

// A job's graph is kept in step with the map between jobs (appended to, poses set) instead of
// copied in the worker: it must be the map's, exactly, whether kept in step or copied afresh
// (after a reset, or while an earlier job still holds it), and the finishes must end where they
// would on a copy.
TEST(BackgroundFinish, AJobsGraphIsTheMapsWhetherKeptInStepOrCopiedAfresh) {
  const DriftScenario sc = makeDriftingSquare(3);
  const std::size_t lap = sc.odometry.size() / 3;
  Pipeline p(finishOptions());
  std::size_t jobs = 0, kept_in_step = 0;
  const toro::PoseGraph* last = nullptr;
  const auto finishIfDue = [&] {
    std::optional<FinishJob> job = p.takeFinishJob();
    if (!job) return;
    ++jobs;
    ASSERT_TRUE(job->graph);
    expectSameGraph(*job->graph, p.graph());
    kept_in_step += job->graph.get() == last;
    last = job->graph.get();
    // The same finish on a copy made here ends on the same bits.
    FinishJob copy = *job;
    copy.graph = std::make_shared<const toro::PoseGraph>(p.graph());
    const FinishOutcome outcome = runFinishJob(std::move(*job));
    const FinishOutcome on_copy = runFinishJob(std::move(copy));
    ASSERT_TRUE(outcome.success) << outcome.error;
    expectSameGraph(outcome.graph, on_copy.graph);
    ASSERT_TRUE(p.mergeFinish(outcome));
  };
  for (int run = 0; run < 2; ++run) {
    for (std::size_t i = 0; i < sc.odometry.size(); ++i) {
      p.handleOdometry(sc.odometry[i]);
      if (i > lap && i % 20 == 0) p.handleLoopClosure(trueLoopClosure(sc, i - lap, i));
      if (i == 2 * lap + 7) {
        // A wrong one: held, then left out of the finishes.
        LoopClosure wrong = trueLoopClosure(sc, 5, i);
        wrong.from_T_to = poseToMsg(toro::Pose3::fromRollPitchYaw(3, 2, 0, 0, 0, 1));
        p.handleLoopClosure(wrong);
      }
      drain(p);
      finishIfDue();
      if (HasFatalFailure()) return;
    }
    if (run == 0) {
      // A job still held when the next is taken: that one is copied afresh, and it is the map's.
      std::optional<FinishJob> held = p.takeFinishJob();
      p.handleLoopClosure(trueLoopClosure(sc, lap, 3 * lap));
      drain(p);
      if (held) {
        ASSERT_TRUE(p.mergeFinish(runFinishJob(FinishJob(*held))));
      }
      finishIfDue();
      p.reset("test");  // the structure changes: the next job copies afresh
      last = nullptr;
    }
  }
  EXPECT_GE(jobs, 10u);
  EXPECT_GE(kept_in_step, jobs / 2) << jobs;  // most jobs did not copy the graph
}

TEST(BackgroundFinish, KeyframesAndLoopClosuresThatArriveDuringAFinishFollowIt) {
  const DriftScenario sc = makeDriftingSquare(3);
  Pipeline p(finishOptions());
  const std::size_t lap = sc.odometry.size() / 3;
  feed(p, sc, 0, 2 * lap + 1);
  p.handleLoopClosure(trueLoopClosure(sc, 0, 2 * lap));
  drain(p);
  std::optional<FinishJob> job = p.takeFinishJob();
  ASSERT_TRUE(job);
  const std::size_t nodes_at_job = p.graph().numNodes();
  // While it "runs": more keyframes, and a loop closure between them and the first lap.
  feed(p, sc, 2 * lap + 1, 2 * lap + lap / 2);
  p.handleLoopClosure(trueLoopClosure(sc, lap / 4, 2 * lap + lap / 4));
  drain(p);
  const toro::PoseGraph before_merge = p.graph();
  const std::size_t newer_loop_closure = before_merge.numConstraints() - 1;
  ASSERT_GT(before_merge.numNodes(), nodes_at_job + 3);

  const FinishOutcome outcome = runFinishJob(std::move(*job));
  ASSERT_TRUE(outcome.success);
  ASSERT_TRUE(p.mergeFinish(outcome));
  const toro::PoseGraph& merged = p.graph();
  ASSERT_EQ(merged.numNodes(), before_merge.numNodes());
  // The newer loop closure got its pass again on the finished poses: its residual is as small as
  // its pass left it before the merge (not back at its arrival value).
  const double before = toro::constraintChi2(before_merge, newer_loop_closure);
  const double after = toro::constraintChi2(merged, newer_loop_closure);
  EXPECT_LT(after, 2.0 * before + 1e-9);
  EXPECT_EQ(p.status().last_finish->nodes_added_since, before_merge.numNodes() - nodes_at_job);
  // It is not in the finished map yet: another finish is due.
  std::optional<FinishJob> next = p.takeFinishJob();
  ASSERT_TRUE(next);
  ASSERT_TRUE(p.mergeFinish(runFinishJob(std::move(*next))));
  const toro::PoseGraph best = optimum(p.graph());
  EXPECT_NEAR(toro::g2oChi2(p.graph()), toro::g2oChi2(best), 1e-4 * toro::g2oChi2(best));
}

TEST(BackgroundFinish, NewerNodesKeepTheirPoseRelativeToTheirParent) {
  const DriftScenario sc = makeDriftingSquare();
  Pipeline p(finishOptions());
  const std::size_t last = sc.odometry.size() - 1;
  feed(p, sc, 0, last - 30);
  p.handleLoopClosure(trueLoopClosure(sc, 0, last - 31));
  drain(p);
  std::optional<FinishJob> job = p.takeFinishJob();
  ASSERT_TRUE(job);
  const std::size_t nodes_at_job = p.graph().numNodes();
  feed(p, sc, last - 30, sc.odometry.size());  // odometry only: newer nodes on a chain
  const toro::PoseGraph before_merge = p.graph();
  ASSERT_GT(before_merge.numNodes(), nodes_at_job + 2);
  ASSERT_TRUE(p.mergeFinish(runFinishJob(std::move(*job))));
  const toro::PoseGraph& merged = p.graph();
  // Old nodes moved (the finish corrected them) ...
  EXPECT_GT(maxPositionDifference(before_merge, merged, nodes_at_job), 1e-3);
  // ... and each newer one kept its pose relative to the one before it (its parent): no jump.
  for (std::size_t i = nodes_at_job; i < merged.numNodes(); ++i) {
    const toro::Pose3 was = toro::relativePose(before_merge.node(i - 1).pose, before_merge.node(i).pose);
    const toro::Pose3 now = toro::relativePose(merged.node(i - 1).pose, merged.node(i).pose);
    EXPECT_LT((was.translation() - now.translation()).norm(), 1e-9) << i;
    EXPECT_LT(toro::relativePose(was, now).angle(), 1e-9) << i;
  }
}

TEST(BackgroundFinish, AFinishOfAGraphThatWasResetMeanwhileIsDropped) {
  const DriftScenario sc = makeDriftingSquare();
  Pipeline p(finishOptions());
  const std::size_t last = sc.odometry.size() - 1;
  feed(p, sc, 0, sc.odometry.size());
  p.handleLoopClosure(trueLoopClosure(sc, 0, last));
  drain(p);
  std::optional<FinishJob> job = p.takeFinishJob();
  ASSERT_TRUE(job);
  p.reset("test");
  feed(p, sc, 0, 20);  // a new graph, as large as the old one's first keyframes
  const toro::PoseGraph fresh = p.graph();
  EXPECT_FALSE(p.mergeFinish(runFinishJob(std::move(*job))));
  EXPECT_EQ(maxPositionDifference(fresh, p.graph(), fresh.numNodes()), 0.0);
  const PipelineStatus s = p.status();
  EXPECT_EQ(s.counters.finishes_dropped, 1u);
  EXPECT_EQ(s.counters.finishes_merged, 0u);
  ASSERT_TRUE(s.last_finish);
  EXPECT_FALSE(s.last_finish->merged);
  EXPECT_NE(s.last_finish->error.find("reset"), std::string::npos);
}

TEST(BackgroundFinish, AtMostOnePerMinimumIntervalOfMessageTimeAndOffWhenDisabled) {
  const DriftScenario sc = makeDriftingSquare(3);
  PipelineOptions o = finishOptions();
  o.optimization.finish_min_interval_sec = 5.0;
  Pipeline p(o);
  const std::size_t lap = sc.odometry.size() / 3;  // 20 s of message time
  feed(p, sc, 0, lap + 1);
  p.handleLoopClosure(trueLoopClosure(sc, 0, lap));
  drain(p);
  std::optional<FinishJob> first = p.takeFinishJob();
  ASSERT_TRUE(first);
  ASSERT_TRUE(p.mergeFinish(runFinishJob(std::move(*first))));
  feed(p, sc, lap + 1, lap + 11);  // 1 s later
  p.handleLoopClosure(trueLoopClosure(sc, 5, lap + 5));
  drain(p);
  EXPECT_FALSE(p.takeFinishJob());  // due, but only 1 s after the last one started
  feed(p, sc, lap + 11, lap + 51);  // 5 s after it
  EXPECT_TRUE(p.takeFinishJob());

  o.optimization.background_finish = false;
  Pipeline off(o);
  feed(off, sc, 0, lap + 1);
  off.handleLoopClosure(trueLoopClosure(sc, 0, lap));
  drain(off);
  EXPECT_FALSE(off.takeFinishJob());
}

// The node's default schedule: while loop closures move the map a finish may follow the last one
// a quarter of a second later; one that would only test a held loop closure (the map within the
// tolerance of the last finished one) waits a second.  Measured for the first: the curve of
// sphere2500 replayed node by node, 72 % of its samples within 1 % of the optimum at 1 s, all at
// 0.25 s; for the second: intel with 1000 wrong loop closures took 15.7 s at 0.25 s, 8.2 s with the
// floor (bench/background_finish_results.md, session 34).
TEST(BackgroundFinish, DefaultScheduleAQuarterSecondWhileTheMapMovesASecondToTestAHeldLoopClosure) {
  const DriftScenario sc = makeDriftingSquare(2);
  PipelineOptions o = baseTestOptions();
  o.optimization.full_iterations = 0;
  o.optimization.background_finish = true;
  o.optimization.hold_until_supported = true;  // the node's default (the test options turn it off)
  ASSERT_EQ(o.optimization.finish_min_interval_sec, OptimizationOptions{}.finish_min_interval_sec);
  Pipeline p(o);
  auto finish = [&p] { return finishIfDue(p); };
  // A first revisit, its loop closures agreeing with each other: the map moves, a finish follows.
  const std::size_t revisit = 225;
  feed(p, sc, 0, revisit + 1);
  for (const LoopClosure& lc : testing::revisitLoopClosures(sc, 25, revisit)) p.handleLoopClosure(lc);
  drain(p);
  ASSERT_TRUE(finish());
  // 0.3 s later (samples every 0.1 s) more of the revisit, each next to an accepted one.
  feed(p, sc, revisit + 1, revisit + 4);
  for (std::size_t k = 1; k <= 3; ++k) p.handleLoopClosure(trueLoopClosure(sc, 25 + k, revisit + k));
  drain(p);
  ASSERT_GT(p.status().last_chi2, 1.01 * p.status().last_finish->chi2_after);  // the map moved
  ASSERT_TRUE(finish());  // a quarter of a second is enough
  // 0.3 s later again a lone loop closure, wrong and far from everything: held, the map unmoved.
  feed(p, sc, revisit + 4, revisit + 7);
  const std::uint64_t held = p.counters().loop_closures_held;
  LoopClosure lone = trueLoopClosure(sc, 110, revisit + 6);
  lone.from_T_to =
      poseToMsg(poseFromMsg(lone.from_T_to) * toro::Pose3::fromRollPitchYaw(1.5, -1.0, 0, 0, 0, 0.3));
  p.handleLoopClosure(lone);
  drain(p);
  ASSERT_EQ(p.counters().loop_closures_held, held + 1);
  ASSERT_LE(p.status().last_chi2, 1.01 * p.status().last_finish->chi2_after);
  EXPECT_TRUE(p.finishPending());
  EXPECT_FALSE(p.takeFinishJob());  // 0.3 s after the last finish
  feed(p, sc, revisit + 7, revisit + 13);
  EXPECT_FALSE(p.takeFinishJob());  // 0.9 s
  feed(p, sc, revisit + 13, revisit + 15);
  std::optional<FinishJob> test = p.takeFinishJob();  // 1.1 s: the held one is tested
  ASSERT_TRUE(test);
  EXPECT_EQ(test->innovation_candidates.size(), 1u);
}

// A loop closure that closes a large loop alone has no neighbour to agree with it, so the support
// holds it; the finished map, whose uncertainty between its ends it is measured against, releases
// a right one and keeps a wrong one held.
// Two laps of the drifting square: a first revisit reported keyframe by keyframe (its loop
// closures support each other) at lap 2's first side, its finish merged, then 12.5 s later a lone
// loop closure halfway along the third side back to lap 1, its measurement times `error`.
// Returns how many loop closures had been held before the lone one.
std::uint64_t loneLoopClosureAfterAFinishedRevisit(Pipeline& p, const DriftScenario& sc,
                                                   const toro::Pose3& error) {
  const std::size_t revisit = 225, lone_at = 350;
  feed(p, sc, 0, revisit + 1);
  for (const LoopClosure& lc : testing::revisitLoopClosures(sc, 25, revisit)) p.handleLoopClosure(lc);
  drain(p);
  std::optional<FinishJob> first = p.takeFinishJob();
  EXPECT_TRUE(first && p.mergeFinish(runFinishJob(std::move(*first))));
  feed(p, sc, revisit + 1, lone_at + 1);
  const std::uint64_t held = p.counters().loop_closures_held;
  LoopClosure lone = trueLoopClosure(sc, lone_at - 200, lone_at);
  lone.from_T_to = poseToMsg(poseFromMsg(lone.from_T_to) * error);
  p.handleLoopClosure(lone);
  drain(p);
  return held;
}

TEST(BackgroundFinish, ALoneRightLoopClosureIsReleasedByTheFinishedMapAndAWrongOneIsNot) {
  const DriftScenario sc = makeDriftingSquare(2);
  const auto run = [&](const toro::Pose3& error) {
    PipelineOptions o = finishOptions();
    o.optimization.hold_until_supported = true;  // the node's default (the test options turn it off)
    Pipeline p(o);
    const std::uint64_t held = loneLoopClosureAfterAFinishedRevisit(p, sc, error);
    EXPECT_EQ(p.counters().loop_closures_held, held + 1);  // nothing near it agrees: held
    std::optional<FinishJob> job = p.takeFinishJob();
    EXPECT_TRUE(job);
    if (!job) return p.counters().loop_closures_released_predicted;
    EXPECT_EQ(job->innovation_candidates.size(), 1u);
    const FinishOutcome outcome = runFinishJob(std::move(*job));
    // Measured: innovation 2.9 (right) and 6.7 (wrong) against 16.8 x 7.1 / (6 x 5) = 4.0.
    EXPECT_EQ(outcome.innovations.size(), 1u);
    EXPECT_EQ(outcome.loop_closure_weight, 5.0);
    EXPECT_TRUE(p.mergeFinish(outcome));
    return p.counters().loop_closures_released_predicted;
  };
  EXPECT_EQ(run(toro::Pose3()), 1u);
  EXPECT_EQ(run(toro::Pose3::fromRollPitchYaw(1.5, -1.0, 0, 0, 0, 0.3)), 0u);  // 1.8 m and 17 degrees off
}

// A finish that releases a held loop closure leaves the map off the optimum by it (its affected
// pass is no finish): the next finish follows at once, whatever the interval.  One that releases
// nothing waits for the interval as usual.
TEST(BackgroundFinish, AFinishThatReleasesAHeldLoopClosureIsFollowedAtOnce) {
  const DriftScenario sc = makeDriftingSquare(2);
  const auto followed_at_once = [&](const toro::Pose3& error) {
    PipelineOptions o = finishOptions();
    o.optimization.hold_until_supported = true;
    o.optimization.finish_min_interval_sec = 5.0;
    Pipeline p(o);
    loneLoopClosureAfterAFinishedRevisit(p, sc, error);  // 12.5 s after the first finish
    std::optional<FinishJob> job = p.takeFinishJob();    // tests the held one
    EXPECT_TRUE(job);
    if (!job) return false;
    EXPECT_TRUE(p.mergeFinish(runFinishJob(std::move(*job))));
    const bool released = p.counters().loop_closures_released_predicted > 0;
    drain(p);
    const bool followed = p.takeFinishJob().has_value();  // at the same stamp: within the 5 s
    EXPECT_EQ(followed, released);
    return followed;
  };
  EXPECT_TRUE(followed_at_once(toro::Pose3()));
  EXPECT_FALSE(followed_at_once(toro::Pose3::fromRollPitchYaw(1.5, -1.0, 0, 0, 0, 0.3)));  // held: no hurry
}

// Laps 2 and 3 revisit lap 1's second side, a loop closure every half metre.  Lap 3's arrive
// after a lap of drift, their chi2 on the map as it is 60 to 130 times the 0.99 chi-square
// quantile and the robust width: far enough that
// neighbours agreeing with each other no longer suffice (a repeated wrong claim agrees with itself
// too), so they wait for the next background finish, which tests each one by its innovation
// against the whole map.  Each lies about 2.8 times above the strict threshold (the 0.99 quantile
// times the map's variance factor: the odometry's systematic drift is not in its declared
// covariance), and within kCorroboratedInnovationLenience (10) of it with its neighbours
// agreeing, so the finish releases them and the map is corrected.  With the lenience at 1 they
// stay held to the end.
TEST(BackgroundFinish, ARevisitFarFromTheMapWaitsForTheFinishWhichReleasesItsAgreeingLoopClosures) {
  const DriftScenario sc = makeDriftingSquare(3);
  PipelineOptions o = finishOptions();
  o.optimization.hold_until_supported = true;  // the node's default (the test options turn it off)
  Pipeline p(o);
  std::size_t lap3_first = 0;
  std::uint64_t released_at_lap3_first = 0;
  for (std::size_t i = 0; i < sc.odometry.size(); ++i) {
    p.handleOdometry(sc.odometry[i]);
    const std::size_t lap = i / 200, side = (i % 200) / 50;
    if (lap >= 1 && side == 1 && i % 5 == 0) {
      p.handleLoopClosure(trueLoopClosure(sc, i % 200, i));
      if (lap == 2 && lap3_first == 0) {
        lap3_first = p.graph().numConstraints() - 1;
        released_at_lap3_first = p.counters().loop_closures_released_predicted;
      }
    }
    drain(p);
    if (std::optional<FinishJob> job = p.takeFinishJob()) p.mergeFinish(runFinishJob(std::move(*job)));
    drain(p);
  }
  ASSERT_GT(lap3_first, 0u);
  // Lap 3's first loop closures were released by a finish (by their innovation, their neighbours
  // agreeing), not by their neighbours at once; every loop closure counts at the end.
  const PipelineCounters& n = p.counters();
  EXPECT_GE(n.loop_closures_released_predicted, released_at_lap3_first + 3);
  EXPECT_EQ(n.loop_closures_held, n.loop_closures_released);
  EXPECT_EQ(p.makeSnapshot()->down_weighted_loop_closures, 0u);
}

// A first revisit reported all at once while finishes run beside it (as the node's worker runs
// them): the loop closures held on arrival make finishes due, and those released while a finish
// ran (the fifth's support) are corrected after its merge, not set back to the finish's poses.
TEST(BackgroundFinish, LoopClosuresReleasedWhileAFinishRunsAreCorrectedAfterItsMerge) {
  const DriftScenario sc = makeDriftingSquare();
  PipelineOptions o;  // the node's defaults (config/map_corrector.yaml)
  o.keyframer.angle_rad = 0.35;
  const std::size_t last = sc.odometry.size() - 1;
  const double raw =
      (poseFromMsg(sc.odometry[last].pose.pose).translation() - sc.truth[last].translation()).norm();
  ASSERT_GT(raw, 1.0);
  const std::vector<LoopClosure> revisit = testing::revisitLoopClosures(sc, 0, last);
  // The finish taken after the first loop closure merges after the `merge_after`-th.
  for (std::size_t merge_after = 1; merge_after <= revisit.size(); ++merge_after) {
    SCOPED_TRACE("merged after loop closure " + std::to_string(merge_after));
    Pipeline p(o);
    feed(p, sc, 0, sc.odometry.size());
    std::optional<FinishJob> running;
    for (std::size_t k = 0; k < revisit.size(); ++k) {
      p.handleLoopClosure(revisit[k]);
      drain(p);
      if (!running) running = p.takeFinishJob();
      if (k + 1 == merge_after && running) {
        EXPECT_TRUE(p.mergeFinish(runFinishJob(std::move(*running))));
        drain(p);
        running = p.takeFinishJob();
      }
    }
    if (running) {
      EXPECT_TRUE(p.mergeFinish(runFinishJob(std::move(*running))));
    }
    drain(p);
    EXPECT_EQ(p.counters().loop_closures_released, 5u);
    EXPECT_EQ(p.makeSnapshot()->down_weighted_loop_closures, 0u);
    const double corrected =
        (p.makeSnapshot()->keyframes.back().map_T_base.translation() - sc.truth[last].translation()).norm();
    EXPECT_LT(corrected, 0.1 * raw) << "raw " << raw;
  }
}

// Only odometry with a free axis leaves the exact optimum undetermined: the chain fixes every pose
// whatever axes a loop closure leaves free.  Such odometry switches the finish off for the map, says
// why in the status once, and a reset forgets it.
TEST(BackgroundFinish, OffOnlyForOdometryWithUnmeasuredAxesAndTheStatusSaysWhy) {
  const DriftScenario sc = makeDriftingSquare(3);
  const std::size_t lap = sc.odometry.size() / 3;
  std::vector<std::string> warnings;
  const Pipeline::WarningSink sink = [&](const std::string& w) { warnings.push_back(w); };
  Pipeline free_loop_closure(finishOptions(), sink);
  feed(free_loop_closure, sc, 0, lap + 1);
  LoopClosure scan_match = trueLoopClosure(sc, 0, lap);
  for (int k : {2, 3, 4}) scan_match.covariance[7 * k] = 1e6;  // a 2D scan matcher: z, roll, pitch free
  free_loop_closure.handleLoopClosure(scan_match);
  drain(free_loop_closure);
  ASSERT_EQ(free_loop_closure.counters().loop_closures_applied, 1u);
  EXPECT_TRUE(free_loop_closure.takeFinishJob());
  EXPECT_EQ(free_loop_closure.status().finish_off_reason, "");

  // diff_drive_controller in 3D mode: 1e6 on z, roll and pitch in every message.
  DriftScenario pinned = sc;
  for (nav_msgs::Odometry& m : pinned.odometry)
    for (int k = 0; k < 6; ++k) m.pose.covariance[7 * k] = k >= 2 && k <= 4 ? 1e6 : 1e-3;
  warnings.clear();
  Pipeline free_odometry(finishOptions(), sink);
  feed(free_odometry, pinned, 0, lap + 1);
  free_odometry.handleLoopClosure(trueLoopClosure(pinned, 0, lap));
  drain(free_odometry);
  EXPECT_FALSE(free_odometry.takeFinishJob());
  EXPECT_FALSE(free_odometry.takeFinishJob());
  const std::string reason = free_odometry.status().finish_off_reason;
  EXPECT_NE(reason.find("odometry step(s) leave axes unmeasured"), std::string::npos) << reason;
  EXPECT_NE(reason.find("planar: true"), std::string::npos) << reason;
  std::size_t said = 0;
  for (const std::string& w : warnings) said += w.find("background finish off") != std::string::npos;
  EXPECT_EQ(said, 1u);
  free_odometry.reset("test");
  EXPECT_EQ(free_odometry.status().finish_off_reason, "");
}

// Once a finish was merged it settles the map: a due full round re-weighs and runs no pass (its
// passes, restarted at learning rate 1, would pull the map off the optimum).  Before any merge, as
// without the finish, a round runs its passes.
TEST(BackgroundFinish, AfterAMergeADueFullRoundRunsNoPass) {
  const DriftScenario sc = makeDriftingSquare(3);
  const std::size_t lap = sc.odometry.size() / 3;
  for (const bool merge : {false, true}) {
    PipelineOptions o = finishOptions();
    o.optimization.full_iterations = 5;
    o.optimization.full_every_keyframes = 4;
    Pipeline p(o);
    feed(p, sc, 0, lap + 1);
    p.handleLoopClosure(trueLoopClosure(sc, 0, lap));
    drain(p);
    std::optional<FinishJob> job = p.takeFinishJob();
    ASSERT_TRUE(job);
    if (merge) {
      ASSERT_TRUE(p.mergeFinish(runFinishJob(std::move(*job))));
    }
    // Keyframes, then a loop closure on the second lap: its pass, and a round falls due.
    feed(p, sc, lap + 1, lap + 31);
    const std::size_t passes_before = p.status().counters.optimization_passes;
    const toro::PoseGraph before = p.graph();
    p.handleLoopClosure(trueLoopClosure(sc, 25, lap + 25));
    const std::size_t lc = p.graph().numConstraints() - 1;
    const double arrival_chi2 = toro::constraintChi2(p.graph(), lc);
    drain(p);
    EXPECT_EQ(p.status().counters.optimization_passes - passes_before, merge ? 1u : 6u);
    // The loop closure's pass corrected the map for it either way.
    EXPECT_LT(toro::constraintChi2(p.graph(), lc), 0.1 * arrival_chi2);
    EXPECT_GT(maxPositionDifference(before, p.graph(), before.numNodes()), 1e-3);
  }
}

TEST(BackgroundFinish, FullOptimizeEndsAtTheOptimumWhenOn) {
  const DriftScenario sc = makeDriftingSquare();
  const std::size_t last = sc.odometry.size() - 1;
  for (const bool on : {false, true}) {
    PipelineOptions o = finishOptions();
    o.optimization.background_finish = on;
    Pipeline p(o);
    feed(p, sc, 0, sc.odometry.size());
    p.handleLoopClosure(trueLoopClosure(sc, 0, last));
    drain(p);
    const OptimizeResult r = p.optimize(5, "full");
    ASSERT_TRUE(r.success) << r.message;
    const double best = toro::g2oChi2(optimum(p.graph()));
    if (on) {
      EXPECT_NEAR(r.chi2_after, best, 1e-6 * best) << r.message;
      EXPECT_NE(r.message.find("finish"), std::string::npos);
    } else {
      EXPECT_GT(r.chi2_after, best * (1 + 1e-4)) << r.message;
    }
  }
}

// A loop closure whose robust weight is ~0 in TORO's passes stays out of the finish: the map after
// the merge is the optimum of the right loop closures alone.
TEST(BackgroundFinish, UsesTheRobustWeightsOfThePasses) {
  const DriftScenario sc = makeDriftingSquare(3);
  Pipeline p(finishOptions());
  const std::size_t lap = sc.odometry.size() / 3;
  feed(p, sc, 0, sc.odometry.size());
  for (std::size_t k = 0; k < 8; ++k)
    p.handleLoopClosure(trueLoopClosure(sc, 5 * k, 2 * lap + 5 * k));
  drain(p);
  LoopClosure wrong = trueLoopClosure(sc, 10, lap + lap / 2);
  wrong.from_T_to = poseToMsg(toro::Pose3::fromRollPitchYaw(15.0, -8.0, 0, 0, 0, 2.0));
  wrong.header.stamp = sc.odometry.back().header.stamp + ros::Duration(1.0);
  p.handleLoopClosure(wrong);
  drain(p);
  const std::size_t wrong_index = p.graph().numConstraints() - 1;
  std::optional<FinishJob> job = p.takeFinishJob();
  ASSERT_TRUE(job);
  ASSERT_LT(job->weights[wrong_index], toro::kRejectedWeight);
  ASSERT_TRUE(p.mergeFinish(runFinishJob(std::move(*job))));
  EXPECT_EQ(p.status().down_weighted.size(), 1u);
  // The optimum without the wrong one.
  const toro::PoseGraph clean =
      toro::keepConstraints(p.graph(), [&](std::size_t c) { return c < wrong_index; });
  // Its small weight still pulls a little; at full weight (the finish's own plain chi2) it would
  // pull the map metres away.
  const double from_clean = maxPositionDifference(optimum(clean), p.graph(), clean.numNodes());
  const double full_weight = maxPositionDifference(optimum(clean), optimum(p.graph()), clean.numNodes());
  EXPECT_GT(full_weight, 1.0);
  EXPECT_LT(from_clean, 0.05 * full_weight);
  EXPECT_LT(from_clean, 0.05);
}

// The schedule's clock runs on while odometry is quiet (the node's worker reports how long): a
// finish due by time comes although no odometry stamp advanced.  When odometry resumes behind
// the clock (a bag paused, then played on) the interval does not wait for it to catch up.
TEST(BackgroundFinish, TheIntervalRunsOnWhileOdometryIsQuietAndDoesNotWaitForItToCatchUp) {
  const DriftScenario sc = makeDriftingSquare(3);
  PipelineOptions o = finishOptions();
  o.optimization.finish_min_interval_sec = 1.0;
  Pipeline p(o);
  const std::size_t lap = (sc.odometry.size() - 1) / 3;
  auto finish = [&p] { return finishIfDue(p); };
  auto aboveOptimum = [&p] { return toro::g2oChi2(p.graph()) > 1.01 * toro::g2oChi2(optimum(p.graph())); };
  feed(p, sc, 0, 2 * lap + 1);
  p.handleLoopClosure(trueLoopClosure(sc, 0, lap));
  drain(p);
  ASSERT_TRUE(finish());
  // Odometry has stopped; the end of the second lap is the start again.  TORO's pass leaves the
  // map above the optimum: a finish is due, but message time stands still.
  p.handleLoopClosure(trueLoopClosure(sc, 0, 2 * lap));
  drain(p);
  ASSERT_TRUE(aboveOptimum());
  EXPECT_TRUE(p.finishPending());
  EXPECT_FALSE(p.takeFinishJob());
  p.setOdometryQuietSec(0.5);
  EXPECT_FALSE(p.takeFinishJob());
  p.setOdometryQuietSec(30.0);  // the bag was paused for 30 s
  ASSERT_TRUE(finish());
  EXPECT_FALSE(p.finishPending());
  // Played on: the third lap (20 s of stamps, all behind the clock the finish was taken at), then
  // its revisit.  The finish does not wait for the stamps to pass that clock.
  feed(p, sc, 2 * lap + 1, 3 * lap + 1);
  ASSERT_LT((sc.odometry[3 * lap].header.stamp - sc.odometry[2 * lap].header.stamp).toSec(), 30.0);
  p.handleLoopClosure(trueLoopClosure(sc, 0, 3 * lap));
  drain(p);
  ASSERT_TRUE(aboveOptimum());
  ASSERT_TRUE(finish());
  EXPECT_FALSE(aboveOptimum());
}

// Within finish_chi2_tolerance of the last finished map a finish waits while loop closures come,
// but once they pause for a second of message time one finish settles the map at the optimum:
// within 1 % in chi2 is not within 1 % at the far end of a long chain (parking-garage.g2o replayed:
// 0.5-0.7 m for 16 s after a revisit, bench/robust_offline_results.md, session 41).
TEST(BackgroundFinish, WithinTheToleranceTheMapStillSettlesAtTheOptimumOnceTheLoopClosuresPause) {
  const DriftScenario sc = makeDriftingSquare(2);
  PipelineOptions o = finishOptions();
  o.optimization.finish_chi2_tolerance = 1.0;  // every pass within it: only the pause finishes
  Pipeline p(o);
  auto finish = [&p] { return finishIfDue(p); };
  const std::size_t revisit = 225;
  feed(p, sc, 0, revisit + 1);
  p.handleLoopClosure(trueLoopClosure(sc, 25, revisit));
  drain(p);
  ASSERT_TRUE(finish());  // the first: nothing finished to compare with
  // More of the revisit (samples every 0.1 s): TORO's passes leave the map off the optimum.
  feed(p, sc, revisit + 1, revisit + 4);
  for (std::size_t k = 1; k <= 3; ++k) p.handleLoopClosure(trueLoopClosure(sc, 25 + k, revisit + k));
  drain(p);
  const std::size_t n = p.graph().numNodes();
  const double off_before = maxPositionDifference(p.graph(), optimum(p.graph()), n);
  ASSERT_GT(off_before, 1e-3);
  ASSERT_LE(p.status().last_chi2, 2.0 * p.status().last_finish->chi2_after);  // within the tolerance
  EXPECT_TRUE(p.finishPending());
  EXPECT_FALSE(p.takeFinishJob());
  feed(p, sc, revisit + 4, revisit + 12);  // 0.8 s after the newest loop closure
  EXPECT_FALSE(p.takeFinishJob());
  feed(p, sc, revisit + 12, revisit + 15);  // 1.1 s
  ASSERT_TRUE(finish());
  EXPECT_LT(maxPositionDifference(p.graph(), optimum(p.graph()), n), 0.01 * off_before);
  // One per pause: odometry alone asks for no other.
  feed(p, sc, revisit + 15, revisit + 60);
  EXPECT_FALSE(p.takeFinishJob());
  EXPECT_EQ(p.status().counters.finishes_started, 2u);
}

}  // namespace
}  // namespace toro_ros
