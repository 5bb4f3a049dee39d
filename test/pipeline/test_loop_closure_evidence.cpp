// LoopClosureEvidence (pipeline/loop_closure_evidence.h): the odometry, tree-path and pair cycles of
// a loop closure read from a growing map, its caches, and the thresholds learnt from the cycles
// tested so far.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "corridor_map.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/pipeline/loop_closure_evidence.h"

using namespace toro;
using toro_ros::LoopClosureEvidence;
using toro_ros::testing::Corridor;

TEST(LoopClosureEvidence, OdometryCycleTellsARightLoopClosureFromAWrongOneAndFollowsTheStructure) {
  Corridor c;
  LoopClosureEvidence evidence(c.map, c.is_loop_closure, false);
  const std::size_t right = c.loopClosure(15, 25);
  const std::size_t wrong = c.loopClosure(16, 24, Pose3::fromRollPitchYaw(2.0, 0, 0, 0, 0, 0));
  EXPECT_EQ(evidence.span(right), 10u);
  EXPECT_NEAR(evidence.odometryCycleChi2(right), 0.0, 1e-9);
  // 2 m off against 0.1 m and 8 odometry steps of 0.05 m (and 0.01 rad): far beyond the quantile.
  const double wrong_chi2 = evidence.odometryCycleChi2(wrong);
  EXPECT_GT(wrong_chi2, 2.0 * LoopClosureEvidence::declaredQuantile(6.0));

  // Cached per constraint: the same value until the owner says the indices changed.  A map rebuilt
  // with the wrong loop closure right at the same index gives the right cycle only after that.
  Corridor rebuilt;
  rebuilt.loopClosure(15, 25);
  rebuilt.loopClosure(16, 24);
  LoopClosureEvidence evidence2(rebuilt.map, rebuilt.is_loop_closure, false);
  EXPECT_NEAR(evidence2.odometryCycleChi2(wrong), 0.0, 1e-9);
  EXPECT_DOUBLE_EQ(evidence.odometryCycleChi2(wrong), wrong_chi2);
  c.map = rebuilt.map;  // same indices, another measurement at `wrong`
  EXPECT_DOUBLE_EQ(evidence.odometryCycleChi2(wrong), wrong_chi2);  // still the cached one
  evidence.forgetStructure();
  EXPECT_NEAR(evidence.odometryCycleChi2(wrong), 0.0, 1e-9);
}

TEST(LoopClosureEvidence, NeighboursArePairsOfPlacesWithinTheWindowAndPairCyclesAgreeForTheRightOnes) {
  Corridor c;
  LoopClosureEvidence evidence(c.map, c.is_loop_closure, false);
  const std::size_t a = c.loopClosure(15, 25);
  const std::size_t b = c.loopClosure(17, 23);
  const std::size_t far = c.loopClosure(5, 35);
  const std::size_t wrong = c.loopClosure(14, 26, Pose3::fromRollPitchYaw(0.0, 1.0, 0, 0, 0, 0));
  std::vector<std::size_t> seen;
  const auto collect = [&](std::size_t j, std::size_t, std::size_t) {
    seen.push_back(j);
    return false;
  };
  EXPECT_FALSE(evidence.visitNeighbours(a, 3, collect));
  std::sort(seen.begin(), seen.end());
  EXPECT_EQ(seen, (std::vector<std::size_t>{b, wrong}));  // not `far` (10 poses off), not a itself
  seen.clear();
  evidence.visitNeighbours(a, 10, collect);
  EXPECT_EQ(std::count(seen.begin(), seen.end(), far), 1);
  // Stops at the first visit that says so.
  EXPECT_TRUE(evidence.visitNeighbours(a, 3, [](std::size_t, std::size_t, std::size_t) { return true; }));

  EXPECT_NEAR(evidence.pairChi2(a, b), 0.0, 1e-9);
  EXPECT_GT(evidence.pairChi2(a, wrong), 20.0);
}

TEST(LoopClosureEvidence, PairThresholdNarrowsToTheSendersScaleOnceEnoughPairsWereTestedNeverWidens) {
  Corridor c;
  LoopClosureEvidence evidence(c.map, c.is_loop_closure, false);
  const double declared = toro::chiSquareQuantile(toro_ros::kSupportConfidence, 6.0);
  EXPECT_DOUBLE_EQ(evidence.pairThreshold(6.0), declared);
  // A sender that declares 100 times its noise in variance: its right pairs' chi2 are 1/100 of the
  // chi-square's.
  for (std::size_t k = 0; k + 1 < toro_ros::kMinPairsToAdaptSupport; ++k) evidence.testedPairs().add(0.06);
  EXPECT_DOUBLE_EQ(evidence.pairThreshold(6.0), declared);  // too few to read a scale
  evidence.testedPairs().add(0.06);
  const double expected = declared * toro_ros::kSupportLenience * 0.06 / toro::chiSquareQuantile(0.2, 6.0);
  EXPECT_NEAR(evidence.pairThreshold(6.0), expected, 1e-12);
  EXPECT_LT(evidence.pairThreshold(6.0), 0.1 * declared);
  // Large cycles (wrong pairs) widen nothing beyond the declared quantile.
  for (int k = 0; k < 2000; ++k) evidence.testedPairs().add(1e6);
  EXPECT_DOUBLE_EQ(evidence.pairThreshold(6.0), declared);
  // The path veto: a lenience times the declared quantile until paths were tested.
  EXPECT_DOUBLE_EQ(evidence.pathThreshold(true, 3.0),
                   toro_ros::kPathLenience * toro::chiSquareQuantile(toro_ros::kSupportConfidence, 3.0));
  evidence.clear();
  EXPECT_EQ(evidence.testedPairs().count(), 0u);
  EXPECT_DOUBLE_EQ(evidence.pairThreshold(6.0), declared);
}

TEST(LoopClosureEvidence, MapPathCountsOnlyPathsThroughLoopClosuresThatCount) {
  Corridor c;
  LoopClosureEvidence evidence(c.map, c.is_loop_closure, false);
  // Not yet a tree edge: the tree is the odometry chain, and a path of odometry alone is not this
  // test's (odometryCycleChi2 says the same).
  const std::size_t first = c.loopClosure(10, 30, Pose3(), false);
  EXPECT_LT(evidence.mapPathChi2(first), 0.0);
  // Admitted, it becomes pose 30's tree edge (10 is its smallest neighbour), and the tree path
  // between 9 and 31 (or 8 and 32) runs through it: a right loop closure there closes that cycle,
  // a wrong one does not.
  c.map.admitToTree(first);
  const std::size_t right = c.loopClosure(9, 31, Pose3(), false);
  const std::size_t wrong = c.loopClosure(8, 32, Pose3::fromRollPitchYaw(2.0, 0, 0, 0, 0, 0), false);
  const double right_chi2 = evidence.mapPathChi2(right);
  ASSERT_GE(right_chi2, 0.0);
  EXPECT_NEAR(right_chi2, 0.0, 1e-9);
  EXPECT_GT(evidence.mapPathChi2(wrong), 2.0 * LoopClosureEvidence::declaredQuantile(6.0));
  // With `first` held (weight cap 0) it is no evidence: no path through loop closures is left.
  c.map.setWeightCap(first, 0.0);
  EXPECT_LT(evidence.mapPathChi2(right), 0.0);
}
