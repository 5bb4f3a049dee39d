// What the pipeline hands to publishers: an immutable copy of the corrected map and counters,
// shared as std::shared_ptr<const Snapshot> so readers never touch the live graph.  Keyframes and
// edges are chunked vectors (chunked_vector.h): consecutive snapshots share the chunks in which
// nothing changed, so making one costs what changed, not the size of the map.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ros/time.h>

#include "toro_ros/core/pose3.h"
#include "toro_ros/core/pose_graph.h"
#include "toro_ros/pipeline/chunked_vector.h"

namespace toro_ros {

struct PipelineCounters {
  std::uint64_t odometry_messages = 0;  // received (valid or not)
  std::uint64_t odometry_refused = 0;
  std::uint64_t loop_closures_received = 0;
  std::uint64_t loop_closures_applied = 0;
  std::uint64_t loop_closures_refused = 0;   // includes the rejected ones
  std::uint64_t loop_closures_rejected = 0;  // applied, then refused by the chi-square gate (now)
  std::uint64_t loop_closures_readmitted = 0;  // rejected ones applied again when the map agreed
  // Support (OptimizationOptions::hold_until_supported): loop closures held at weight 0 when they
  // arrived, and those of them released since (a neighbour or the map agreed).
  std::uint64_t loop_closures_held = 0;
  std::uint64_t loop_closures_released = 0;
  std::uint64_t loop_closures_released_predicted = 0;  // of those, by a finish (their innovation)
  std::uint64_t time_jump_resets = 0;
  std::uint64_t resets = 0;               // all resets (time jumps, service, load)
  std::uint64_t optimization_passes = 0;  // full and affected passes run
  // Background finishes (MapOptimizer): taken, merged into the map, dropped (the graph was reset,
  // loaded or lost a constraint while one ran, or it failed: the log says why).
  std::uint64_t finishes_started = 0;
  std::uint64_t finishes_merged = 0;
  std::uint64_t finishes_dropped = 0;
  // Finishes that also solved from scratch (FinishJob::from_scratch), and those whose solution
  // from scratch ended lower and was merged.
  std::uint64_t finishes_from_scratch = 0;
  std::uint64_t finishes_from_scratch_kept = 0;
  std::uint64_t autosaves = 0;            // successful autosaves
  std::uint64_t autosave_failures = 0;    // failed ones (each also logged with the reason)
  // Covariances read axis by axis (covariance_rules.h); none of these is a refusal.  Odometry steps
  // between keyframes, loop closures as applied:
  std::uint64_t odometry_steps_default = 0;         // every axis took the defaults
  std::uint64_t odometry_steps_partly_default = 0;  // some axes (unknown ones) took the defaults
  std::uint64_t odometry_steps_repaired = 0;        // correlations shrunk to be positive definite
  std::uint64_t loop_closures_default = 0;
  std::uint64_t loop_closures_partly_default = 0;
  std::uint64_t loop_closures_repaired = 0;
  // Refusals by category, "odometry: ..." and "loop closure: ..." (see loop_closure_matcher.h).
  std::map<std::string, std::uint64_t> refused_by_reason;
};

struct SnapshotKeyframe {
  toro::NodeId id = 0;
  ros::Time stamp;
  toro::Pose3 map_T_base;  // corrected pose
};

struct SnapshotEdge {
  std::size_t from_index = 0;  // into Snapshot::keyframes
  std::size_t to_index = 0;
  bool loop_closure = false;
  double chi2 = 0.0;  // g2o chi2 of this constraint at the corrected poses (loop closures only)
  double weight = 1.0;  // robust weight (toro::TreeOptimizer::weights); 1 for odometry
};

// A loop closure the chi-square gate refused (kept for the graph file, the markers and ~get_status).
struct RejectedLoopClosure {
  toro::Constraint constraint;  // as it was applied: keyframe ids, measurement, information
  ros::Time stamp;              // header stamp of its message
  double chi2 = 0.0;            // its g2o chi2 after its affected pass
};

// A loop closure the robust estimator weights below toro::kRejectedWeight now.
struct DownWeightedLoopClosure {
  toro::NodeId from = 0;
  toro::NodeId to = 0;
  double weight = 0.0;  // its robust weight
  double chi2 = 0.0;    // its g2o chi2 at the corrected poses
};

// What the last finish did, for ~get_status and diagnostics.
struct FinishRecord {
  bool merged = false;      // its result was taken into the map (else dropped, or failed: error)
  std::string error;        // why it was dropped or failed ("" when merged)
  ros::Time stamp;          // message time when it was taken
  double seconds = 0.0;     // its wall time
  double chi2_before = 0.0;  // g2o chi2 of its graph before and after
  double chi2_after = 0.0;
  std::size_t iterations = 0;
  std::size_t nodes_added_since = 0;  // keyframes that arrived while it ran (moved with their parents)
};

struct Snapshot {
  std::uint64_t generation = 0;  // increases with every snapshot the pipeline makes
  std::uint64_t epoch = 0;       // increases with every reset/load: publishers clear old markers
  ChunkedVector<SnapshotKeyframe> keyframes;  // in graph order (node index)
  ChunkedVector<SnapshotEdge> edges;          // by constraint index
  std::vector<SnapshotEdge> rejected_edges;  // loop closures the gate refused (chi2 when refused)
  std::size_t down_weighted_loop_closures = 0;  // edges with loop_closure and weight < kRejectedWeight
  double robust_width = 0.0;                    // the robust kernel's width (0: robust off)
  // map_T_odom = (corrected pose of the newest keyframe) * (its odometry pose)^-1; identity and
  // has_map_T_odom = false before the first keyframe.
  bool has_map_T_odom = false;
  toro::Pose3 map_T_odom;
  ros::Time newest_stamp;  // stamp of the newest keyframe
  double chi2 = 0.0;       // g2o chi2 after the last optimisation (NaN before any)
  double last_optimization_sec = 0.0;
  std::size_t pending_loop_closures = 0;
  PipelineCounters counters;
  std::optional<FinishRecord> last_finish;  // the newest background finish (nullopt before any)
  bool finish_running = false;
  std::string finish_off_reason;  // why the background finish is off for this map ("" if it is not)
};

}  // namespace toro_ros
