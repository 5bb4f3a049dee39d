// LoopClosureSupport (pipeline/loop_closure_support.h): the rules that hold, release and judge loop
// closures again, on a small map of their own, with a recording Owner in place of MapOptimizer's
// schedule.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "corridor_map.h"
#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/pipeline/loop_closure_evidence.h"
#include "toro_ros/pipeline/loop_closure_support.h"

using namespace toro;
using toro_ros::LoopClosureEvidence;
using toro_ros::LoopClosureSupport;
using toro_ros::PipelineCounters;

namespace {

// What the schedule is told, and what it answers.
struct RecordingOwner : LoopClosureSupport::Owner {
  double width = 10.0;
  bool finish_on = false;
  std::size_t held = 0, held_testable = 0, released = 0;
  std::vector<std::size_t> held_again;

  double kernelWidth() const override { return width; }
  double dof() const override { return 6.0; }
  bool backgroundFinishOn() const override { return finish_on; }
  bool finishDetermined() override { return true; }
  std::uint64_t structure() const override { return 1; }
  void loopClosureHeld(bool testable) override {
    ++held;
    if (testable) ++held_testable;
  }
  void loopClosureReleased() override { ++released; }
  void acceptedLoopClosureHeld(std::size_t c) override { held_again.push_back(c); }
};

TreeOptimizerOptions robustOptions() {
  TreeOptimizerOptions o;
  o.robust.kernel = RobustKernel::kDcs;
  o.robust.width = 10.0;
  return o;
}

// The corridor with the support rules wired as MapOptimizer wires them (robust loop closures; a
// loop closure joins the tree only once it counts).
struct Corridor : toro_ros::testing::Corridor {
  LoopClosureEvidence evidence{map, is_loop_closure, false};
  PipelineCounters counters;
  RecordingOwner owner;
  LoopClosureSupport support{map, evidence, is_loop_closure, &counters, owner};

  Corridor() : toro_ros::testing::Corridor(robustOptions()) { support.configure(true, 25); }
  // A loop closure off the truth by `error`, judged on arrival.
  std::size_t arrive(int from, int to, const Pose3& error = Pose3()) {
    const std::size_t c = loopClosure(from, to, error, !support.enabled());
    support.judgeSupport(c);
    if (!(map.weightCap(c) < 1.0)) map.admitToTree(c);
    return c;
  }
};

}  // namespace

TEST(LoopClosureSupport, AWrongLoopClosureTheOdometryRefutesIsHeldAndTheOwnerIsTold) {
  Corridor c;
  // 2 m off over a span of 8 keyframes of exact, precise odometry.
  const std::size_t wrong = c.arrive(16, 24, Pose3::fromRollPitchYaw(2.0, 0, 0, 0, 0, 0));
  EXPECT_DOUBLE_EQ(c.map.weightCap(wrong), 0.0);
  EXPECT_EQ(c.support.held(), 1u);
  EXPECT_EQ(c.counters.loop_closures_held, 1u);
  EXPECT_EQ(c.owner.held, 1u);
  // No loop closure counts yet, so no finish could read the covariances' scale to test it.
  EXPECT_EQ(c.owner.held_testable, 0u);
  EXPECT_EQ(c.owner.released, 0u);
  // A right one the map agrees with (exact odometry: its chi2 on the map is 0) counts at once.
  const std::size_t right = c.arrive(15, 25);
  EXPECT_DOUBLE_EQ(c.map.weightCap(right), 1.0);
  EXPECT_EQ(c.support.held(), 1u);
  // The settled map does not agree with the wrong one: nothing is released.
  EXPECT_FALSE(c.support.releaseAgreed());
  EXPECT_EQ(c.owner.released, 0u);
}

TEST(LoopClosureSupport, AHeldLoopClosureTheSettledMapAgreesWithIsReleasedAndTheOwnerAskedForItsPass) {
  Corridor c;
  // Slightly off (0.3 m against 0.1 m declared): its chi2 on the map (9) is above a narrow kernel
  // width, so the map does not accept it, and with the window set to 0 no odometry verdict or
  // neighbour can.
  c.support.configure(true, 0);
  c.owner.width = 0.5;
  const std::size_t off = c.arrive(12, 28, Pose3::fromRollPitchYaw(0.3, 0, 0, 0, 0, 0));
  ASSERT_DOUBLE_EQ(c.map.weightCap(off), 0.0);
  // Beyond ten widths of the map: not even the map's evidence between its ends releases it.
  EXPECT_FALSE(c.support.releaseAgreed());
  EXPECT_EQ(c.owner.released, 0u);
  // The owner's width widens (its adaptation followed the accepted loop closures): now within ten
  // widths, and the odometry over its whole span agrees with it (0.3 m against the 0.22 m of its
  // cycle's standard deviation).
  c.owner.width = 1.0;
  EXPECT_TRUE(c.support.releaseAgreed());
  EXPECT_DOUBLE_EQ(c.map.weightCap(off), 1.0);
  EXPECT_EQ(c.owner.released, 1u);
  EXPECT_EQ(c.counters.loop_closures_released, 1u);
  EXPECT_EQ(c.support.held(), 0u);
  // Released once: a second call has nothing left to release.
  EXPECT_FALSE(c.support.releaseAgreed());
  EXPECT_EQ(c.owner.released, 1u);
}

TEST(LoopClosureSupport, OffItHoldsNothing) {
  Corridor c;
  c.support.configure(false, 25);
  const std::size_t wrong = c.arrive(16, 24, Pose3::fromRollPitchYaw(2.0, 0, 0, 0, 0, 0));
  EXPECT_DOUBLE_EQ(c.map.weightCap(wrong), 1.0);
  EXPECT_EQ(c.owner.held, 0u);
  EXPECT_TRUE(c.support.innovationCandidates(c.map.weights(), 0.1, 1.0).empty());
}

TEST(LoopClosureSupport, FinishesTestTheHeldOnesTestedLongestAgoFirstAndTestAgainOnceTheMapGrew) {
  Corridor c;
  std::vector<std::size_t> wrong;
  for (int k = 0; k < 12; ++k) {
    // Wrong ones 2 m off, each a different pair of places (spans 4 to 26 keyframes).
    const int from = 18 - k % 6, to = 22 + k / 2;
    wrong.push_back(c.arrive(from, to, Pose3::fromRollPitchYaw(2.0, 0, 0, 0, 0, 0)));
  }
  ASSERT_EQ(c.support.held(), wrong.size());
  std::vector<double> weights = c.map.weights();
  for (std::size_t w : wrong) weights[w] = 0.0;  // left out of the finish (below its set-aside weight)
  // At most 8 a finish; the next finish takes the 4 not tested yet first, then the oldest tested.
  const std::vector<std::size_t> first = c.support.innovationCandidates(weights, 0.1, 5.0);
  ASSERT_EQ(first.size(), 8u);
  EXPECT_EQ(first, std::vector<std::size_t>(wrong.begin(), wrong.begin() + 8));
  const std::vector<std::size_t> second = c.support.innovationCandidates(weights, 0.1, 5.0);
  ASSERT_EQ(second.size(), 8u);
  for (std::size_t k = 8; k < 12; ++k) EXPECT_EQ(std::count(second.begin(), second.end(), wrong[k]), 1);
  // Tested again once the loop closures counted grew by a tenth since the last tests.
  EXPECT_FALSE(c.support.innovationRetestDue(5.4));
  EXPECT_TRUE(c.support.innovationRetestDue(5.5));
  // A held one is never a calibration sample; with no held one tested and the calibration not
  // needed yet (few loop closures count), there are none.
  EXPECT_TRUE(c.support.calibrationSamples(weights, 0.1, 5.0, false).empty());
  const std::size_t right = c.arrive(15, 25);
  weights = c.map.weights();
  for (std::size_t w : wrong) weights[w] = 0.0;
  EXPECT_EQ(c.support.calibrationSamples(weights, 0.1, 5.0, true), std::vector<std::size_t>{right});
  // The redundancy a finish has: the one that counts.
  EXPECT_DOUBLE_EQ(c.support.loopClosureWeight(weights), 1.0);
  // Forgotten with a reset: the next test starts from the first held one again, and the re-test
  // is due at once.
  c.support.clear();
  EXPECT_TRUE(c.support.innovationRetestDue(0.0));
  EXPECT_EQ(c.support.innovationCandidates(weights, 0.1, 5.0),
            std::vector<std::size_t>(wrong.begin(), wrong.begin() + 8));
}
