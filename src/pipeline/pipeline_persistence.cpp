// Pipeline::saveGraph / loadGraph: the graph file through the core's graph_io, the keyframe stamps
// and loop-closure flags through the sidecar (persistence.h).
#include <cstdio>
#include <fstream>
#include <stdexcept>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/pipeline/persistence.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

namespace {

bool fileExists(const std::string& path) { return static_cast<bool>(std::ifstream(path)); }

// Without a sidecar: no stamps, odometry poses taken as the graph poses, and every constraint
// that does not join consecutive ids counted as a loop closure.
Sidecar sidecarFromGraph(const toro::PoseGraph& graph) {
  Sidecar s;
  for (const toro::Node& n : graph.nodes()) s.keyframes.push_back(KeyframeRecord{n.id, ros::Time(), n.pose});
  for (std::size_t c = 0; c < graph.numConstraints(); ++c)
    if (graph.constraints()[c].to != graph.constraints()[c].from + 1) s.loop_closures.push_back(c);
  return s;
}

// Empty if the sidecar describes this graph, else why not.
std::string checkSidecar(const Sidecar& s, const toro::PoseGraph& graph) {
  if (s.keyframes.size() != graph.numNodes())
    return "sidecar has " + std::to_string(s.keyframes.size()) + " keyframes, the graph " +
           std::to_string(graph.numNodes()) + " nodes";
  for (std::size_t i = 0; i < s.keyframes.size(); ++i)
    if (s.keyframes[i].id != graph.node(i).id)
      return "sidecar keyframe " + std::to_string(i) + " has id " + std::to_string(s.keyframes[i].id) +
             ", the graph node " + std::to_string(graph.node(i).id);
  for (std::size_t c : s.loop_closures)
    if (c >= graph.numConstraints())
      return "sidecar names loop closure " + std::to_string(c) + " beyond the graph";
  for (const RejectedLoopClosure& r : s.rejected)
    if (!graph.hasNode(r.constraint.from) || !graph.hasNode(r.constraint.to))
      return "sidecar names a rejected loop closure " + std::to_string(r.constraint.from) + " -> " +
             std::to_string(r.constraint.to) + " between unknown keyframes";
  return "";
}

}  // namespace

std::string Pipeline::saveGraph(const std::string& path) const {
  if (optimizer_.graph().empty()) return "nothing to save: the graph is empty";
  // Both written to temporary files first and renamed in place (sidecar first, graph last), so a
  // crash or kill while saving (autosave) leaves the previous pair intact.
  const std::string graph_tmp = temporaryPath(path), sidecar_tmp = temporaryPath(sidecarPath(path));
  try {
    toro::writeGraph(optimizer_.graph(), graph_tmp);
    Sidecar s;
    s.keyframes = keyframes_.records();
    for (std::size_t c = 0; c < is_loop_closure_.size(); ++c)
      if (is_loop_closure_[c]) s.loop_closures.push_back(c);
    s.rejected = rejected_;
    writeSidecar(sidecar_tmp, s);
    commitFile(sidecar_tmp, sidecarPath(path));
    commitFile(graph_tmp, path);
  } catch (const std::exception& e) {
    std::remove(graph_tmp.c_str());
    std::remove(sidecar_tmp.c_str());
    return "cannot save " + path + ": " + e.what();
  }
  return "";
}

std::string Pipeline::loadGraph(const std::string& path) {
  toro::PoseGraph graph;
  Sidecar sidecar;
  try {
    graph = toro::readGraph(path);
    if (graph.empty()) return path + ": the graph is empty";
    for (std::size_t i = 1; i < graph.numNodes(); ++i)
      if (graph.node(i).id <= graph.node(i - 1).id)
        return path + ": node ids must increase in file order (they are keyframes in stamp order)";
    sidecar = fileExists(sidecarPath(path)) ? readSidecar(sidecarPath(path)) : sidecarFromGraph(graph);
  } catch (const std::exception& e) {
    return e.what();
  }
  const std::string mismatch = checkSidecar(sidecar, graph);
  if (!mismatch.empty()) return sidecarPath(path) + ": " + mismatch;

  clearGraph();
  replaceGraph(graph);
  for (const KeyframeRecord& k : sidecar.keyframes) keyframes_.append(k);
  is_loop_closure_.assign(graph.numConstraints(), false);
  for (std::size_t c : sidecar.loop_closures) is_loop_closure_[c] = true;
  rejected_ = sidecar.rejected;
  const KeyframeRecord& newest = keyframes_.newest();
  keyframer_.setLast(OdometrySample{newest.stamp, newest.odom_T_base, toro::Matrix6::Zero()});
  newest_odometry_ = newest.stamp;
  last_full_stamp_ = newest.stamp;
  next_id_ = newest.id + 1;
  return "";
}

}  // namespace toro_ros
