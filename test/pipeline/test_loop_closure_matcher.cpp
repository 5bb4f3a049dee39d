#include <gtest/gtest.h>

#include "toro_ros/pipeline/loop_closure_matcher.h"

using namespace toro_ros;

namespace {

KeyframeIndex index(std::initializer_list<double> stamps) {
  KeyframeIndex k;
  toro::NodeId id = 0;
  for (double s : stamps) k.append(KeyframeRecord{id++, ros::Time(s), toro::Pose3()});
  return k;
}

LoopClosure byStamp(double from, double to) {
  LoopClosure lc;
  lc.id_from = lc.id_to = -1;
  lc.stamp_from = ros::Time(from);
  lc.stamp_to = ros::Time(to);
  lc.from_T_to.orientation.w = 1;
  return lc;
}

LoopClosureMatchOptions options(double tolerance = 0.2, std::size_t max_pending = 3) {
  LoopClosureMatchOptions o;
  o.stamp_tolerance_sec = tolerance;
  o.max_pending = max_pending;
  return o;
}

}  // namespace

TEST(KeyframeIndex, NearestWithinTolerance) {
  const KeyframeIndex k = index({10, 11, 12});
  EXPECT_EQ(k.nearest(ros::Time(10.9), 0.2), 1);
  EXPECT_EQ(k.nearest(ros::Time(11.15), 0.2), 1);
  EXPECT_EQ(k.nearest(ros::Time(11.9), 0.2), 2);
  EXPECT_FALSE(k.nearest(ros::Time(11.5), 0.2).has_value());
  EXPECT_FALSE(k.nearest(ros::Time(9.0), 0.2).has_value());
  EXPECT_FALSE(k.nearest(ros::Time(12.5), 0.2).has_value());
  EXPECT_EQ(k.find(2)->stamp, ros::Time(12));
  EXPECT_EQ(k.find(7), nullptr);
}

TEST(LoopClosureMatcher, MatchesPastStampsAtOnce) {
  LoopClosureMatcher m(options());
  const KeyframeIndex k = index({10, 11, 12});
  const MatchResult r = m.submit(byStamp(10.1, 11.95), k, ros::Time(12.5));
  ASSERT_EQ(r.state, MatchResult::State::kMatched) << r.detail;
  EXPECT_EQ(r.from, 0);
  EXPECT_EQ(r.to, 2);
}

TEST(LoopClosureMatcher, UnknownStampIsRefusedWithReason) {
  LoopClosureMatcher m(options());
  const MatchResult r = m.submit(byStamp(5.0, 11.0), index({10, 11, 12}), ros::Time(12.5));
  EXPECT_EQ(r.state, MatchResult::State::kRefused);
  EXPECT_EQ(r.reason, refusal::kNoKeyframe);
  EXPECT_NE(r.detail.find("5.000000000"), std::string::npos) << r.detail;
}

TEST(LoopClosureMatcher, IdsAreCheckedAndPreferred) {
  LoopClosureMatcher m(options());
  const KeyframeIndex k = index({10, 11, 12});
  LoopClosure lc = byStamp(1, 2);  // stamps ignored when both ids are given
  lc.id_from = 2;
  lc.id_to = 0;
  const MatchResult ok = m.submit(lc, k, ros::Time(12));
  EXPECT_EQ(ok.state, MatchResult::State::kMatched);
  EXPECT_EQ(ok.from, 2);
  EXPECT_EQ(ok.to, 0);
  lc.id_to = 9;
  EXPECT_EQ(m.submit(lc, k, ros::Time(12)).reason, refusal::kUnknownId);
}

TEST(LoopClosureMatcher, BothEndsNearestToOneKeyframeSpanItAndTheNext) {
  LoopClosureMatcher m(options());
  // The later stamp moves on to the next keyframe; at the newest, the earlier one moves back.
  const MatchResult r = m.submit(byStamp(10.0, 10.1), index({10, 11}), ros::Time(11));
  EXPECT_EQ(r.state, MatchResult::State::kMatched);
  EXPECT_EQ(r.from, 0);
  EXPECT_EQ(r.to, 1);
  const MatchResult back = m.submit(byStamp(11.1, 11.0), index({10, 11}), ros::Time(12));
  EXPECT_EQ(back.from, 1);
  EXPECT_EQ(back.to, 0);
  // A single keyframe cannot hold both ends.
  EXPECT_EQ(m.submit(byStamp(10.0, 10.1), index({10}), ros::Time(11)).reason, refusal::kSameKeyframe);
}

TEST(LoopClosureMatcher, FutureStampWaitsUntilOdometryReachesIt) {
  LoopClosureMatcher m(options());
  KeyframeIndex k = index({10, 11});
  EXPECT_EQ(m.submit(byStamp(10, 13), k, ros::Time(11.5)).state, MatchResult::State::kPending);
  EXPECT_EQ(m.pending(), 1u);
  EXPECT_TRUE(m.release(k, ros::Time(12.0)).empty());
  // Odometry at 13.05 has no keyframe near 13 yet: the pipeline is asked to make one there.
  EXPECT_TRUE(m.wantsKeyframeAt(ros::Time(13.05), k));
  EXPECT_FALSE(m.wantsKeyframeAt(ros::Time(12.9), k));
  k.append(KeyframeRecord{2, ros::Time(13.05), toro::Pose3()});
  const auto released = m.release(k, ros::Time(13.05));
  ASSERT_EQ(released.size(), 1u);
  EXPECT_EQ(released[0].second.state, MatchResult::State::kMatched);
  EXPECT_EQ(released[0].second.from, 0);
  EXPECT_EQ(released[0].second.to, 2);
  EXPECT_EQ(m.pending(), 0u);
}

TEST(LoopClosureMatcher, FutureStampWithNoNearKeyframeAttachesToTheNewestOnceOdometryPassesIt) {
  LoopClosureMatcher m(options());
  const KeyframeIndex k = index({10, 11});
  m.submit(byStamp(10, 13), k, ros::Time(11.5));
  EXPECT_TRUE(m.release(k, ros::Time(13.1)).empty());  // a keyframe could still come within 0.2 s
  const auto released = m.release(k, ros::Time(13.3));
  ASSERT_EQ(released.size(), 1u);
  EXPECT_EQ(released[0].second.state, MatchResult::State::kMatched);
  EXPECT_EQ(released[0].second.to, 1);  // the odometry from 11 to 13 moves it there
}

TEST(LoopClosureMatcher, PendingListIsBounded) {
  LoopClosureMatcher m(options(0.2, 2));
  const KeyframeIndex k = index({10});
  EXPECT_EQ(m.submit(byStamp(10, 20), k, ros::Time(10)).state, MatchResult::State::kPending);
  EXPECT_EQ(m.submit(byStamp(10, 21), k, ros::Time(10)).state, MatchResult::State::kPending);
  EXPECT_EQ(m.submit(byStamp(10, 22), k, ros::Time(10)).reason, refusal::kPendingFull);
  EXPECT_EQ(m.clear().size(), 2u);
  EXPECT_EQ(m.pending(), 0u);
}
