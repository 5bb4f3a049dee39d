// The odometry poses of the run, so that a loop closure naming a stamp between keyframes can be
// moved onto the keyframe it is attached to: keyframe_T_stamp = odom_T_keyframe^-1 * odom_T_stamp,
// with the pose at the stamp interpolated between the two kept messages around it.  The newest
// span_sec are kept at full rate; older messages are thinned to a trace that a linear (slerp)
// interpolation reproduces within kTraceTolerance (a few messages per metre or per second of
// turning, none while standing still), so stamps of any age are placed as well as recent ones.
// Stamps before the history (a loaded map) use the keyframes' odometry poses instead
// (KeyframeIndex::odometryAt, Pipeline::odometryPoseAt).
#pragma once

#include <deque>
#include <optional>
#include <vector>

#include <ros/time.h>

#include "toro_ros/core/pose3.h"

namespace toro_ros {

// How far OdometryHistory's thinned trace may be from the messages it drops.
struct TraceTolerance {
  double translation_m;
  double rotation_rad;
};

class OdometryHistory {
 public:
  static constexpr TraceTolerance kTraceTolerance{0.005, 0.002};

  // Keeps the messages of the newest `span_sec` at full rate and a trace of the older ones
  // (0: keeps nothing at all).
  explicit OdometryHistory(double span_sec) : span_sec_(span_sec) {}

  // Stamps must increase (the pipeline refuses out-of-order odometry before this).
  void add(const ros::Time& stamp, const toro::Pose3& odom_T_base);
  // odom_T_base at `stamp`, interpolated (slerp) between the kept messages around it; nullopt
  // before the first or after the newest message.
  std::optional<toro::Pose3> at(const ros::Time& stamp) const;
  void clear();
  std::size_t size() const { return recent_.size(); }                           // messages kept at full rate
  std::size_t traceSize() const { return trace_.size() + (pending_ ? 1 : 0); }  // thinned older ones

 private:
  struct Sample {
    ros::Time stamp;
    toro::Pose3 odom_T_base;
  };
  // A message leaving the full-rate span: kept in the trace unless interpolating around it is
  // as good.
  void retire(const Sample& sample);

  // Messages dropped in a row at most (each new one is checked against all of them): on a long
  // uniform straight line one message in this many is kept.
  static constexpr std::size_t kMaxDropped = 64;

  double span_sec_;
  std::vector<Sample> trace_;      // thinned, older than pending_
  std::vector<Sample> dropped_;    // dropped since trace_.back(), to check the next chord against
  std::optional<Sample> pending_;  // the last retired message, kept or dropped at the next one
  std::deque<Sample> recent_;      // full rate
};

}  // namespace toro_ros
