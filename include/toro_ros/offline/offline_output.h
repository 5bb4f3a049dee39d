// What toro_offline writes into its output directory:
//   corrected.g2o (+ corrected.g2o.stamps)  the graph, as ~save_graph writes it
//   corrected_poses.bag  /corrected_pose (geometry_msgs/PoseStamped per keyframe, at its stamp),
//                        /corrected_path (one nav_msgs/Path at the end), /tf (map -> odom at each
//                        keyframe stamp from the final poses)
//   summary.json         counts, chi2 before/after, times, the error curve, per-keyframe poses
//                        ("trajectory": odometry, corrected, truth) and per-loop-closure chi2 (indices
//                        into "trajectory"), for scripts/plot_trajectory.py
#pragma once

#include <string>

#include "toro_ros/offline/offline_runner.h"
#include "toro_ros/offline/scoring.h"

namespace toro_ros {
namespace offline {

struct OfflineSummary {
  std::string bag;
  OfflineRun run;
  PipelineStatus status;
  double chi2_odometry = 0.0;   // g2o chi2 of the final graph at the keyframes' odometry poses
  double chi2_corrected = 0.0;  // ... at the corrected poses
  bool has_score = false;
  Score score;
};

// Chi2 before/after and, with a truth file, the score.
OfflineSummary summarize(OfflineRunner& runner, const OfflineRun& run, const OfflineOptions& options);

// Writes the three outputs; throws std::runtime_error naming the file that failed.
void writeOutputs(OfflineRunner& runner, const OfflineSummary& summary, const OfflineOptions& options);

// The human-readable lines printed at the end.
std::string describeSummary(const OfflineSummary& summary);

}  // namespace offline
}  // namespace toro_ros
