// Save/load of what a graph file cannot hold: keyframe stamps, the odometry poses they were made
// from, and which constraints are loop closures.  They go to a sidecar "<graph path>.stamps" so the
// graph file itself stays a plain g2o/TORO file any tool reads.  Format (text, one record a line,
// '#' comments):
//   KEYFRAME id sec nsec x y z qx qy qz qw     (odom_T_base of the keyframe)
//   LOOP_CLOSURE constraint_index
//   REJECTED from to sec nsec chi2 x y z qx qy qz qw i11 i12 .. i16 i22 .. i66
//     (a loop closure the chi-square gate refused: keyframe ids, message stamp, its chi2 when
//     refused, the measurement from_T_to and the upper triangle of its g2o-ordered information)
#pragma once

#include <string>
#include <vector>

#include "toro_ros/pipeline/loop_closure_matcher.h"
#include "toro_ros/pipeline/snapshot.h"

namespace toro_ros {

class Pipeline;

struct Sidecar {
  std::vector<KeyframeRecord> keyframes;
  std::vector<std::size_t> loop_closures;  // constraint indices
  std::vector<RejectedLoopClosure> rejected;
};

std::string sidecarPath(const std::string& graph_path);
// Throws std::runtime_error naming the path if it cannot be written.
void writeSidecar(const std::string& path, const Sidecar& sidecar);
// Throws std::runtime_error "path:line: why" for a malformed line or an unreadable file.
Sidecar readSidecar(const std::string& path);

// A temporary name in the same directory with the same extension (the graph format goes by it):
// "dir/name.g2o" -> "dir/.name.tmp<pid>.g2o".
std::string temporaryPath(const std::string& path);
// Flushes the file's data to the disk (fsync) and renames it over `path`, then syncs the
// directory, so that a crash leaves either the old or the new file, never a partial one.
// Throws std::runtime_error naming the path.
void commitFile(const std::string& temporary, const std::string& path);

// load_path on start (node and offline runner alike).  Returns a line for the log: "" for an empty
// path, "starting a new map" when the file does not exist yet (the first run of an autosave that
// is also the load_path), else what was resumed.  Throws std::runtime_error when the file exists
// but cannot be loaded: the owner must stop rather than start empty and autosave over it.
std::string loadOnStart(Pipeline& pipeline, const std::string& path);

}  // namespace toro_ros
