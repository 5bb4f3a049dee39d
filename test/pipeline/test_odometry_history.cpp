#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/odometry_history.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;

TEST(OdometryHistory, InterpolatesBetweenMessagesAndForgetsOldOnes) {
  OdometryHistory h(2.0);
  for (int i = 0; i <= 40; ++i)
    h.add(ros::Time(10 + 0.1 * i), toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0.05 * i));
  // 4.0 s of messages, 2.0 s kept: 12.0 .. 14.0.
  EXPECT_FALSE(h.at(ros::Time(11.9)).has_value());
  EXPECT_FALSE(h.at(ros::Time(14.01)).has_value());
  const auto exact = h.at(ros::Time(13.0));
  ASSERT_TRUE(exact.has_value());
  EXPECT_NEAR(exact->translation().x(), 3.0, 1e-9);
  const auto mid = h.at(ros::Time(13.05));
  ASSERT_TRUE(mid.has_value());
  EXPECT_NEAR(mid->translation().x(), 3.05, 1e-9);
  EXPECT_NEAR(mid->rollPitchYaw().z(), 1.525, 1e-9);
  OdometryHistory none(0.0);
  none.add(ros::Time(1), toro::Pose3());
  EXPECT_EQ(none.size(), 0u);
}

namespace {

// Straight line at 1 m/s, exact odometry, messages every 0.1 s, keyframes every 0.5 m; a loop
// closure between stamps that are not keyframes, with the true relative pose.
double loopClosureChi2(double history_sec) {
  PipelineOptions o;
  o.keyframer.distance_m = 0.45;
  o.keyframer.interval_sec = 0;
  o.matcher.stamp_tolerance_sec = 0.3;
  o.matcher.create_keyframes = false;
  o.odometry_history_sec = history_sec;
  Pipeline p(o);
  std::vector<toro::Pose3> truth;
  for (int i = 0; i <= 40; ++i) {
    truth.push_back(toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0.02 * i));
    p.handleOdometry(toro_ros::testing::odometryMsg(ros::Time(100 + 0.1 * i), truth.back()));
  }
  // Keyframes at samples 0, 5, 10, ...; samples 7 and 32 are between keyframes.
  EXPECT_FALSE(p.keyframes().nearest(ros::Time(100.7), 0.0).has_value());
  LoopClosure lc;
  lc.id_from = lc.id_to = -1;
  lc.stamp_from = ros::Time(100.7);
  lc.stamp_to = ros::Time(103.2);
  lc.from_T_to = poseToMsg(toro::relativePose(truth[7], truth[32]));
  for (int k = 0; k < 6; ++k) lc.covariance[7 * k] = 1e-4;  // 1 cm, 0.01 rad
  p.handleLoopClosure(lc);
  EXPECT_EQ(p.status().counters.loop_closures_applied, 1u);
  return toro::constraintChi2(p.graph(), p.graph().numConstraints() - 1);
}

}  // namespace

TEST(Pipeline, LoopClosureIsMovedFromItsStampsOntoItsKeyframes) {
  // The constraint agrees exactly with the (exact) odometry, from the full-rate history or, without
  // it, from the keyframes' odometry poses (this odometry is linear in time between keyframes, so
  // their interpolation is exact too).  Uncorrected it would be off by the 0.2 m / 0.04 rad between
  // the stamps and their keyframes (chi2 ~ 400 at 1 cm / 0.01 rad).
  EXPECT_LT(loopClosureChi2(60.0), 1e-12);
  EXPECT_LT(loopClosureChi2(0.0), 1e-12);
}
