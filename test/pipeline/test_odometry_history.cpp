#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/odometry_history.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;

TEST(OdometryHistory, InterpolatesBetweenMessagesAndThinsOldOnes) {
  OdometryHistory h(2.0);
  for (int i = 0; i <= 40; ++i)
    h.add(ros::Time(10 + 0.1 * i), toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0.05 * i));
  // 4.0 s of messages, 2.0 s at full rate (12.0 .. 14.0); the older ones move uniformly, so the
  // trace keeps only the first and the last one it has seen.
  EXPECT_EQ(h.size(), 21u);
  EXPECT_EQ(h.traceSize(), 2u);
  EXPECT_FALSE(h.at(ros::Time(9.9)).has_value());
  EXPECT_FALSE(h.at(ros::Time(14.01)).has_value());
  for (double t : {10.0, 10.55, 11.9, 13.0, 13.05}) {
    const auto p = h.at(ros::Time(t));
    ASSERT_TRUE(p.has_value()) << t;
    EXPECT_NEAR(p->translation().x(), t - 10, 1e-9) << t;
    EXPECT_NEAR(p->rollPitchYaw().z(), 0.5 * (t - 10), 1e-9) << t;
  }
  OdometryHistory none(0.0);
  none.add(ros::Time(1), toro::Pose3());
  EXPECT_EQ(none.size(), 0u);
  EXPECT_FALSE(none.at(ros::Time(1)).has_value());
}

TEST(OdometryHistory, TheThinnedTraceStaysWithinItsToleranceOnCurvesAndStops) {
  // 1 m/s around a 3 m circle for 30 s, a 20 s stop, then on: 50 Hz, 10 s at full rate.
  auto pose = [](double t) {
    const double s = t < 30 ? t : t < 50 ? 30 : t - 20;
    return toro::Pose3::fromRollPitchYaw(3 * std::sin(s / 3), 3 - 3 * std::cos(s / 3), 0, 0, 0, s / 3);
  };
  OdometryHistory h(10.0);
  for (int i = 0; i <= 70 * 50; ++i) h.add(ros::Time(100 + i / 50.0), pose(i / 50.0));
  EXPECT_EQ(h.size(), 501u);
  EXPECT_LT(h.traceSize(), 300u) << "of 3000 older messages";
  RecordProperty("trace_size", std::to_string(h.traceSize()));
  std::printf("trace: %zu of 3000 older messages kept\n", h.traceSize());
  double worst_m = 0, worst_rad = 0;
  for (int i = 0; i <= 70 * 50; ++i) {
    const double t = i / 50.0 + 0.01;  // between messages too
    const auto p = h.at(ros::Time(100 + t));
    ASSERT_TRUE(p.has_value() || t > 70) << t;
    if (!p) continue;
    const toro::Pose3 error = toro::relativePose(pose(t), *p);
    worst_m = std::max(worst_m, error.translation().norm());
    worst_rad = std::max(worst_rad, error.angle());
  }
  // The tolerance, plus the chord of one message period (1/50 s on a 3 m circle: 17 um).
  EXPECT_LT(worst_m, OdometryHistory::kTraceTolerance.translation_m + 1e-4);
  EXPECT_LT(worst_rad, OdometryHistory::kTraceTolerance.rotation_rad + 1e-4);
  // During the stop the pose is the stop's, not a blend with the motion around it.
  EXPECT_LT((h.at(ros::Time(140))->translation() - pose(35).translation()).norm(), 1e-9);
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
