#include "toro_ros/pipeline/odometry_history.h"

#include <algorithm>

namespace toro_ros {

void OdometryHistory::add(const ros::Time& stamp, const toro::Pose3& odom_T_base) {
  if (span_sec_ <= 0) return;
  samples_.emplace_back(stamp, odom_T_base);
  while (!samples_.empty() && (stamp - samples_.front().first).toSec() > span_sec_) samples_.pop_front();
}

std::optional<toro::Pose3> OdometryHistory::at(const ros::Time& stamp) const {
  if (samples_.empty() || stamp < samples_.front().first || stamp > samples_.back().first)
    return std::nullopt;
  const auto after = std::lower_bound(samples_.begin(), samples_.end(), stamp,
                                      [](const auto& s, const ros::Time& t) { return s.first < t; });
  if (after->first == stamp) return after->second;
  const auto before = after - 1;
  const double fraction = (stamp - before->first).toSec() / (after->first - before->first).toSec();
  return toro::slerp(before->second, after->second, fraction);
}

}  // namespace toro_ros
