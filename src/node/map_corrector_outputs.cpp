// Outputs of MapCorrectorNode: map->odom on tf, the corrected pose at the odometry rate, the
// whole graph (~graph), path and markers, diagnostics.
#include <cmath>
#include <sstream>

#include <geometry_msgs/TransformStamped.h>

#include "toro_ros/node/graph_message.h"
#include "toro_ros/node/map_corrector_node.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/visualization.h"

namespace toro_ros {

namespace {

// tf2 ignores a leading slash ("/odom" is "odom").
std::string withoutLeadingSlash(const std::string& frame) {
  return !frame.empty() && frame[0] == '/' ? frame.substr(1) : frame;
}

// map->odom moved by more than this is a correction (see sendMapToOdom).
constexpr double kCorrectionMetres = 1e-9;
constexpr double kCorrectionRadians = 1e-9;

bool samePose(const toro::Pose3& a, const toro::Pose3& b) {
  return a.translation() == b.translation() && a.rotation().coeffs() == b.rotation().coeffs();
}

}  // namespace

void MapCorrectorNode::tfTimerCallback(const ros::TimerEvent&) { sendMapToOdom(nullptr); }

void MapCorrectorNode::correctionTimerCallback(const ros::WallTimerEvent&) {
  {
    std::lock_guard<std::mutex> lock(tf_mutex_);
    if (!tf_schedule_.retryDue(ros::WallTime::now().toSec())) return;
  }
  const std::shared_ptr<const Snapshot> newest = worker_->snapshot();
  sendMapToOdom(newest.get());
}

void MapCorrectorNode::sendMapToOdom(const Snapshot* correction) {
  // The tick reads the worker's snapshot under the lock: a correction sent meanwhile from a newer
  // snapshot (published before its observer runs) is then never followed by an older map->odom.
  std::lock_guard<std::mutex> lock(tf_mutex_);
  std::shared_ptr<const Snapshot> newest;
  if (!correction) newest = worker_->snapshot();
  const Snapshot& snapshot = correction ? *correction : *newest;
  const ros::Time now = ros::Time::now();
  if (!snapshot.has_map_T_odom || now.isZero()) return;  // nothing yet, or sim time before the first /clock
  const std::shared_ptr<const NodeOptions> o = options();
  // Stamped ahead so that tf lookups at "now" made by other nodes find it before the next tick.
  const ros::Time stamp = now + ros::Duration(o->transform_tolerance_sec);
  const double wall = ros::WallTime::now().toSec();
  // A new keyframe moves map->odom by rounding only (~1e-15); a loop closure's pass, a merged
  // finish or a full round by far more.
  const toro::Pose3 moved = last_tf_map_T_odom_.inverse() * snapshot.map_T_odom;
  const bool has_moved = moved.translation().norm() > kCorrectionMetres || moved.angle() > kCorrectionRadians;
  const MapToOdomSchedule::Decision decision =
      correction ? tf_schedule_.correction(stamp, wall, has_moved) : tf_schedule_.tick(stamp);
  if (decision != MapToOdomSchedule::Decision::kSend) return;
  tf_schedule_.sent(stamp, wall, correction != nullptr);
  last_tf_map_T_odom_ = snapshot.map_T_odom;
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = o->map_frame;
  t.child_frame_id = o->odom_frame;
  t.transform = transformToMsg(snapshot.map_T_odom);
  tf_broadcaster_.sendTransform(t);
}

void MapCorrectorNode::onOdometryArrived(const nav_msgs::Odometry::ConstPtr& msg) {
  last_odometry_wall_sec_ = ros::WallTime::now().toSec();
  const std::shared_ptr<const Snapshot> s = worker_->snapshot();
  const std::shared_ptr<const NodeOptions> o = options();
  // Only what the pipeline would take (it refuses the rest, counted): a valid pose in odom_frame.
  if (!s->has_map_T_odom || !validateOdometry(*msg).empty()) return;
  if (!msg->header.frame_id.empty() &&
      withoutLeadingSlash(msg->header.frame_id) != withoutLeadingSlash(o->odom_frame))
    return;
  pose_pub_.publish(correctedPose(s->map_T_odom, *msg, o->map_frame, o->pipeline.planar));
  std::lock_guard<std::mutex> lock(pose_mutex_);
  pose_odometry_ = msg;
  pose_map_T_odom_ = s->map_T_odom;
}

void MapCorrectorNode::onSnapshot(const Pipeline& pipeline, const Snapshot& snapshot) {
  sendMapToOdom(&snapshot);
  // Commands such as ~get_status make snapshots too; the graph goes out only when it changed, and
  // only to subscribers (one that connects later sets graph_pending_: the timer flushes).
  if (graph_published_ && pipeline.revision() == graph_revision_) return;
  if (graph_pub_.getNumSubscribers() == 0) return;
  const std::shared_ptr<const NodeOptions> o = options();
  const double now = ros::WallTime::now().toSec();
  if (now < next_graph_wall_sec_) {
    graph_pending_ = true;  // the visualisation timer asks for it again
    return;
  }
  graph_pub_.publish(graphMessage(pipeline, snapshot, o->map_frame));
  graph_published_ = true;
  graph_revision_ = pipeline.revision();
  next_graph_wall_sec_ =
      now + visualizationPeriodSec(o->visualization_rate_hz, o->visualization_period_per_keyframe_sec,
                                   snapshot.keyframes.size());
  graph_pending_ = false;
}

void MapCorrectorNode::visualizationTimerCallback(const ros::WallTimerEvent&) {
  // A no-op command makes the worker publish a snapshot, so onSnapshot sends the pending graph.
  if (graph_pending_.exchange(false)) worker_->post([](Pipeline&) {});
  const std::shared_ptr<const Snapshot> s = worker_->snapshot();
  if (s->generation == published_generation_) return;
  const std::shared_ptr<const NodeOptions> o = options();
  const bool new_epoch = s->epoch != published_epoch_;
  const double wall = ros::WallTime::now().toSec();
  // Large graphs wait longer (visualizationPeriodSec); a reset clears the old markers at once.
  if (new_epoch || wall >= next_visualization_wall_sec_) {
    const ros::Time now = ros::Time::now();
    path_pub_.publish(pathFromSnapshot(*s, o->map_frame, now));
    markers_pub_.publish(markersFromSnapshot(*s, o->map_frame, now, o->markers, new_epoch));
    published_generation_ = s->generation;
    published_epoch_ = s->epoch;
    next_visualization_wall_sec_ =
        wall + visualizationPeriodSec(o->visualization_rate_hz, o->visualization_period_per_keyframe_sec,
                                      s->keyframes.size());
  }

  // Once odometry has stopped (a bag ended), a later correction (~optimize, a full round) would
  // otherwise never reach ~pose: publish the last pose again with the new map_T_odom.
  const double since_odometry = ros::WallTime::now().toSec() - last_odometry_wall_sec_;
  if (!s->has_map_T_odom || !(since_odometry > 1.0 / o->visualization_rate_hz)) return;
  nav_msgs::Odometry::ConstPtr odometry;
  {
    std::lock_guard<std::mutex> lock(pose_mutex_);
    if (!pose_odometry_ || samePose(pose_map_T_odom_, s->map_T_odom)) return;
    odometry = pose_odometry_;
    pose_map_T_odom_ = s->map_T_odom;
  }
  pose_pub_.publish(correctedPose(s->map_T_odom, *odometry, o->map_frame, o->pipeline.planar));
}

void MapCorrectorNode::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  const std::shared_ptr<const Snapshot> s = worker_->snapshot();
  const std::shared_ptr<const NodeOptions> o = options();
  InputSample sample;
  sample.now_sec = ros::WallTime::now().toSec();
  sample.start_sec = start_wall_sec_;
  const double last_odometry = last_odometry_wall_sec_;
  if (!std::isnan(last_odometry)) sample.last_odometry_sec = last_odometry;
  sample.queue_length = worker_->queueLength();
  sample.counters = s->counters;
  input_health_.setOptions(o->diagnostics);
  std::vector<HealthFinding> findings = input_health_.update(sample);
  if (sample.queue_length * 2 > static_cast<std::size_t>(o->queue_size))
    findings.push_back({diagnostic_msgs::DiagnosticStatus::WARN, "input queue more than half full"});
  if (s->counters.autosave_failures > 0)
    findings.push_back({diagnostic_msgs::DiagnosticStatus::WARN, "autosave failed, see the log"});
  if (!unknown_parameters_.empty())
    findings.push_back({diagnostic_msgs::DiagnosticStatus::WARN, "unknown parameters (typos?), see the log"});
  if (findings.empty()) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK,
                   s->keyframes.empty() ? "waiting for odometry" : "running");
  } else {
    std::uint8_t level = diagnostic_msgs::DiagnosticStatus::OK;
    std::string message;
    for (const HealthFinding& f : findings) {
      level = std::max(level, f.level);
      message += (message.empty() ? "" : "; ") + f.message;
    }
    status.summary(level, message);
  }
  std::string unknown;
  for (const std::string& key : unknown_parameters_) unknown += (unknown.empty() ? "" : " ") + key;
  status.add("unknown parameters", unknown);
  status.add("queue length", sample.queue_length);
  status.add("queue dropped", worker_->dropped());
  status.add("odometry age sec",
             sample.last_odometry_sec ? sample.now_sec - *sample.last_odometry_sec : -1.0);
  status.add("odometry messages", s->counters.odometry_messages);
  status.add("odometry refused", s->counters.odometry_refused);
  status.add("refusals per sec", input_health_.refusalRate());
  status.add("keyframes", s->keyframes.size());
  status.add("constraints", s->edges.size());
  status.add("loop closures applied", s->counters.loop_closures_applied);
  status.add("loop closures refused", s->counters.loop_closures_refused);
  status.add("loop closures pending", s->pending_loop_closures);
  status.add("loop closures rejected", s->counters.loop_closures_rejected);
  status.add("loop closures readmitted", s->counters.loop_closures_readmitted);
  status.add("loop closures held for support / released (by a finish)",
             std::to_string(s->counters.loop_closures_held) + " / " +
                 std::to_string(s->counters.loop_closures_released) + " (" +
                 std::to_string(s->counters.loop_closures_released_predicted) + ")");
  status.add("loop closures down-weighted (robust)", s->down_weighted_loop_closures);
  status.add("robust kernel width", s->robust_width);
  // The same counts as ~get_status's refused_reasons/refused_counts, one key per reason.
  for (const auto& [reason, count] : s->counters.refused_by_reason) status.add("refused: " + reason, count);
  status.add("odometry steps with default covariance (all / some axes)",
             std::to_string(s->counters.odometry_steps_default) + " / " +
                 std::to_string(s->counters.odometry_steps_partly_default));
  status.add("loop closures with default covariance (all / some axes)",
             std::to_string(s->counters.loop_closures_default) + " / " +
                 std::to_string(s->counters.loop_closures_partly_default));
  status.add("autosaves", s->counters.autosaves);
  status.add("autosave failures", s->counters.autosave_failures);
  status.add("background finishes (started / merged / dropped)",
             std::to_string(s->counters.finishes_started) + " / " + std::to_string(s->counters.finishes_merged) +
                 " / " + std::to_string(s->counters.finishes_dropped));
  status.add("background finishes from scratch (tried / kept)",
             std::to_string(s->counters.finishes_from_scratch) + " / " +
                 std::to_string(s->counters.finishes_from_scratch_kept));
  status.add("background finish running", s->finish_running ? "yes" : "no");
  if (!s->finish_off_reason.empty()) status.add("background finish off", s->finish_off_reason);
  if (s->last_finish) {
    const FinishRecord& f = *s->last_finish;
    std::ostringstream last;
    last << (f.merged ? "merged" : "not merged: " + f.error) << "; taken at " << f.stamp.toSec() << " s, "
         << f.seconds << " s, chi2 " << f.chi2_before << " -> " << f.chi2_after << ", " << f.iterations
         << " iterations, " << f.nodes_added_since << " keyframes added meanwhile";
    status.add("last background finish", last.str());
  }
  status.add("last chi2", s->chi2);
  status.add("last optimization sec", s->last_optimization_sec);
}

}  // namespace toro_ros
