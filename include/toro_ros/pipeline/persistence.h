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

#include <iosfwd>
#include <string>
#include <vector>

#include "toro_ros/pipeline/graph_file.h"
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
void writeSidecar(std::ostream& out, const Sidecar& sidecar);
// Throws toro::ParseError "source:line: why" for a malformed line or an unreadable file (an
// unknown tag is quoted as toro::excerpt; ParseError::redactedWhat has it without).
Sidecar readSidecar(const std::string& path);
Sidecar readSidecar(std::istream& in, const std::string& source);
Sidecar readSidecarFile(const GraphFileRef& file);

// Empty when a save may replace what is at `graph` and its sidecar: for each, nothing, or a
// regular file that reads as a graph (the graph) or as a keyframe sidecar (the sidecar).  Else
// why not ("... is not a graph file: <line and problem>"), so that a save given the name of
// something else (a text file, a configuration, a link) refuses instead of destroying it.
std::string checkReplaceable(const GraphFileRef& graph);

// load_path on start (node and offline runner alike).  Returns a line for the log: "" for an empty
// path, "starting a new map" when the file does not exist yet (the first run of an autosave that
// is also the load_path), else what was resumed.  Throws std::runtime_error when the file exists
// but cannot be loaded: the owner must stop rather than start empty and autosave over it; and
// when the pipeline's autosave_path holds something checkReplaceable refuses (a typo in the path
// must not make the autosave destroy another file).  `quote_content` false: the messages quote
// neither file (see GraphFileRef).
std::string loadOnStart(Pipeline& pipeline, const std::string& path, bool quote_content = true);

}  // namespace toro_ros
