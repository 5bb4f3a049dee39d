// A deterministic drifting-odometry scenario shared by the pipeline tests and the node's rostest:
// a square driven twice, odometry over-reading distance by 3 % and drifting 0.02 rad in yaw per
// metre, and the loop closure that ties the end of the second lap to the start.
#pragma once

#include <cmath>
#include <vector>

#include <nav_msgs/Odometry.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/core/pose3.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {
namespace testing {

struct DriftScenario {
  std::vector<nav_msgs::Odometry> odometry;  // odom_T_base as the drifting odometry reports it
  std::vector<toro::Pose3> truth;            // world_T_base, world = odom at the start
};

// The options the pipeline tests start from: keyframes every 0.5 m or 0.5 rad (no time trigger),
// loop-closure stamps matched within 0.15 s, full rounds by keyframe count only.  Each test adds
// what it is about.
inline PipelineOptions baseTestOptions() {
  PipelineOptions o;
  o.keyframer.distance_m = 0.5;
  o.keyframer.angle_rad = 0.5;
  o.keyframer.interval_sec = 0;
  o.matcher.stamp_tolerance_sec = 0.15;
  o.optimization.full_every_sec = 0;
  // The scenarios below close their loops with one loop closure; holding loop closures until a
  // second one agrees (the default) is tested on its own (test_pipeline_support.cpp).
  o.optimization.hold_until_supported = false;
  return o;
}

// baseTestOptions with a full round of 10 passes every 10 keyframes.
inline PipelineOptions roundsEvery10Keyframes() {
  PipelineOptions o = baseTestOptions();
  o.optimization.full_every_keyframes = 10;
  o.optimization.full_iterations = 10;
  return o;
}

// Runs the pipeline's scheduled optimisation until nothing is left (bounded).
inline void drain(Pipeline& p) {
  for (int i = 0; i < 1000 && (p.runScheduledOptimization() || p.hasScheduledWork()); ++i) {
  }
}

inline nav_msgs::Odometry odometryMsg(const ros::Time& stamp, const toro::Pose3& odom_T_base) {
  nav_msgs::Odometry m;
  m.header.stamp = stamp;
  m.header.frame_id = "odom";
  m.child_frame_id = "base_link";
  m.pose.pose = poseToMsg(odom_T_base);
  return m;
}

// Side `side_m`, 1 m/s along the sides, 90 deg turns in place over 1 s, samples every `dt_sec`.
inline DriftScenario makeDriftingSquare(int laps = 2, double side_m = 4.0, double dt_sec = 0.1,
                                        double start_sec = 100.0) {
  DriftScenario s;
  toro::Pose3 truth, odom;
  double t = start_sec;
  auto emit = [&] {
    s.truth.push_back(truth);
    s.odometry.push_back(odometryMsg(ros::Time(t), odom));
  };
  emit();
  const int straight_steps = static_cast<int>(std::lround(side_m / dt_sec));
  const int turn_steps = static_cast<int>(std::lround(1.0 / dt_sec));
  for (int side = 0; side < 4 * laps; ++side) {
    for (int i = 0; i < straight_steps; ++i) {
      const double d = dt_sec;  // 1 m/s
      truth = truth * toro::Pose3::fromRollPitchYaw(d, 0, 0, 0, 0, 0);
      odom = odom * toro::Pose3::fromRollPitchYaw(1.03 * d, 0, 0, 0, 0, 0.02 * d);
      t += dt_sec;
      emit();
    }
    for (int i = 0; i < turn_steps; ++i) {
      const double a = (M_PI / 2) / turn_steps;
      truth = truth * toro::Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, a);
      odom = odom * toro::Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, a);
      t += dt_sec;
      emit();
    }
  }
  return s;
}

// Loop closure between samples i and j (by stamp) with the true relative pose.
inline LoopClosure trueLoopClosure(const DriftScenario& s, std::size_t i, std::size_t j,
                                   double stddev_m = 0.02, double stddev_rad = 0.01) {
  LoopClosure lc;
  lc.header.stamp = s.odometry[j].header.stamp;
  lc.stamp_from = s.odometry[i].header.stamp;
  lc.stamp_to = s.odometry[j].header.stamp;
  lc.id_from = lc.id_to = -1;
  lc.from_T_to = poseToMsg(toro::relativePose(s.truth[i], s.truth[j]));
  for (int k = 0; k < 3; ++k) {
    lc.covariance[7 * k] = stddev_m * stddev_m;
    lc.covariance[7 * (k + 3)] = stddev_rad * stddev_rad;
  }
  return lc;
}

// A revisit as a place recogniser reports it: the loop closures (i + k step, j - k step), k = 0 ..
// count - 1, samples half a metre apart at 1 m/s and 0.1 s.  The default options hold loop closures
// that would bend the map until others agree, and count agreement only once 10 pairs were tested
// (the sender's covariance scale): five loop closures of a first revisit make 10 pairs.
inline std::vector<LoopClosure> revisitLoopClosures(const DriftScenario& s, std::size_t i, std::size_t j,
                                                    std::size_t count = 5, std::size_t step = 5) {
  std::vector<LoopClosure> out;
  for (std::size_t k = 0; k < count; ++k) out.push_back(trueLoopClosure(s, i + k * step, j - k * step));
  return out;
}

}  // namespace testing
}  // namespace toro_ros
