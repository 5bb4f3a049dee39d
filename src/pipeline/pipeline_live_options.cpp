// Run-time tuning of a running pipeline (the node's dynamic_reconfigure server sends it as a
// command to the worker, so it never races a pass).  Only options whose new value takes effect
// cleanly from the next message or pass are taken; the rest (frames, covariance handling, the
// matcher, persistence, the learning rate and robust kernel of the optimiser that already holds
// the graph) keep the values the pipeline was built with.
#include <algorithm>

#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

std::string Pipeline::applyLiveOptions(const PipelineOptions& requested) {
  PipelineOptions next = options_;
  // Keyframe thresholds: the next odometry message is measured against them.
  next.keyframer.distance_m = requested.keyframer.distance_m;
  next.keyframer.angle_rad = requested.keyframer.angle_rad;
  next.keyframer.interval_sec = requested.keyframer.interval_sec;
  // The schedule: read at every call of runScheduledOptimization / optimize.
  next.optimization.full_iterations = requested.optimization.full_iterations;
  next.optimization.full_every_keyframes = requested.optimization.full_every_keyframes;
  next.optimization.full_every_sec = requested.optimization.full_every_sec;
  next.optimization.service_default_iterations = requested.optimization.service_default_iterations;
  // The background finish: read when the next job is due.
  next.optimization.background_finish = requested.optimization.background_finish;
  next.optimization.finish_min_interval_sec = requested.optimization.finish_min_interval_sec;
  next.optimization.finish_max_iterations = requested.optimization.finish_max_iterations;
  next.optimization.finish_chi2_tolerance = requested.optimization.finish_chi2_tolerance;
  // The gate: the threshold applies to the next test (a loop closure on trial included).
  next.loop_closure_gate_confidence = requested.loop_closure_gate_confidence;
  next.loop_closure_gate_variance_factor = requested.loop_closure_gate_variance_factor;
  // Robust loop closures: the kernel's width (the adaptation starts again from it) and the
  // adaptation factor.  Not the kernel itself nor on/off: the optimiser's weights and
  // preconditioner were built with them.
  next.robust.width = requested.robust.width;
  next.robust.adaptive_width_factor = requested.robust.adaptive_width_factor;
  const std::string error = next.validate();
  if (!error.empty()) return "invalid options: " + error;

  // The keyframer keeps its reference keyframe and what it learnt of the covariance convention;
  // only its thresholds change.
  keyframer_.setThresholds(next.keyframer.distance_m, next.keyframer.angle_rad, next.keyframer.interval_sec);
  map_.applyLiveOptions(next.optimization, next.robust, gateOptionsOf(next));
  options_ = next;
  return "";
}

}  // namespace toro_ros
