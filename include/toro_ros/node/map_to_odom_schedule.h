// When map->odom goes out: every tf tick, and at once after a correction (no ROS transport:
// test/node/test_map_to_odom_schedule.cpp).  The node asks, under its tf lock, before each send
// and reports each send; stamps are the tf stamps (ros::Time, simulated or not), spacing is in
// wall seconds (it bounds traffic, which is a wall-time fact).
#pragma once

#include <ros/time.h>

namespace toro_ros {

class MapToOdomSchedule {
 public:
  // Corrections come back to back in full rounds; spaced this far apart, they add at most
  // 1 / kCorrectionSpacingSec transforms a second to the tick's rate.
  static constexpr double kCorrectionSpacingSec = 0.05;

  enum class Decision {
    kSend,   // send it now
    kDefer,  // a correction that cannot go out yet: retry (retryDue) with the newest map
    kSkip,   // nothing to send
  };

  // The tf tick: sends unless that stamp went out already (under simulated time a timer can fire
  // twice between /clock ticks, and the same stamp again would only make tf warn
  // TF_REPEATED_DATA).  A stamp behind the last one is a clock jump: it goes out.
  Decision tick(const ros::Time& stamp) const {
    return stamp == last_stamp_ ? Decision::kSkip : Decision::kSend;
  }
  // A snapshot the worker made: `moved` says whether map->odom moved since the last one sent.
  // Deferred, not dropped, when it comes within the spacing or at the stamp that went out last
  // (the clock had not moved since a tick): the correction must not wait for the next tick,
  // which may be seconds away (tf_rate_hz 0.1), nor for a later correction that may never come.
  Decision correction(const ros::Time& stamp, double wall_sec, bool moved);
  // Whether the retry timer should send the newest snapshot as a correction now.
  bool retryDue(double wall_sec) const { return deferred_ && wall_sec >= next_correction_wall_sec_; }
  // A transform went out (a tick's or a correction's).  A tick's sends the newest map, so a
  // deferred correction is moot.
  void sent(const ros::Time& stamp, double wall_sec, bool correction);

  bool deferred() const { return deferred_; }

 private:
  ros::Time last_stamp_;
  double next_correction_wall_sec_ = 0.0;
  bool deferred_ = false;
};

}  // namespace toro_ros
