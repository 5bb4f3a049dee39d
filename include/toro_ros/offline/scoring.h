// Scoring a corrected trajectory against the truth graph_to_bag wrote beside its bag: the truth
// is known per graph node with a stamp, so any keyframe (whichever stamps the node chose) is
// compared with the truth interpolated at its stamp (slerp between the two nearest truth poses).
// All poses are in the odom frame's origin (the first pose is the identity in truth, odometry and
// the corrected map alike), so the main figures apply no alignment: a gauge drift counts as error.
// rmse_aligned_m is the same after the best rigid alignment.
#pragma once

#include <string>
#include <vector>

#include "toro_ros/core/pose3.h"
#include "toro_ros/pipeline/loop_closure_matcher.h"

namespace toro_ros {
namespace offline {

struct TrajectoryError {
  std::size_t poses = 0;  // keyframes scored (stamps inside the truth's time span)
  double rmse_m = 0.0;    // position
  double mean_m = 0.0;
  double max_m = 0.0;
  double mean_rotation_rad = 0.0;
  double final_m = 0.0;  // position error of the newest scored keyframe
  // Position RMSE after the rigid motion that best aligns the poses with the truth (Kabsch, no
  // scale; the "absolute trajectory error" of SLAM benchmarks): the shape of the map without the
  // rotation about the first pose that no loop closure can observe.
  double rmse_aligned_m = 0.0;
};

struct Score {
  TrajectoryError odometry;   // the keyframes' odometry poses (what the robot reported)
  TrajectoryError corrected;  // the corrected map
};

// A time series of true poses.
class TruthTrajectory {
 public:
  // From "<stem>.truth.g2o" and the sidecar "<stem>.odometry.g2o.stamps" graph_to_bag wrote.
  // Throws std::runtime_error / toro::ParseError naming the file.
  static TruthTrajectory load(const std::string& truth_path);
  // The pose at `stamp`, interpolated; false outside the span.
  bool at(const ros::Time& stamp, toro::Pose3* pose) const;
  const std::vector<ros::Time>& stamps() const { return stamps_; }

 private:
  std::vector<ros::Time> stamps_;
  std::vector<toro::Pose3> poses_;
};

TrajectoryError trajectoryError(const std::vector<ros::Time>& stamps, const std::vector<toro::Pose3>& poses,
                                const TruthTrajectory& truth);
Score scoreKeyframes(const std::vector<KeyframeRecord>& keyframes, const std::vector<toro::Pose3>& corrected,
                     const TruthTrajectory& truth);
std::string describeScore(const Score& score);

}  // namespace offline
}  // namespace toro_ros
