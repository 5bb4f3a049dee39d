// Services of MapCorrectorNode: each becomes a command the worker runs between passes, answered
// through a future with a timeout (PipelineWorker::call), so no service touches the pipeline from
// another thread.  Commands capture by value: after a timeout they still run, later.
#include <chrono>
#include <cmath>
#include <sstream>

#include "toro_ros/node/map_corrector_node.h"

namespace toro_ros {

namespace {
constexpr const char* kTimedOut = "no answer from the worker (service_timeout_sec passed, or an internal error: see the log)";
}  // namespace

bool MapCorrectorNode::optimizeService(Optimize::Request& req, Optimize::Response& res) {
  const unsigned iterations = req.iterations;
  const std::string mode = req.mode;
  const auto r = runOnWorker<OptimizeResult>([iterations, mode](Pipeline& p) { return p.optimize(iterations, mode); });
  if (!r) {
    res.success = false;
    res.message = kTimedOut;
    return true;
  }
  res.success = r->success;
  res.message = r->message;
  res.chi2_before = r->chi2_before;
  res.chi2_after = r->chi2_after;
  res.time_sec = r->time_sec;
  return true;
}

bool MapCorrectorNode::pauseService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const auto r = runOnWorker<bool>([](Pipeline& p) { return p.setPaused(true), true; });
  res.success = r.has_value();
  res.message = r ? "optimisation paused (the graph keeps growing)" : kTimedOut;
  return true;
}

bool MapCorrectorNode::resumeService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const auto r = runOnWorker<bool>([](Pipeline& p) { return p.setPaused(false), true; });
  res.success = r.has_value();
  res.message = r ? "optimisation resumed" : kTimedOut;
  return true;
}

bool MapCorrectorNode::resetService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const auto r = runOnWorker<bool>([](Pipeline& p) { return p.reset("~reset service called"), true; });
  res.success = r.has_value();
  res.message = r ? "graph reset" : kTimedOut;
  return true;
}

// The caller's name is confined to graph_directory (checked here, in the service thread, so a
// large existing file is parsed outside the worker); the worker then writes or reads exactly the
// file checked (GraphFileRef keeps its directory open).
bool MapCorrectorNode::saveGraphService(GraphFile::Request& req, GraphFile::Response& res) {
  const ConfinedFile target = graph_directory_.forSave(req.path);
  if (!target.file) {
    res.success = false;
    res.message = target.error;
    return true;
  }
  const GraphFileRef file = *target.file;
  const auto r = runOnWorker<std::string>([file](Pipeline& p) { return p.saveGraph(file); });
  res.success = r && r->empty();
  res.message = !r ? kTimedOut : (r->empty() ? "saved " + file.displayPath() + " and its .stamps" : *r);
  return true;
}

bool MapCorrectorNode::loadGraphService(GraphFile::Request& req, GraphFile::Response& res) {
  const ConfinedFile source = graph_directory_.forLoad(req.path);
  if (!source.file) {
    res.success = false;
    res.message = source.error;
    return true;
  }
  const GraphFileRef file = *source.file;
  const auto r = runOnWorker<std::string>([file](Pipeline& p) { return p.loadGraph(file); });
  res.success = r && r->empty();
  res.message = !r ? kTimedOut : (r->empty() ? "loaded " + file.displayPath() : *r);
  return true;
}

bool MapCorrectorNode::getStatusService(GetStatus::Request&, GetStatus::Response& res) {
  const auto r = runOnWorker<PipelineStatus>([](Pipeline& p) { return p.status(); });
  if (!r) return false;
  res.keyframes = r->keyframes;
  res.constraints = r->constraints;
  res.loop_closures_applied = r->counters.loop_closures_applied;
  res.loop_closures_pending = r->pending_loop_closures;
  res.loop_closures_refused = r->counters.loop_closures_refused;
  for (const auto& [reason, count] : r->counters.refused_by_reason) {
    res.refused_reasons.push_back(reason);
    res.refused_counts.push_back(count);
  }
  res.odometry_messages = r->counters.odometry_messages;
  res.time_jump_resets = r->counters.time_jump_resets;
  res.queue_length = worker_->queueLength();
  res.loop_closures_down_weighted = r->down_weighted.size();
  for (const DownWeightedLoopClosure& d : r->down_weighted) {
    std::ostringstream line;
    line << d.from << " -> " << d.to << " weight " << d.weight << " chi2 " << d.chi2;
    res.down_weighted_loop_closures.push_back(line.str());
  }
  res.robust_width = r->robust_width;
  res.finishes_started = r->counters.finishes_started;
  res.finishes_merged = r->counters.finishes_merged;
  res.finishes_dropped = r->counters.finishes_dropped;
  res.finishes_from_scratch = r->counters.finishes_from_scratch;
  res.finishes_from_scratch_kept = r->counters.finishes_from_scratch_kept;
  res.finish_running = r->finish_running;
  res.finish_off_reason = r->finish_off_reason;
  if (r->last_finish) {
    const FinishRecord& f = *r->last_finish;
    res.last_finish_merged = f.merged;
    res.last_finish_error = f.error;
    res.last_finish_stamp = f.stamp.toSec();
    res.last_finish_sec = f.seconds;
    res.last_finish_chi2_before = f.chi2_before;
    res.last_finish_chi2_after = f.chi2_after;
    res.last_finish_iterations = f.iterations;
    res.last_finish_keyframes_added_since = f.nodes_added_since;
  }
  res.queue_dropped = worker_->dropped();
  res.last_chi2 = r->last_chi2;
  res.last_optimization_sec = r->last_optimization_sec;
  res.paused = r->paused;
  res.loop_closures_rejected = r->counters.loop_closures_rejected;
  res.loop_closures_readmitted = r->counters.loop_closures_readmitted;
  res.loop_closures_held = r->counters.loop_closures_held;
  res.loop_closures_released = r->counters.loop_closures_released;
  res.loop_closures_released_predicted = r->counters.loop_closures_released_predicted;
  res.autosaves = r->counters.autosaves;
  res.autosave_failures = r->counters.autosave_failures;
  res.odometry_covariance_rule = r->odometry_covariance_rule;
  res.odometry_steps_default = r->counters.odometry_steps_default;
  res.odometry_steps_partly_default = r->counters.odometry_steps_partly_default;
  res.odometry_steps_repaired = r->counters.odometry_steps_repaired;
  res.loop_closure_covariance_rule = r->loop_closure_covariance_rule;
  res.loop_closures_default_covariance = r->counters.loop_closures_default;
  res.loop_closures_partly_default_covariance = r->counters.loop_closures_partly_default;
  res.loop_closures_repaired_covariance = r->counters.loop_closures_repaired;
  for (const RejectedLoopClosure& x : r->rejected)
    res.rejected_loop_closures.push_back(std::to_string(x.constraint.from) + " -> " +
                                         std::to_string(x.constraint.to) + " chi2 " + std::to_string(x.chi2));
  return true;
}

}  // namespace toro_ros
