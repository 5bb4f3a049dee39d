#include "toro_ros/node/map_to_odom_schedule.h"

namespace toro_ros {

MapToOdomSchedule::Decision MapToOdomSchedule::correction(const ros::Time& stamp, double wall_sec,
                                                          bool moved) {
  if (!moved) return Decision::kSkip;
  if (wall_sec < next_correction_wall_sec_ || stamp == last_stamp_) {
    deferred_ = true;
    return Decision::kDefer;
  }
  return Decision::kSend;
}

void MapToOdomSchedule::sent(const ros::Time& stamp, double wall_sec, bool correction) {
  last_stamp_ = stamp;
  deferred_ = false;
  if (correction) next_correction_wall_sec_ = wall_sec + kCorrectionSpacingSec;
}

}  // namespace toro_ros
