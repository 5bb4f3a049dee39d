// MapToOdomSchedule: when the node sends map->odom.  A correction goes out at once unless it
// comes within the spacing of the last one or at the stamp that went out last; then it is
// deferred to the retry, never dropped until the next tick (live_tuning.test once waited 10 s
// at tf_rate_hz 0.1 for a revisit's correction that had come 3 ms after a tick, at its stamp).
#include <gtest/gtest.h>

#include "toro_ros/node/map_to_odom_schedule.h"

using toro_ros::MapToOdomSchedule;
using Decision = MapToOdomSchedule::Decision;

namespace {
constexpr double kSpacing = MapToOdomSchedule::kCorrectionSpacingSec;
}

TEST(MapToOdomSchedule, ATickSendsUnlessItsStampWentOutAlready) {
  MapToOdomSchedule s;
  EXPECT_EQ(s.tick(ros::Time(10.0)), Decision::kSend);
  s.sent(ros::Time(10.0), 100.0, false);
  EXPECT_EQ(s.tick(ros::Time(10.0)), Decision::kSkip);  // the timer fired twice between /clock ticks
  EXPECT_EQ(s.tick(ros::Time(10.1)), Decision::kSend);
  EXPECT_EQ(s.tick(ros::Time(5.0)), Decision::kSend);  // a clock jump back goes out
}

TEST(MapToOdomSchedule, ACorrectionAtTheStampOfTheLastTickIsDeferredAndRetriedWhenTheClockMoves) {
  MapToOdomSchedule s;
  s.sent(ros::Time(152.905), 1000.0, false);  // a tick
  EXPECT_EQ(s.correction(ros::Time(152.905), 1000.003, true), Decision::kDefer);
  EXPECT_TRUE(s.deferred());
  EXPECT_TRUE(s.retryDue(1000.003));  // no spacing to wait for after a tick
  // The clock has not moved at the retry: deferred again, still due.
  EXPECT_EQ(s.correction(ros::Time(152.905), 1000.05, true), Decision::kDefer);
  EXPECT_TRUE(s.retryDue(1000.05));
  EXPECT_EQ(s.correction(ros::Time(152.91), 1000.10, true), Decision::kSend);
  s.sent(ros::Time(152.91), 1000.10, true);
  EXPECT_FALSE(s.deferred());
  EXPECT_FALSE(s.retryDue(1000.10 + 2 * kSpacing));
}

TEST(MapToOdomSchedule, CorrectionsBackToBackAreSpacedAndTheLastOneIsNotLost) {
  MapToOdomSchedule s;
  double wall = 50.0;
  ros::Time stamp(20.0);
  ASSERT_EQ(s.correction(stamp, wall, true), Decision::kSend);
  s.sent(stamp, wall, true);
  // A full round: a correction every millisecond, each at a new stamp.  Within the spacing none
  // goes out, each is deferred; the retry is due once the spacing has passed.
  int sent = 0;
  for (int k = 1; k <= 200; ++k) {
    wall += 0.001;
    stamp += ros::Duration(0.001);
    const Decision d = s.correction(stamp, wall, true);
    ASSERT_NE(d, Decision::kSkip);
    if (d == Decision::kSend) {
      s.sent(stamp, wall, true);
      ++sent;
    }
  }
  // 0.2 s of corrections: one per spacing (4), not 200.
  EXPECT_GE(sent, static_cast<int>(0.2 / kSpacing) - 1);
  EXPECT_LE(sent, static_cast<int>(0.2 / kSpacing) + 1);
  // The round's last correction came inside the spacing: it is deferred, and the retry is due
  // once the spacing has passed (not at the next tick).
  EXPECT_TRUE(s.deferred());
  EXPECT_FALSE(s.retryDue(wall));
  EXPECT_TRUE(s.retryDue(wall + kSpacing));
  EXPECT_EQ(s.correction(stamp + ros::Duration(kSpacing), wall + kSpacing, true), Decision::kSend);
}

TEST(MapToOdomSchedule, ASnapshotThatDidNotMoveTheMapSendsNothingAndATickClearsADeferral) {
  MapToOdomSchedule s;
  s.sent(ros::Time(1.0), 10.0, true);
  EXPECT_EQ(s.correction(ros::Time(2.0), 20.0, false), Decision::kSkip);  // a keyframe: rounding only
  EXPECT_FALSE(s.deferred());
  EXPECT_EQ(s.correction(ros::Time(2.0), 10.01, true), Decision::kDefer);
  // The tick sends the newest map: the deferred correction is in it.
  ASSERT_EQ(s.tick(ros::Time(2.01)), Decision::kSend);
  s.sent(ros::Time(2.01), 10.02, false);
  EXPECT_FALSE(s.deferred());
  EXPECT_FALSE(s.retryDue(100.0));
}
