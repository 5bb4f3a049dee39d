// Incremental snapshots: the chunked vectors they are made of share what did not change and never
// change under a reader, the builder writes only what the optimiser's journal lists, and the
// pipeline's snapshots equal what its graph says at every step (new keyframes, affected passes,
// full rounds, robust down-weighting, the gate's restore, reset).
#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/pipeline.h"
#include "toro_ros/pipeline/snapshot_builder.h"

using namespace toro_ros;
using toro_ros::testing::DriftScenario;
using toro_ros::testing::makeDriftingSquare;
using toro_ros::testing::trueLoopClosure;

namespace {

bool samePose(const toro::Pose3& a, const toro::Pose3& b) {
  return a.translation() == b.translation() && a.rotation().coeffs() == b.rotation().coeffs();
}

// What makeSnapshot's keyframes and edges must be, read from the pipeline's graph directly.
void expectSnapshotMatchesGraph(const Pipeline& p, const Snapshot& s, const std::string& when) {
  const toro::PoseGraph& g = p.graph();
  const auto& records = p.keyframes().records();
  ASSERT_EQ(s.keyframes.size(), records.size()) << when;
  ASSERT_EQ(s.keyframes.size(), g.numNodes()) << when;
  for (std::size_t i = 0; i < records.size(); ++i) {
    ASSERT_EQ(s.keyframes[i].id, records[i].id) << when;
    ASSERT_EQ(s.keyframes[i].stamp, records[i].stamp) << when;
    ASSERT_TRUE(samePose(s.keyframes[i].map_T_base, g.node(i).pose)) << when << ": keyframe " << i;
  }
  ASSERT_EQ(s.edges.size(), g.numConstraints()) << when;
  std::size_t down_weighted = 0;
  for (std::size_t c = 0; c < g.numConstraints(); ++c) {
    const toro::Constraint& k = g.constraints()[c];
    const SnapshotEdge& e = s.edges[c];
    ASSERT_EQ(e.from_index, g.indexOf(k.from)) << when;
    ASSERT_EQ(e.to_index, g.indexOf(k.to)) << when;
    ASSERT_EQ(e.loop_closure, k.kind == toro::ConstraintKind::kLoopClosure) << when << ": edge " << c;
    const double chi2 = e.loop_closure ? toro::constraintChi2(g, c) : 0.0;
    ASSERT_NEAR(e.chi2, chi2, 1e-9 * std::max(1.0, chi2)) << when << ": edge " << c;
    if (e.loop_closure && e.weight < toro::kRejectedWeight) ++down_weighted;
  }
  EXPECT_EQ(s.down_weighted_loop_closures, down_weighted) << when;
  const PipelineStatus status = p.status();
  EXPECT_EQ(status.down_weighted.size(), down_weighted) << when;
  for (const DownWeightedLoopClosure& d : status.down_weighted) {
    bool found = false;
    for (std::size_t c = 0; c < g.numConstraints(); ++c)
      found = found || (g.constraints()[c].from == d.from && g.constraints()[c].to == d.to &&
                        s.edges[c].weight == d.weight);
    EXPECT_TRUE(found) << when << ": down-weighted " << d.from << " -> " << d.to;
  }
}

LoopClosure wrongLoopClosure(const DriftScenario& sc, std::size_t claimed, std::size_t at) {
  LoopClosure lc = trueLoopClosure(sc, claimed, at);
  lc.from_T_to = poseToMsg(toro::Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, M_PI));
  return lc;
}

// Four laps of the drifting square with true loop closures at the corners of laps 2-4 and one wrong
// one; a snapshot after every message and every scheduled pass, each checked against the graph.
void runAndCheck(PipelineOptions o) {
  const DriftScenario sc = makeDriftingSquare(4);
  Pipeline p(o);
  std::shared_ptr<const Snapshot> previous = p.makeSnapshot();
  std::size_t checked = 0, passes = 0;
  const auto check = [&](const std::string& when) {
    // The previous snapshot must not change when the next is made (readers hold it meanwhile).
    std::vector<toro::Pose3> held;
    for (const SnapshotKeyframe& k : previous->keyframes) held.push_back(k.map_T_base);
    const std::shared_ptr<const Snapshot> s = p.makeSnapshot();
    for (std::size_t i = 0; i < held.size(); ++i)
      ASSERT_TRUE(samePose(held[i], previous->keyframes[i].map_T_base)) << when << ": held keyframe " << i;
    expectSnapshotMatchesGraph(p, *s, when);
    previous = s;
    ++checked;
  };
  for (std::size_t i = 0; i < sc.odometry.size(); ++i) {
    p.handleOdometry(sc.odometry[i]);
    if (i % 3 == 0) check("odometry " + std::to_string(i));
    if (i >= 200 && i % 50 == 0) {
      p.handleLoopClosure(i == 450 ? wrongLoopClosure(sc, i - 200 + 20, i) : trueLoopClosure(sc, i - 200, i));
      check("loop closure at " + std::to_string(i));
    }
    for (int k = 0; k < 3 && p.runScheduledOptimization(); ++k, ++passes) check("pass after " + std::to_string(i));
  }
  EXPECT_GT(checked, 250u);
  EXPECT_GE(passes, 10u);
  p.reset("test");
  check("reset");
  for (std::size_t i = 0; i < 30; ++i) p.handleOdometry(sc.odometry[i]);
  check("after the reset");
}

}  // namespace

TEST(ChunkedVector, CopiesShareUnchangedChunksAndNeverSeeLaterWrites) {
  ChunkedVector<int, 4> working;
  for (int i = 0; i < 10; ++i) working.push_back(i);
  const ChunkedVector<int, 4> published = working.share();
  ASSERT_EQ(published.size(), 10u);
  for (std::size_t i = 0; i < 10; ++i) EXPECT_EQ(published[i], static_cast<int>(i));
  EXPECT_TRUE(published.sharesElementWith(working, 0));
  working.set(5, 50);   // chunk 1 is copied first
  working.push_back(10);  // chunk 2 (partly filled, shared) too
  EXPECT_EQ(published[5], 5);
  EXPECT_EQ(published.size(), 10u);
  EXPECT_EQ(working[5], 50);
  EXPECT_EQ(working.back(), 10);
  EXPECT_TRUE(published.sharesElementWith(working, 0));   // chunk 0 unchanged: still one object
  EXPECT_FALSE(published.sharesElementWith(working, 5));
  EXPECT_FALSE(published.sharesElementWith(working, 8));
  // A plain copy of a vector with writable chunks copies those (they would change under it).
  const ChunkedVector<int, 4> copy = working;
  working.set(4, 40);
  EXPECT_EQ(copy[4], 4);
  EXPECT_TRUE(copy.sharesElementWith(published, 0));
  int sum = 0;
  for (int x : copy) sum += x;
  EXPECT_EQ(sum, 0 + 1 + 2 + 3 + 4 + 50 + 6 + 7 + 8 + 9 + 10);
  ChunkedVector<int, 4> moved = std::move(working);
  EXPECT_EQ(moved.size(), 11u);
  EXPECT_TRUE(working.empty());  // NOLINT(bugprone-use-after-move): moved-from is empty by contract
  const ChunkedVector<int, 4> listed{1, 2, 3, 4, 5};
  EXPECT_EQ(listed.size(), 5u);
  EXPECT_EQ(listed.back(), 5);
}

TEST(SnapshotBuilder, WritesOnlyWhatTheJournalLists) {
  // A chain of 5000 keyframes and one loop closure over its last 100: the update after the pass
  // rewrites about 100 keyframes and their edges, not 5000, and shares the other chunks.
  toro::TreeOptimizer opt;
  std::vector<KeyframeRecord> records;
  std::vector<bool> is_loop_closure;
  const toro::Pose3 step = toro::Pose3::fromRollPitchYaw(0.1, 0, 0, 0, 0, 0.01);
  SnapshotBuilder builder;
  for (std::size_t v = 0; v < 5000; ++v) {
    const toro::Pose3 pose = v == 0 ? toro::Pose3() : opt.graph().node(v - 1).pose * step;
    opt.addNode(static_cast<toro::NodeId>(v), pose);
    records.push_back(KeyframeRecord{static_cast<toro::NodeId>(v), ros::Time(100 + 0.1 * v), pose});
    if (v > 0) {
      opt.addConstraint(toro::Constraint{static_cast<toro::NodeId>(v - 1), static_cast<toro::NodeId>(v), step,
                                         toro::Matrix6::Identity(), toro::ConstraintKind::kOdometry});
      is_loop_closure.push_back(false);
    }
  }
  opt.clearAffected();  // the chain is settled: the pass below is the loop closure's alone
  builder.update(opt, records, is_loop_closure);
  EXPECT_EQ(builder.lastWritten(), 5000u + 4999u);  // the first update writes everything
  builder.update(opt, records, is_loop_closure);
  EXPECT_EQ(builder.lastWritten(), 0u);
  const ChunkedVector<SnapshotKeyframe> before = builder.shareKeyframes();
  toro::Pose3 measured = opt.graph().node(4899).pose.inverse() * opt.graph().node(4999).pose;
  measured = measured * toro::Pose3::fromRollPitchYaw(0.5, 0.2, 0, 0, 0, 0.1);
  opt.addConstraint(toro::Constraint{4899, 4999, measured, 10 * toro::Matrix6::Identity(),
                                     toro::ConstraintKind::kLoopClosure});
  is_loop_closure.push_back(true);
  opt.iterateAffected(1);
  builder.update(opt, records, is_loop_closure);
  // The 100 moved keyframes 4900..4999 + the new loop closure; the odometry edges along the path
  // show nothing that changed.
  EXPECT_EQ(builder.lastWritten(), 100u + 1u);
  const ChunkedVector<SnapshotKeyframe> after = builder.shareKeyframes();
  const ChunkedVector<SnapshotEdge> edges = builder.shareEdges();
  ASSERT_EQ(after.size(), 5000u);
  ASSERT_EQ(edges.size(), 5000u);
  for (std::size_t v = 0; v < 5000; ++v) ASSERT_TRUE(samePose(after[v].map_T_base, opt.graph().node(v).pose)) << v;
  EXPECT_NEAR(edges.back().chi2, toro::constraintChi2(opt.graph(), 4999), 1e-12);
  EXPECT_TRUE(edges.back().loop_closure);
  EXPECT_TRUE(after.sharesElementWith(before, 0));
  EXPECT_TRUE(after.sharesElementWith(before, 4000));
  EXPECT_FALSE(after.sharesElementWith(before, 4999));
  EXPECT_FALSE(samePose(before[4999].map_T_base, after[4999].map_T_base));  // the old one kept its pose
}

TEST(PipelineSnapshot, EqualsTheGraphAtEveryStepWithRobustWeights) {
  PipelineOptions o = toro_ros::testing::roundsEvery10Keyframes();
  runAndCheck(o);
}

TEST(PipelineSnapshot, EqualsTheGraphAtEveryStepWithTheGate) {
  PipelineOptions o = toro_ros::testing::roundsEvery10Keyframes();
  o.loop_closure_gate_confidence = 0.99;
  runAndCheck(o);
}

TEST(PipelineSnapshot, EqualsTheGraphAtEveryStepInThePlaneWithoutFullRounds) {
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.optimization.full_iterations = 0;
  o.planar = true;
  runAndCheck(o);
}
