// What to draw: nav_msgs/Path and rviz markers made from a Snapshot (no publishing here).
#pragma once

#include <cstddef>
#include <string>

#include <nav_msgs/Path.h>
#include <visualization_msgs/MarkerArray.h>

#include "toro_ros/pipeline/snapshot.h"

namespace toro_ros {

struct MarkerOptions {
  double node_scale_m = 0.1;   // sphere diameter of keyframes
  double edge_width_m = 0.02;  // line width of constraints
  // Loop closures are coloured from green (chi2 0) to red (chi2 >= this).
  double loop_closure_chi2_red = 10.0;
  bool draw_odometry_edges = true;
  std::string validate() const;
};

// Stable namespaces and ids: one marker per namespace, id 0, so each update replaces the last.
namespace marker_ns {
constexpr const char* kNodes = "keyframes";
constexpr const char* kOdometryEdges = "odometry_edges";
constexpr const char* kLoopClosures = "loop_closures";
constexpr const char* kRejectedLoopClosures = "rejected_loop_closures";  // magenta, by the gate
// Loop closures with a robust weight below toro::kRejectedWeight: orange, not in loop_closures.
constexpr const char* kDownWeightedLoopClosures = "down_weighted_loop_closures";
}  // namespace marker_ns

nav_msgs::Path pathFromSnapshot(const Snapshot& snapshot, const std::string& map_frame,
                                const ros::Time& stamp);

// Markers for the snapshot.  With `delete_all` the array starts with a DELETEALL marker (after a
// reset, so nothing of the old graph stays on screen).
visualization_msgs::MarkerArray markersFromSnapshot(const Snapshot& snapshot, const std::string& map_frame,
                                                    const ros::Time& stamp, const MarkerOptions& options,
                                                    bool delete_all);

// Seconds between two publications of the whole-graph topics (~path, ~graph_markers, ~graph):
// 1 / rate_hz, or period_per_keyframe_sec * keyframes when that is longer.  Building and
// serialising them is linear in the graph, so this bounds their share of the machine (about their
// cost per keyframe / period_per_keyframe_sec) however long the robot maps.
double visualizationPeriodSec(double rate_hz, double period_per_keyframe_sec, std::size_t keyframes);

// Colour of a loop closure with this chi2: green -> yellow -> red.
std_msgs::ColorRGBA residualColour(double chi2, double chi2_red);

}  // namespace toro_ros
