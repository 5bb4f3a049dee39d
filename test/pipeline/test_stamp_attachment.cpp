// Loop closures named by stamps anywhere on the trajectory (issue 11, item 4): a front end names the
// stamps of its own scans, not our keyframes.  Each stamp attaches to the nearest keyframe and the
// measurement is moved onto it with the odometry between; only stamps before the first keyframe or
// in the gap before a resumed map's new odometry are refused.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {
namespace {

using testing::odometryMsg;

// A slow robot (0.3 m/s) on a circle of radius 5 m, exact odometry at 20 Hz: keyframes every
// 0.5 m are 1.7 s apart, nearly 7 times the 0.25 s tolerance, and scans come every 0.1 s.
constexpr double kSpeed = 0.3, kRadius = 5.0, kRate = 20.0, kStart = 100.0;
toro::Pose3 circleAt(double t) {
  const double a = kSpeed * t / kRadius;
  return toro::Pose3::fromRollPitchYaw(kRadius * std::sin(a), kRadius - kRadius * std::cos(a), 0, 0, 0, a);
}

PipelineOptions defaultsWithHistory(double history_sec) {
  PipelineOptions o;  // the shipped defaults (tolerance 0.25 s, keyframes every 0.5 m)
  o.odometry_history_sec = history_sec;
  return o;
}

LoopClosure trueLoopClosure(double from_sec, double to_sec) {
  LoopClosure lc;
  lc.header.stamp = ros::Time(kStart + to_sec + 0.05);
  lc.stamp_from = ros::Time(kStart + from_sec);
  lc.stamp_to = ros::Time(kStart + to_sec);
  lc.id_from = lc.id_to = -1;
  lc.from_T_to = poseToMsg(toro::relativePose(circleAt(from_sec), circleAt(to_sec)));
  for (int k = 0; k < 6; ++k) lc.covariance[7 * k] = k < 3 ? 1e-4 : 1e-5;
  return lc;
}

struct SlowRobotRun {
  std::size_t sent = 0, applied = 0, refused = 0;
  double worst_translation_m = 0.0, worst_rotation_rad = 0.0;  // constraint vs the keyframes' truth
};

// Drives one lap and a half; every 2 s a loop closure from a scan one lap back to the scan "now".
SlowRobotRun driveSlowRobot(double history_sec) {
  Pipeline p(defaultsWithHistory(history_sec));
  const double lap = 2 * M_PI * kRadius / kSpeed;
  SlowRobotRun r;
  std::vector<LoopClosure> sent;
  for (long i = 0; i <= std::lround(1.5 * lap * kRate); ++i) {
    const double t = i / kRate;
    p.handleOdometry(odometryMsg(ros::Time(kStart + t), circleAt(t)));
    // Scans at 10 Hz, offset from the odometry by 0.03 s; one loop closure every 2 s after a lap.
    if (t > lap && i % static_cast<long>(2 * kRate) == 0) {
      const double to = t - 0.07, from = to - lap + 0.43;
      sent.push_back(trueLoopClosure(from, to));
      p.handleLoopClosure(sent.back());
    }
  }
  const PipelineCounters& c = p.status().counters;
  r.sent = sent.size();
  r.applied = c.loop_closures_applied;
  r.refused = c.loop_closures_refused;
  // Every loop-closure constraint must agree with the true relative pose of its two keyframes.
  const toro::PoseGraph& g = p.graph();
  const auto& records = p.keyframes().records();
  for (const toro::Constraint& c : g.constraints()) {
    if (c.to == c.from + 1) continue;  // odometry
    const KeyframeRecord* a = p.keyframes().find(c.from);
    const KeyframeRecord* b = p.keyframes().find(c.to);
    const toro::Pose3 truth = toro::relativePose(circleAt((a->stamp - ros::Time(kStart)).toSec()),
                                                 circleAt((b->stamp - ros::Time(kStart)).toSec()));
    const toro::Pose3 error = toro::relativePose(truth, c.measurement);
    r.worst_translation_m = std::max(r.worst_translation_m, error.translation().norm());
    r.worst_rotation_rad = std::max(r.worst_rotation_rad, error.angle());
  }
  EXPECT_GT(records.size(), 100u);
  return r;
}

TEST(StampAttachment, KeyframesFarApartRefuseNoStampBetweenThem) {
  // The full-rate history covers the newer stamps; the older ones (a lap back, 105 s) lie beyond
  // the 60 s default history and are moved with the keyframes' odometry poses.
  const SlowRobotRun r = driveSlowRobot(60.0);
  ASSERT_GT(r.sent, 20u);
  EXPECT_EQ(r.refused, 0u);
  EXPECT_EQ(r.applied, r.sent);
  // Interpolating between keyframes 0.5 m apart on a 5 m circle: a chord, 6 mm from the arc at most.
  EXPECT_LT(r.worst_translation_m, 0.01);
  EXPECT_LT(r.worst_rotation_rad, 1e-6);
}

TEST(StampAttachment, WithoutAnyHistoryTheKeyframesOdometryPosesCarryEveryStamp) {
  const SlowRobotRun r = driveSlowRobot(0.0);
  EXPECT_EQ(r.refused, 0u);
  EXPECT_EQ(r.applied, r.sent);
  EXPECT_LT(r.worst_translation_m, 0.01);
}

TEST(StampAttachment, AStampAfterTheNewestKeyframeUsesTheNewestOdometry) {
  // No history (and no keyframe made for the stamp): between the newest keyframe and the newest
  // odometry message, the motion comes from the two of them.
  PipelineOptions o = defaultsWithHistory(0.0);
  o.matcher.create_keyframes = false;
  Pipeline p(o);
  for (int i = 0; i <= 40; ++i)
    p.handleOdometry(odometryMsg(ros::Time(kStart + i / kRate), circleAt(i / kRate)));
  const ros::Time newest = p.keyframes().newest().stamp;
  ASSERT_LT(newest, ros::Time(kStart + 2.0));
  const double to = 2.0 - 0.5 * (2.0 - (newest - ros::Time(kStart)).toSec());  // halfway to "now"
  p.handleLoopClosure(trueLoopClosure(0.0, to));
  ASSERT_EQ(p.status().counters.loop_closures_applied, 1u);
  const toro::Constraint& c = p.graph().constraints().back();
  const toro::Pose3 truth = toro::relativePose(circleAt(0.0), circleAt((newest - ros::Time(kStart)).toSec()));
  // The chord between the keyframe and "now" is 6 mm from the arc at most.
  EXPECT_LT(toro::relativePose(truth, c.measurement).translation().norm(), 0.01);
  EXPECT_GT(toro::relativePose(circleAt(0.0), circleAt(to)).translation().norm() - truth.translation().norm(),
            0.03);  // the stamp is well past the keyframe
}

TEST(StampAttachment, AStampBetweenKeyframesAddsTheOdometrysUncertaintyThereNoMore) {
  // diff_drive_controller's odometry: x, y, yaw at 1e-3 per metre-and-radian moved, z, roll and pitch
  // flagged unmeasured (1e6).  A loop closure declared to 1 cm, from a keyframe's stamp to a stamp
  // halfway between two keyframes, carries half a step of that odometry: x and y lose most of
  // their information; the flagged axes add nothing (z keeps its declared 1 cm).
  Pipeline p(defaultsWithHistory(60.0));
  for (int i = 0; i <= 200; ++i) {
    nav_msgs::Odometry m = odometryMsg(ros::Time(kStart + i / kRate), circleAt(i / kRate));
    for (int k = 0; k < 6; ++k) m.pose.covariance[7 * k] = k == 0 || k == 1 || k == 5 ? 1e-3 : 1e6;
    p.handleOdometry(m);
  }
  const auto& records = p.keyframes().records();
  ASSERT_GE(records.size(), 5u);
  const KeyframeRecord &first = records.front(), &k = records.at(3), &next = records.at(4);
  const double from = (first.stamp - ros::Time(kStart)).toSec();
  const double between =
      0.5 * ((k.stamp - ros::Time(kStart)).toSec() + (next.stamp - ros::Time(kStart)).toSec());
  const double on_keyframe = (k.stamp - ros::Time(kStart)).toSec();
  p.handleLoopClosure(trueLoopClosure(from, on_keyframe));
  p.handleLoopClosure(trueLoopClosure(from, between + 0.01));  // nearer to `next`, before it
  ASSERT_EQ(p.status().counters.loop_closures_applied, 2u);
  const auto& constraints = p.graph().constraints();
  const toro::Matrix6 exact =
      toro::quaternionToAngleUnits(constraints.at(constraints.size() - 2).information);
  const toro::Matrix6 carried = toro::quaternionToAngleUnits(constraints.back().information);
  ASSERT_EQ(constraints.back().to, next.id);
  // On the keyframe: the declared information (1e4 on x, y, z; 1e5 on the angles).
  EXPECT_NEAR(exact(0, 0), 1e4, 1e-6);
  EXPECT_NEAR(exact(2, 2), 1e4, 1e-6);
  EXPECT_NEAR(exact(5, 5), 1e5, 1e-4);
  // Between: x and y variance 1e-4 + (the offset's share of the step) x 1e-3 x (metres + radians
  // of the step), within the few per cent that yaw's lever arm adds.
  const toro::Pose3 k_T_next = toro::relativePose(k.odom_T_base, next.odom_T_base);
  const double step = k_T_next.translation().norm() + k_T_next.angle();
  const double share = (next.stamp.toSec() - (kStart + between + 0.01)) / (next.stamp - k.stamp).toSec();
  const double expected = 1.0 / (1e-4 + share * 1e-3 * step);
  for (int axis : {0, 1}) {
    EXPECT_LT(carried(axis, axis), 1.0 * expected) << axis;
    EXPECT_GT(carried(axis, axis), 0.9 * expected) << axis;
  }
  EXPECT_LT(expected, 0.5e4);        // most of it lost
  EXPECT_GT(carried(2, 2), 0.99e4);  // z: the odometry's flag adds nothing
}

TEST(StampAttachment, TheToleranceGuardsStampsBeforeTheFirstKeyframe) {
  Pipeline p(defaultsWithHistory(60.0));
  for (int i = 0; i <= 100; ++i)
    p.handleOdometry(odometryMsg(ros::Time(kStart + i / kRate), circleAt(i / kRate)));
  p.handleLoopClosure(trueLoopClosure(-0.2, 4.0));  // 0.2 s before the first odometry: attached
  p.handleLoopClosure(trueLoopClosure(-0.3, 4.5));  // 0.3 s before: refused
  const PipelineCounters c = p.status().counters;
  EXPECT_EQ(c.loop_closures_applied, 1u);
  EXPECT_EQ(c.refused_by_reason.at("loop closure: no keyframe within tolerance"), 1u);
}

// A map saved at 10 s and resumed at 40 s: the odometry between was never seen (the node was down;
// with last_pose the new odometry even starts again at its own origin).  A stamp in the gap matches
// neither run; one in the new run is attached.
void checkGapBeforeAResumedMap(ResumeLink link) {
  char dir_template[] = "/tmp/toro_stamps_XXXXXX";
  const std::string dir = mkdtemp(dir_template);
  const std::string path = dir + "/map.g2o";
  PipelineOptions o = defaultsWithHistory(60.0);
  o.persistence.resume_link = link;
  {
    Pipeline first(o);
    for (int i = 0; i <= 200; ++i)
      first.handleOdometry(odometryMsg(ros::Time(kStart + i / kRate), circleAt(i / kRate)));
    ASSERT_EQ(first.saveGraph(path), "");
  }
  Pipeline p(o);
  ASSERT_EQ(p.loadGraph(path), "");
  const double restart = 40.0;
  for (int i = 0; i <= 200; ++i) {
    const double t = restart + i / kRate;
    p.handleOdometry(
        odometryMsg(ros::Time(kStart + t), circleAt(link == ResumeLink::kContinue ? t : t - restart)));
  }
  LoopClosure in_gap = trueLoopClosure(5.0, 25.0);  // 25 s: between the runs
  in_gap.header.stamp = ros::Time(kStart + restart + 10.05);
  LoopClosure in_new = trueLoopClosure(5.0, restart + 5.03);  // a scan of the new run
  in_new.header.stamp = in_gap.header.stamp;
  p.handleLoopClosure(in_gap);
  p.handleLoopClosure(in_new);
  const PipelineCounters c = p.status().counters;
  EXPECT_EQ(c.loop_closures_applied, 1u) << toString(link);
  EXPECT_EQ(c.refused_by_reason.at("loop closure: no keyframe within tolerance"), 1u);
  // The first new keyframe is marked: nothing is interpolated between it and the saved newest.
  std::size_t gaps = 0;
  for (const KeyframeRecord& k : p.keyframes().records()) gaps += k.after_gap;
  EXPECT_EQ(gaps, 1u);
  std::filesystem::remove_all(dir);
}

TEST(StampAttachment, NothingIsInterpolatedAcrossTheGapBeforeAResumedMap) {
  checkGapBeforeAResumedMap(ResumeLink::kLastPose);
  checkGapBeforeAResumedMap(ResumeLink::kContinue);
}

}  // namespace
}  // namespace toro_ros
