// Topic and service names of the map corrector, in one place (relative names: remap as usual).
#pragma once

namespace toro_ros {
namespace names {

// Subscribed (resolved in the node's namespace).
constexpr const char* kOdometryTopic = "odom";
constexpr const char* kLoopClosureTopic = "loop_closure";

// Published in the private namespace (latched).
constexpr const char* kPathTopic = "path";
constexpr const char* kMarkersTopic = "graph_markers";

// Services in the private namespace.
constexpr const char* kOptimizeService = "optimize";
constexpr const char* kPauseService = "pause";
constexpr const char* kResumeService = "resume";
constexpr const char* kResetService = "reset";
constexpr const char* kSaveGraphService = "save_graph";
constexpr const char* kLoadGraphService = "load_graph";
constexpr const char* kGetStatusService = "get_status";

}  // namespace names
}  // namespace toro_ros
