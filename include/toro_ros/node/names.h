// Topic and service names of the map corrector, in one place (relative names: remap as usual).
#pragma once

namespace toro_ros {
namespace names {

// Subscribed (resolved in the node's namespace).
constexpr const char* kOdometryTopic = "odom";
constexpr const char* kLoopClosureTopic = "loop_closure";

// Published in the private namespace.
constexpr const char* kPathTopic = "path";              // nav_msgs/Path, latched
constexpr const char* kMarkersTopic = "graph_markers";  // visualization_msgs/MarkerArray, latched
constexpr const char* kGraphTopic = "graph";            // toro_ros/PoseGraph, latched
constexpr const char* kPoseTopic = "pose";              // geometry_msgs/PoseWithCovarianceStamped

// Services in the private namespace.
constexpr const char* kOptimizeService = "optimize";
constexpr const char* kPauseService = "pause";
constexpr const char* kResumeService = "resume";
constexpr const char* kResetService = "reset";
constexpr const char* kSaveGraphService = "save_graph";
constexpr const char* kLoadGraphService = "load_graph";
constexpr const char* kGetStatusService = "get_status";
// dynamic_reconfigure adds set_parameters (service) and parameter_descriptions /
// parameter_updates (topics) in the private namespace.

}  // namespace names
}  // namespace toro_ros
