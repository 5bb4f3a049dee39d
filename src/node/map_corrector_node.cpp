#include "toro_ros/node/map_corrector_node.h"

#include <sstream>
#include <stdexcept>

#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Path.h>
#include <visualization_msgs/MarkerArray.h>

#include "toro_ros/node/names.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/persistence.h"
#include "toro_ros/pipeline/visualization.h"

namespace toro_ros {

namespace {

// The one place parameters are read: the whole private namespace at once, every value logged,
// unknown keys warned about (typos would otherwise silently keep a default).
NodeOptions loadOptions(const ros::NodeHandle& private_nh, std::vector<std::string>* unknown_keys) {
  XmlRpc::XmlRpcValue params;
  if (!private_nh.getParam(private_nh.getNamespace(), params)) params = XmlRpc::XmlRpcValue();
  OptionsReport report;
  const NodeOptions options = loadNodeOptions(params, &report);
  for (const std::string& line : report.values)
    ROS_INFO_STREAM("  " << private_nh.getNamespace() << "/" << line);
  for (const std::string& key : report.unknown_keys)
    ROS_WARN_STREAM("unknown parameter " << private_nh.getNamespace() << "/" << key
                                         << " (ignored; see config/map_corrector.yaml for the known keys)");
  if (!report.errors.empty()) {
    std::ostringstream all;
    for (const std::string& e : report.errors) all << "\n  " << e;
    throw std::invalid_argument("invalid parameters in " + private_nh.getNamespace() + ":" + all.str());
  }
  *unknown_keys = report.unknown_keys;
  return options;
}

}  // namespace

MapCorrectorNode::MapCorrectorNode(ros::NodeHandle nh, ros::NodeHandle private_nh)
    : nh_(nh),
      private_nh_(private_nh),
      options_(loadOptions(private_nh, &unknown_parameters_)),
      graph_directory_(options_.graph_directory),
      diagnostics_(nh, private_nh) {
  ROS_INFO_STREAM("map corrector: " << graph_directory_.resolveOperatorPaths(
                      &options_.load_path, &options_.pipeline.persistence.autosave_path));
  auto pipeline = std::make_unique<Pipeline>(
      options_.pipeline, [](const std::string& w) { ROS_WARN_STREAM("map corrector: " << w); });
  // Before the worker takes the pipeline; throws, stopping the node, if load_path exists but
  // cannot be loaded, rather than start empty and autosave over it.  Its message goes to /rosout,
  // which anyone on the ROS network reads, and parameters can be set by anyone there: it quotes
  // no file content.
  const std::string resumed = loadOnStart(*pipeline, options_.load_path, /*quote_content=*/false);
  if (!resumed.empty()) ROS_INFO_STREAM("map corrector: " << resumed);
  worker_ = std::make_unique<PipelineWorker>(std::move(pipeline), static_cast<std::size_t>(options_.queue_size),
                                             [](const std::string& e) { ROS_ERROR_STREAM("map corrector: " << e); });
  path_pub_ = private_nh_.advertise<nav_msgs::Path>(names::kPathTopic, 1, true);
  markers_pub_ = private_nh_.advertise<visualization_msgs::MarkerArray>(names::kMarkersTopic, 1, true);

  subscribeInputs();

  ros::NodeHandle service_nh(private_nh_);
  service_nh.setCallbackQueue(&service_queue_);
  services_.push_back(
      service_nh.advertiseService(names::kOptimizeService, &MapCorrectorNode::optimizeService, this));
  services_.push_back(
      service_nh.advertiseService(names::kPauseService, &MapCorrectorNode::pauseService, this));
  services_.push_back(
      service_nh.advertiseService(names::kResumeService, &MapCorrectorNode::resumeService, this));
  services_.push_back(
      service_nh.advertiseService(names::kResetService, &MapCorrectorNode::resetService, this));
  services_.push_back(
      service_nh.advertiseService(names::kSaveGraphService, &MapCorrectorNode::saveGraphService, this));
  services_.push_back(
      service_nh.advertiseService(names::kLoadGraphService, &MapCorrectorNode::loadGraphService, this));
  services_.push_back(
      service_nh.advertiseService(names::kGetStatusService, &MapCorrectorNode::getStatusService, this));
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &service_queue_);
  service_spinner_->start();

  ros::NodeHandle tf_nh(nh_);
  tf_nh.setCallbackQueue(&tf_queue_);
  tf_timer_ =
      tf_nh.createTimer(ros::Duration(1.0 / options_.tf_rate_hz), &MapCorrectorNode::tfTimerCallback, this);
  tf_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &tf_queue_);
  tf_spinner_->start();

  visualization_timer_ = nh_.createTimer(ros::Duration(1.0 / options_.visualization_rate_hz),
                                         &MapCorrectorNode::visualizationTimerCallback, this);
  diagnostics_.setHardwareID("none");
  diagnostics_.add("map corrector", this, &MapCorrectorNode::diagnose);
  diagnostics_timer_ = nh_.createTimer(ros::Duration(1.0 / options_.diagnostics_rate_hz),
                                       [this](const ros::TimerEvent&) { diagnostics_.update(); });
  ROS_INFO_STREAM("map corrector: publishing " << options_.map_frame << " -> " << options_.odom_frame);
}

MapCorrectorNode::~MapCorrectorNode() {
  // Stop the producers first, then the worker: flag, wake it, join.
  tf_timer_.stop();
  visualization_timer_.stop();
  diagnostics_timer_.stop();
  for (ros::Subscriber& sub : input_subs_) sub.shutdown();
  if (service_spinner_) service_spinner_->stop();
  if (tf_spinner_) tf_spinner_->stop();
  worker_->stop();
  // The worker is gone: this thread may touch the pipeline and save what was applied.  autosave()
  // writes only if something changed since the last save (a failure is logged by the pipeline).
  const std::string error = worker_->pipeline().autosave();
  if (!options_.pipeline.persistence.autosave_path.empty() && error.empty())
    ROS_INFO_STREAM("map corrector: the graph in " << options_.pipeline.persistence.autosave_path
                                                   << " is up to date");
}

void MapCorrectorNode::subscribeInputs() {
  forEachPipelineInput([this](const char* topic, auto handler) {
    using M = MessageOf<decltype(handler)>;
    const boost::function<void(const boost::shared_ptr<const M>&)> callback =
        [this, topic](const boost::shared_ptr<const M>& msg) { enqueue<M>(msg, topic); };
    input_subs_.push_back(
        nh_.subscribe<M>(topic, 100, callback, ros::VoidConstPtr(), ros::TransportHints().tcpNoDelay()));
    ROS_INFO_STREAM("map corrector: listening on " << input_subs_.back().getTopic());
  });
}

template <class M>
void MapCorrectorNode::enqueue(const boost::shared_ptr<const M>& msg, const char* what) {
  // Never blocks: a full queue drops the message and counts it (diagnostics, ~get_status).
  if (!worker_->push(PipelineMessage(msg)))
    ROS_WARN_THROTTLE(5.0, "map corrector: input queue full, %s message dropped", what);
}

void MapCorrectorNode::tfTimerCallback(const ros::TimerEvent&) {
  const std::shared_ptr<const Snapshot> s = worker_->snapshot();
  const ros::Time now = ros::Time::now();
  if (!s->has_map_T_odom || now.isZero()) return;  // nothing yet, or sim time before the first /clock
  // Stamped ahead so that tf lookups at "now" made by other nodes find it before the next tick.
  const ros::Time stamp = now + ros::Duration(options_.transform_tolerance_sec);
  // Under sim time the timer can fire twice between /clock ticks; the same stamp again would only
  // make tf warn TF_REPEATED_DATA.  (A stamp behind the last one is a clock jump: publish it.)
  if (stamp == last_tf_stamp_) return;
  last_tf_stamp_ = stamp;
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = options_.map_frame;
  t.child_frame_id = options_.odom_frame;
  t.transform = transformToMsg(s->map_T_odom);
  tf_broadcaster_.sendTransform(t);
}

void MapCorrectorNode::visualizationTimerCallback(const ros::TimerEvent&) {
  const std::shared_ptr<const Snapshot> s = worker_->snapshot();
  if (s->generation == published_generation_) return;
  const bool new_epoch = s->epoch != published_epoch_;
  const ros::Time now = ros::Time::now();
  path_pub_.publish(pathFromSnapshot(*s, options_.map_frame, now));
  markers_pub_.publish(markersFromSnapshot(*s, options_.map_frame, now, options_.markers, new_epoch));
  published_generation_ = s->generation;
  published_epoch_ = s->epoch;
}

void MapCorrectorNode::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  const std::shared_ptr<const Snapshot> s = worker_->snapshot();
  const std::size_t queued = worker_->queueLength();
  if (queued * 2 > static_cast<std::size_t>(options_.queue_size))
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "input queue more than half full");
  else if (s->counters.autosave_failures > 0)
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "autosave failed, see the log");
  else if (!unknown_parameters_.empty())
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "unknown parameters (typos?), see the log");
  else if (s->keyframes.empty())
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "waiting for odometry");
  else
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "running");
  std::string unknown;
  for (const std::string& key : unknown_parameters_) unknown += (unknown.empty() ? "" : " ") + key;
  status.add("unknown parameters", unknown);
  status.add("queue length", queued);
  status.add("queue dropped", worker_->dropped());
  status.add("keyframes", s->keyframes.size());
  status.add("constraints", s->edges.size());
  status.add("loop closures applied", s->counters.loop_closures_applied);
  status.add("loop closures refused", s->counters.loop_closures_refused);
  status.add("loop closures pending", s->pending_loop_closures);
  status.add("loop closures rejected", s->counters.loop_closures_rejected);
  status.add("loop closures readmitted", s->counters.loop_closures_readmitted);
  status.add("loop closures down-weighted (robust)", s->down_weighted_loop_closures);
  status.add("robust kernel width", s->robust_width);
  // The same counts as ~get_status's refused_reasons/refused_counts, one key per reason.
  for (const auto& [reason, count] : s->counters.refused_by_reason) status.add("refused: " + reason, count);
  status.add("autosaves", s->counters.autosaves);
  status.add("autosave failures", s->counters.autosave_failures);
  status.add("last chi2", s->chi2);
  status.add("last optimization sec", s->last_optimization_sec);
}

}  // namespace toro_ros
