// The recent full-rate odometry, so that a loop closure naming a stamp between keyframes can be moved
// onto the keyframe it is attached to: keyframe_T_stamp = odom_T_keyframe^-1 * odom_T_stamp, with the
// pose at the stamp interpolated between the two odometry messages around it.  Older stamps use the
// keyframes' odometry poses instead (KeyframeIndex::odometryAt, Pipeline::odometryPoseAt).
#pragma once

#include <deque>
#include <optional>

#include <ros/time.h>

#include "toro_ros/core/pose3.h"

namespace toro_ros {

class OdometryHistory {
 public:
  // Keeps messages no older than `span_sec` before the newest (0: keep none).
  explicit OdometryHistory(double span_sec) : span_sec_(span_sec) {}

  // Stamps must increase (the pipeline refuses out-of-order odometry before this).
  void add(const ros::Time& stamp, const toro::Pose3& odom_T_base);
  // odom_T_base at `stamp`, interpolated (slerp) between the messages around it; nullopt if the
  // stamp is outside the kept span.
  std::optional<toro::Pose3> at(const ros::Time& stamp) const;
  void clear() { samples_.clear(); }
  std::size_t size() const { return samples_.size(); }

 private:
  double span_sec_;
  std::deque<std::pair<ros::Time, toro::Pose3>> samples_;
};

}  // namespace toro_ros
