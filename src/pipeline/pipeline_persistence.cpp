// Pipeline::saveGraph / loadGraph: the graph file through the core's graph_io, the keyframe stamps
// and loop-closure flags through the sidecar (persistence.h); autosave and the resume of a loaded
// map by new odometry.
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/planar.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/persistence.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

namespace {

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

std::optional<ResumeLink> resumeLinkFromString(const std::string& s) {
  if (s == "continue") return ResumeLink::kContinue;
  if (s == "last_pose") return ResumeLink::kLastPose;
  return std::nullopt;
}

std::string toString(ResumeLink link) { return link == ResumeLink::kContinue ? "continue" : "last_pose"; }

std::string PersistenceOptions::validate() const {
  if (!(std::isfinite(autosave_period_sec) && autosave_period_sec > 0))
    return "autosave_period_sec must be > 0";
  const std::string e = resume_link_stddev.validate();
  return e.empty() ? "" : "resume_link_stddev: " + e;
}

std::string Pipeline::saveGraph(const std::string& path) const { return saveGraph(GraphFileRef(path)); }

std::string Pipeline::saveGraph(const GraphFileRef& file) const {
  if (map_.graph().empty()) return "nothing to save: the graph is empty";
  Sidecar s;
  s.keyframes = keyframes_.records();
  const std::vector<bool>& is_loop_closure = map_.loopClosureFlags();
  for (std::size_t c = 0; c < is_loop_closure.size(); ++c)
    if (is_loop_closure[c]) s.loop_closures.push_back(c);
  s.rejected = map_.rejected();
  toro::WriteOptions format;
  format.format = toro::formatFromExtension(file.name());
  try {
    // Both written to temporary files first and renamed in place (sidecar first, graph last), so
    // a crash or kill while saving (autosave) leaves the previous pair intact.
    PendingFile sidecar(file.sidecar(), [&](std::ostream& out) { writeSidecar(out, s); });
    PendingFile graph(file, [&](std::ostream& out) { toro::writeGraph(map_.graph(), out, format); });
    sidecar.commit();
    graph.commit();
  } catch (const std::exception& e) {
    return "cannot save " + file.displayPath() + ": " + e.what();
  }
  return "";
}

std::string Pipeline::loadGraph(const std::string& path) { return loadGraph(GraphFileRef(path)); }

std::string Pipeline::loadGraph(const GraphFileRef& file) {
  const std::string& path = file.displayPath();
  toro::PoseGraph graph;
  Sidecar sidecar;
  try {
    graph = readGraphFile(file);
    if (graph.empty()) return path + ": the graph is empty";
    for (std::size_t i = 1; i < graph.numNodes(); ++i)
      if (graph.node(i).id <= graph.node(i - 1).id)
        return path + ": node ids must increase in file order (they are keyframes in stamp order)";
    const GraphFileRef side = file.sidecar();
    sidecar = fileExists(side) ? readSidecarFile(side) : sidecarFromGraph(graph);
  } catch (const toro::ParseError& e) {
    return file.describe(e);
  } catch (const std::exception& e) {
    return e.what();
  }
  const std::string mismatch = checkSidecar(sidecar, graph);
  if (!mismatch.empty()) return sidecarPath(path) + ": " + mismatch;

  clearGraph();
  std::vector<bool> is_loop_closure(graph.numConstraints(), false);
  for (std::size_t c : sidecar.loop_closures) is_loop_closure[c] = true;
  for (KeyframeRecord k : sidecar.keyframes) {
    if (options_.planar) k.odom_T_base = toro::projectToPlane(k.odom_T_base);  // as at input
    keyframes_.append(k);
  }
  const KeyframeRecord& newest = keyframes_.newest();
  map_.load(graph, is_loop_closure, sidecar.rejected, newest.stamp);
  // The sidecar does not keep odometry covariances: NaN marks the reference's as unknown, so the
  // first step after the load takes the default information (kDifference would otherwise use the
  // whole covariance accumulated since the odometry started).
  keyframer_.setLast(OdometrySample{newest.stamp, newest.odom_T_base,
                                    toro::Matrix6::Constant(std::numeric_limits<double>::quiet_NaN())});
  newest_odometry_ = newest.stamp;
  next_id_ = newest.id + 1;
  resume_after_ = loaded_until_ = newest.stamp;
  // Whatever the resume link, the odometry between the saved newest keyframe and the first new one
  // was not seen (the node was down; with last_pose it is even in another frame): no stamp in
  // that gap is interpolated.
  next_keyframe_after_gap_ = true;
  // What was just loaded is on disk already; the next autosave waits for a change.
  autosaved_revision_ = revision_;
  last_autosave_stamp_ = newest.stamp;
  return "";
}

bool Pipeline::resumeWith(const OdometrySample& sample) {
  if (sample.stamp <= *resume_after_) {
    ++counters_.odometry_refused;
    refuse(std::string("odometry: ") + refusal::kBeforeResume,
           "odometry at " + stampString(sample.stamp) + " is not after the newest loaded keyframe " +
               stampString(*resume_after_) + " (it is in the map already)");
    return false;
  }
  resume_after_.reset();
  if (options_.persistence.resume_link == ResumeLink::kContinue) return true;  // keyframer goes on
  // kLastPose: the new odometry frame starts where the saved run ended.  The sample becomes a
  // keyframe at the newest saved pose (an identity step), and later keyframes step from it in the
  // new frame.
  InformationResult link;
  link.information = defaultInformation(options_.persistence.resume_link_stddev);
  keyframer_.setLast(sample);
  appendKeyframe(sample, OdometryStep{toro::Pose3(), link});
  return true;
}

void Pipeline::autosaveIfDue(const ros::Time& stamp) {
  if (options_.persistence.autosave_path.empty()) return;
  if (last_autosave_stamp_.isZero() || stamp < last_autosave_stamp_) last_autosave_stamp_ = stamp;
  if ((stamp - last_autosave_stamp_).toSec() < options_.persistence.autosave_period_sec) return;
  last_autosave_stamp_ = stamp;
  autosave();
}

namespace {

std::string resume(Pipeline& pipeline, const std::string& path, bool quote_content) {
  if (path.empty()) return "";
  const GraphFileRef file(path, quote_content);
  if (!fileExists(file)) return "load_path " + path + " does not exist yet: starting a new map";
  const std::string error = pipeline.loadGraph(file);
  if (!error.empty()) throw std::runtime_error("load_path: " + error);
  const KeyframeIndex& k = pipeline.keyframes();
  return "resumed " + path + ": " + std::to_string(k.size()) + " keyframes, " +
         std::to_string(pipeline.graph().numConstraints()) + " constraints, newest keyframe at " +
         stampString(k.newest().stamp) + "; odometry joins it by resume_link " +
         toString(pipeline.options().persistence.resume_link);
}

}  // namespace

std::string loadOnStart(Pipeline& pipeline, const std::string& path, bool quote_content) {
  const std::string resumed = resume(pipeline, path, quote_content);
  const std::string& autosave = pipeline.options().persistence.autosave_path;
  // Unless it is the file just loaded (a graph, then).
  if (!autosave.empty() && !(autosave == path && !pipeline.graph().empty())) {
    const std::string why = checkReplaceable(GraphFileRef(autosave, quote_content));
    if (!why.empty()) throw std::runtime_error("autosave_path: refusing to replace it: " + why);
  }
  return resumed;
}

std::string Pipeline::autosave() {
  const std::string& path = options_.persistence.autosave_path;
  if (path.empty() || revision_ == autosaved_revision_ || map_.graph().empty()) return "";
  const std::string error = saveGraph(path);
  if (!error.empty()) {
    ++counters_.autosave_failures;
    if (warn_) warn_("autosave failed (will retry after the next period): " + error);
    return error;
  }
  ++counters_.autosaves;
  autosaved_revision_ = revision_;
  return "";
}

}  // namespace toro_ros
