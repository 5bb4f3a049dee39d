// Save/load of what a graph file cannot hold: keyframe stamps, the odometry poses they were made
// from, and which constraints are loop closures.  They go to a sidecar "<graph path>.stamps" so the
// graph file itself stays a plain g2o/TORO file any tool reads.  Format (text, one record a line,
// '#' comments):
//   KEYFRAME id sec nsec x y z qx qy qz qw     (odom_T_base of the keyframe)
//   LOOP_CLOSURE constraint_index
#pragma once

#include <string>
#include <vector>

#include "toro_ros/pipeline/loop_closure_matcher.h"

namespace toro_ros {

struct Sidecar {
  std::vector<KeyframeRecord> keyframes;
  std::vector<std::size_t> loop_closures;  // constraint indices
};

std::string sidecarPath(const std::string& graph_path);
// Throws std::runtime_error naming the path if it cannot be written.
void writeSidecar(const std::string& path, const Sidecar& sidecar);
// Throws std::runtime_error "path:line: why" for a malformed line or an unreadable file.
Sidecar readSidecar(const std::string& path);

}  // namespace toro_ros
