// The pairwise consistency of loop closures over the odometry (core/loop_closure_pairs.h).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "toro_ros/core/loop_closure_pairs.h"
#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/random_draws.h"

using namespace toro;

namespace {

// Information with the given standard deviations, in g2o's quaternion units (rotation x4).
Matrix6 informationOf(double stddev_m, double stddev_rad) {
  Matrix6 info = Matrix6::Zero();
  for (int k = 0; k < 3; ++k) {
    info(k, k) = 1.0 / (stddev_m * stddev_m);
    info(k + 3, k + 3) = 4.0 / (stddev_rad * stddev_rad);
  }
  return info;
}

// A corridor driven there and back: 40 poses, 1 m steps with a 180 degree turn at pose 20, so
// pose 20 + k and pose 20 - k are the same place seen from either way (true poses in `truth`).
struct Corridor {
  PoseGraph graph;
  std::vector<Pose3> truth;
};

Corridor corridor(bool planar_only) {
  Corridor c;
  Pose3 pose;
  for (int i = 0; i < 40; ++i) {
    c.truth.push_back(pose);
    c.graph.addNode(i, pose);
    const Pose3 step = i == 19 ? Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, M_PI)
                               : Pose3::fromRollPitchYaw(1.0, 0, planar_only ? 0.0 : 0.01, 0, 0, 0);
    pose = pose * step;
  }
  for (int i = 1; i < 40; ++i)
    c.graph.addConstraint({i - 1, i, relativePose(c.truth[i - 1], c.truth[i]), informationOf(0.05, 0.01),
                           ConstraintKind::kOdometry});
  return c;
}

std::size_t addLoopClosure(Corridor& c, int from, int to, const Pose3& error = Pose3()) {
  return c.graph.addConstraint(
      {from, to, relativePose(c.truth[from], c.truth[to]) * error, informationOf(0.1, 0.05), ConstraintKind::kLoopClosure});
}

}  // namespace

TEST(LoopClosurePairs, OdometryStepsFollowTheDrivingOrder) {
  Corridor c = corridor(false);
  addLoopClosure(c, 15, 25);
  const std::vector<std::size_t> steps = odometrySteps(c.graph, {});
  ASSERT_EQ(steps.size(), 40u);
  EXPECT_EQ(steps[0], kNoOdometry);
  for (std::size_t v = 1; v < 40; ++v) EXPECT_EQ(steps[v], v - 1);  // constraint v-1 joins v-1 and v
}

TEST(LoopClosurePairs, TwoRightLoopClosuresAgreeAndAWrongOneDoesNot) {
  Corridor c = corridor(false);
  const std::size_t right = addLoopClosure(c, 15, 25);
  const std::size_t neighbour = addLoopClosure(c, 17, 23);
  const std::size_t backwards = addLoopClosure(c, 24, 16);  // stored the other way round
  // Claims the robot was 3 m further than it was (a repeated structure along the corridor).
  const std::size_t wrong = addLoopClosure(c, 16, 24, Pose3::fromRollPitchYaw(3.0, 0, 0, 0, 0, 0));
  const OdometryChain odometry(c.graph, {}, false);
  EXPECT_NEAR(loopClosurePairChi2(c.graph, odometry, right, neighbour), 0.0, 1e-9);
  EXPECT_NEAR(loopClosurePairChi2(c.graph, odometry, right, backwards), 0.0, 1e-9);
  EXPECT_NEAR(loopClosurePairChi2(c.graph, odometry, neighbour, right), 0.0, 1e-9);
  const double chi2 = loopClosurePairChi2(c.graph, odometry, right, wrong);
  // 3 m against 0.1 m on both loop closures and ~0.05 m * sqrt(2) of odometry: about (3 / 0.15)^2.
  EXPECT_GT(chi2, 300.0);
  EXPECT_LT(chi2, 500.0);
  EXPECT_NEAR(loopClosurePairChi2(c.graph, odometry, wrong, right), chi2, 1e-6 * chi2);
}

TEST(LoopClosurePairs, OdometryStoredBackwardsAndAChainGrownStepByStepGiveTheSameCycles) {
  Corridor c = corridor(false);
  // The same corridor with its odometry from 12 to 13 and 20 to 21 stored the other way round.
  PoseGraph flipped;
  for (const Node& node : c.graph.nodes()) flipped.addNode(node.id, node.pose);
  for (const Constraint& k : c.graph.constraints()) {
    Constraint m = k;
    if (k.from == 12 || k.from == 20) {
      std::swap(m.from, m.to);
      m.measurement = k.measurement.inverse();
      // The covariance carried to the other end (first order, and in g2o's units, so the cycles
      // below agree to ~1e-5, not to rounding).
      const Matrix6 ad = adjoint(k.measurement);
      m.information = (ad * k.information.inverse() * ad.transpose()).inverse();
    }
    flipped.addConstraint(m);
  }
  const Constraint right{15, 25,
                         relativePose(c.truth[15], c.truth[25]) * Pose3::fromRollPitchYaw(0.3, 0, 0, 0, 0, 0),
                         informationOf(0.1, 0.05), ConstraintKind::kLoopClosure};
  const Constraint other{11, 29, relativePose(c.truth[11], c.truth[29]), informationOf(0.1, 0.05),
                         ConstraintKind::kLoopClosure};
  const std::size_t a = c.graph.addConstraint(right), b = c.graph.addConstraint(other);
  ASSERT_EQ(flipped.addConstraint(right), a);
  ASSERT_EQ(flipped.addConstraint(other), b);
  const OdometryChain forward(c.graph, {}, false);
  OdometryChain grown(false);
  for (std::size_t step : odometrySteps(flipped, {})) grown.append(flipped, step);
  EXPECT_TRUE(grown.reversed(13));
  EXPECT_FALSE(grown.reversed(14));
  const double expected = loopClosurePairChi2(c.graph, forward, a, b);
  EXPECT_GT(expected, 1.5);  // 0.3 m off: something to compare
  EXPECT_NEAR(loopClosurePairChi2(flipped, grown, a, b), expected, 1e-4 * expected);
  EXPECT_NEAR(loopClosurePairChi2(flipped, OdometryChain(flipped, {}, false), a, b), expected,
              1e-4 * expected);
}

TEST(LoopClosurePairs, ChiSquareDistributedForRightOnesWithNoise) {
  // With noise drawn from the declared covariances, the cycle's chi2 has 6 degrees of freedom.
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  double sum = 0.0;
  const int runs = 400;
  for (int r = 0; r < runs; ++r) {
    Corridor c = corridor(false);
    PoseGraph noisy;
    for (const Node& node : c.graph.nodes()) noisy.addNode(node.id, node.pose);
    const auto noise = [&](double sm, double sr) {
      const auto d = drawLastFirst<6>(n, rng);
      return Pose3::fromRollPitchYaw(sm * d[0], sm * d[1], sm * d[2], sr * d[3], sr * d[4], sr * d[5]);
    };
    for (const Constraint& k : c.graph.constraints()) {
      Constraint m = k;
      m.measurement = k.measurement * noise(0.05, 0.01);
      noisy.addConstraint(m);
    }
    c.graph = noisy;
    const std::size_t a = c.graph.addConstraint({15, 25, relativePose(c.truth[15], c.truth[25]) * noise(0.1, 0.05),
                                                  informationOf(0.1, 0.05), ConstraintKind::kLoopClosure});
    const std::size_t b = c.graph.addConstraint({17, 23, relativePose(c.truth[17], c.truth[23]) * noise(0.1, 0.05),
                                                  informationOf(0.1, 0.05), ConstraintKind::kLoopClosure});
    sum += loopClosurePairChi2(c.graph, OdometryChain(c.graph, {}, false), a, b);
  }
  // Mean 6 (roll-pitch-yaw noise is close to the rotation vector's at these angles).
  EXPECT_NEAR(sum / runs, 6.0, 1.0);
}

TEST(LoopClosurePairs, PlanarUsesXYAndYawAndAGapInTheOdometryCannotBeTested) {
  Corridor c = corridor(true);
  c.graph.setDimension(GraphDimension::k2D);
  const std::size_t right = addLoopClosure(c, 15, 25);
  const std::size_t wrong = addLoopClosure(c, 16, 24, Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, 0.5));
  const double chi2 = loopClosurePairChi2(c.graph, OdometryChain(c.graph, {}, true), right, wrong);
  // 0.5 rad against 0.05 rad on each loop closure: ~ 0.5^2 / (2 * 0.05^2) = 50, plus the lever
  // arm the yaw error gives the translation.
  EXPECT_GT(chi2, 40.0);
  const std::size_t neighbour = addLoopClosure(c, 14, 26);
  EXPECT_NEAR(loopClosurePairChi2(c.graph, OdometryChain(c.graph, {}, true), right, neighbour), 0.0, 1e-9);
  OdometryChain gap(true);
  const std::vector<std::size_t> steps = odometrySteps(c.graph, {});
  for (std::size_t v = 0; v < steps.size(); ++v) gap.append(c.graph, v == 16 ? kNoOdometry : steps[v]);
  // The odometry between 15 and 16 is missing.
  EXPECT_EQ(loopClosurePairChi2(c.graph, gap, right, wrong), -1.0);
}

TEST(LoopClosurePairs, OdometryDecidesNearbyLoopClosures) {
  Corridor c = corridor(false);
  const std::size_t right = addLoopClosure(c, 18, 22);
  const std::size_t wrong = addLoopClosure(c, 10, 13, Pose3::fromRollPitchYaw(-3.0, 0, 0, 0, 0, 0));  // "same place"
  const OdometryChain odometry(c.graph, {}, false);
  EXPECT_NEAR(loopClosureOdometryChi2(c.graph, odometry, right), 0.0, 1e-9);
  EXPECT_GT(loopClosureOdometryChi2(c.graph, odometry, wrong), 300.0);
  // The flags say what is odometry: with every constraint a loop closure nothing connects them.
  const std::vector<bool> all_loop_closures(c.graph.numConstraints(), true);
  EXPECT_EQ(loopClosureOdometryChi2(c.graph, OdometryChain(c.graph, all_loop_closures, false), right), -1.0);
}

TEST(LoopClosurePairs, ChainThroughAnAcceptedLoopClosureIsStifferThanTheOdometry) {
  // Nodes 0..19 out, 20..39 back along the same line.  A right loop closure 15 -> 24 makes the
  // path from 10 to 30 short: 10 -> 15 (odometry), 15 -> 24 (a precise loop closure), 24 -> 30.
  Corridor c = corridor(false);
  const std::size_t shortcut = c.graph.addConstraint({15, 24, relativePose(c.truth[15], c.truth[24]),
                                                      informationOf(0.01, 0.002), ConstraintKind::kLoopClosure});
  const std::size_t claim = addLoopClosure(c, 10, 30, Pose3::fromRollPitchYaw(1.0, 0, 0, 0, 0, 0));  // 1 m off
  std::vector<ChainLink> chain;
  for (std::size_t k = 10; k < 15; ++k) chain.push_back({k, 1.0});  // odometry k -> k + 1 is constraint k
  chain.push_back({shortcut, 1.0});
  for (std::size_t k = 24; k < 30; ++k) chain.push_back({k, 1.0});
  const double through_loop_closure = loopClosureChainChi2(c.graph, claim, chain, false);
  std::vector<ChainLink> odometry;
  for (std::size_t k = 10; k < 30; ++k) odometry.push_back({k, 1.0});
  const double along_odometry = loopClosureChainChi2(c.graph, claim, odometry, false);
  // The odometry chain equals the odometry test; the shorter chain contradicts the claim more.
  EXPECT_NEAR(along_odometry, loopClosureOdometryChi2(c.graph, OdometryChain(c.graph, {}, false), claim),
              1e-9 * along_odometry);
  EXPECT_GT(through_loop_closure, 1.5 * along_odometry);
  // A right claim agrees with either chain; a weight below 1 widens a link (less contradiction).
  const std::size_t right = addLoopClosure(c, 10, 30);
  EXPECT_NEAR(loopClosureChainChi2(c.graph, right, chain, false), 0.0, 1e-9);
  std::vector<ChainLink> weak = chain;
  weak[5].weight = 0.01;
  EXPECT_LT(loopClosureChainChi2(c.graph, claim, weak, false), through_loop_closure);
  // Links that do not walk from 10 to 30, or a weight of 0: cannot tell.
  EXPECT_EQ(loopClosureChainChi2(c.graph, claim, std::vector<ChainLink>(chain.begin() + 1, chain.end()), false), -1.0);
  weak[5].weight = 0.0;
  EXPECT_EQ(loopClosureChainChi2(c.graph, claim, weak, false), -1.0);
}
