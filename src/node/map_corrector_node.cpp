#include "toro_ros/node/map_corrector_node.h"

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Path.h>
#include <visualization_msgs/MarkerArray.h>

#include "toro_ros/PoseGraph.h"
#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/node/names.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {

namespace {

// The one place parameters are read at start: the whole private namespace at once, every value
// logged, unknown keys warned about (typos would otherwise silently keep a default).
NodeOptions loadOptions(const ros::NodeHandle& private_nh, XmlRpc::XmlRpcValue* params,
                        std::vector<std::string>* unknown_keys) {
  if (!private_nh.getParam(private_nh.getNamespace(), *params)) *params = XmlRpc::XmlRpcValue();
  OptionsReport report;
  const NodeOptions options = loadNodeOptions(*params, &report);
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
      options_(std::make_shared<const NodeOptions>(loadOptions(private_nh, &params_, &unknown_parameters_))),
      applied_config_(MapCorrectorConfig::__getDefault__()),
      graph_directory_(options_->graph_directory),
      last_odometry_wall_sec_(std::numeric_limits<double>::quiet_NaN()),
      start_wall_sec_(ros::WallTime::now().toSec()),
      input_health_(options_->diagnostics),
      diagnostics_(nh, private_nh) {
  {
    // No other thread runs yet: the options may still be replaced without the lock.
    NodeOptions resolved = *options_;
    ROS_INFO_STREAM("map corrector: " << graph_directory_.resolveOperatorPaths(
                        &resolved.load_path, &resolved.pipeline.persistence.autosave_path));
    options_ = std::make_shared<const NodeOptions>(resolved);
  }
  {
    // Process-wide (a nodelet: the whole manager); every finish applies it in its own thread.
    const toro::SolverThreadSettings threads = toro::setSolverThreads(options_->finish_threads);
    ROS_INFO_STREAM("map corrector: finish threads "
                    << (threads.threads > 0 ? std::to_string(threads.threads) : std::string("of the libraries"))
                    << " (OpenBLAS " << (threads.openblas_set ? "set" : "not loaded or left") << ", OpenMP "
                    << (threads.openmp_set ? "set" : "not loaded or left") << ")");
    // Reports only: the kernels can be switched only where no other code may be inside the BLAS,
    // which map_corrector_node's main does before this; in a nodelet manager the note advises.
    ROS_INFO_STREAM("map corrector: " << toro::selectBlasKernels(/*may_switch=*/false).note);
  }
  auto pipeline = std::make_unique<Pipeline>(
      options_->pipeline, [](const std::string& w) { ROS_WARN_STREAM("map corrector: " << w); },
      [](const std::string& i) { ROS_INFO_STREAM("map corrector: " << i); });
  // Before the worker takes the pipeline; throws, stopping the node, if load_path exists but
  // cannot be loaded, rather than start empty and autosave over it.  Its message goes to /rosout,
  // which anyone on the ROS network reads, and parameters can be set by anyone there: it quotes
  // no file content.
  const std::string resumed = loadOnStart(*pipeline, options_->load_path, /*quote_content=*/false);
  if (!resumed.empty()) ROS_INFO_STREAM("map corrector: " << resumed);
  path_pub_ = private_nh_.advertise<nav_msgs::Path>(names::kPathTopic, 1, true);
  markers_pub_ = private_nh_.advertise<visualization_msgs::MarkerArray>(names::kMarkersTopic, 1, true);
  // ~graph is built only while someone subscribes (about 500 bytes per keyframe: 10 MB and ~0.1 s
  // of the worker at 20,000 keyframes, bench/node_results.md); a new subscriber gets the current
  // graph within one visualisation period.
  graph_pub_ = private_nh_.advertise<PoseGraph>(
      names::kGraphTopic, 1, [this](const ros::SingleSubscriberPublisher&) { graph_pending_ = true; },
      ros::SubscriberStatusCallback(), ros::VoidConstPtr(), true);
  pose_pub_ = private_nh_.advertise<geometry_msgs::PoseWithCovarianceStamped>(names::kPoseTopic, 10);
  // The observer publishes ~graph, so the publishers exist before the worker.
  worker_ = std::make_unique<PipelineWorker>(
      std::move(pipeline), static_cast<std::size_t>(options_->queue_size),
      [](const std::string& e) { ROS_ERROR_STREAM("map corrector: " << e); },
      [this](const Pipeline& p, const Snapshot& s) { onSnapshot(p, s); });

  subscribeInputs();
  advertiseServices();
  startTimers();
  ROS_INFO_STREAM("map corrector: publishing " << options_->map_frame << " -> " << options_->odom_frame);
}

MapCorrectorNode::~MapCorrectorNode() {
  // Stop the producers first, then the worker: flag, wake it, join.
  tf_timer_.stop();
  correction_timer_.stop();
  visualization_timer_.stop();
  diagnostics_timer_.stop();
  for (ros::Subscriber& sub : input_subs_) sub.shutdown();
  if (service_spinner_) service_spinner_->stop();
  if (tf_spinner_) tf_spinner_->stop();
  reconfigure_server_.reset();
  worker_->stop();
  // The worker is gone: this thread may touch the pipeline and save what was applied.  autosave()
  // writes only if something changed since the last save (a failure is logged by the pipeline).
  const std::string error = worker_->pipeline().autosave();
  if (!options_->pipeline.persistence.autosave_path.empty() && error.empty())
    ROS_INFO_STREAM("map corrector: the graph in " << options_->pipeline.persistence.autosave_path
                                                   << " is up to date");
}

void MapCorrectorNode::advertiseServices() {
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
  // Its first callback (from setCallback, on this thread) sees the start-up values: no change.
  reconfigure_server_ = std::make_unique<dynamic_reconfigure::Server<MapCorrectorConfig>>(service_nh);
  reconfigure_server_->setCallback(
      [this](MapCorrectorConfig& config, std::uint32_t level) { reconfigure(config, level); });
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &service_queue_);
  service_spinner_->start();
}

void MapCorrectorNode::startTimers() {
  const std::shared_ptr<const NodeOptions> o = options();
  ros::NodeHandle tf_nh(nh_);
  tf_nh.setCallbackQueue(&tf_queue_);
  tf_timer_ = tf_nh.createTimer(ros::Duration(1.0 / o->tf_rate_hz), &MapCorrectorNode::tfTimerCallback, this);
  // Always running, it does nothing unless a correction was deferred (a flag read under tf_mutex_,
  // 20 times a second): a one-shot timer restarted from the worker would have to be stopped
  // under the lock its own callback takes.
  correction_timer_ = tf_nh.createWallTimer(ros::WallDuration(MapToOdomSchedule::kCorrectionSpacingSec),
                                            &MapCorrectorNode::correctionTimerCallback, this);
  tf_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &tf_queue_);
  tf_spinner_->start();

  visualization_timer_ = nh_.createWallTimer(ros::WallDuration(1.0 / o->visualization_rate_hz),
                                             &MapCorrectorNode::visualizationTimerCallback, this);
  diagnostics_.setHardwareID("none");
  diagnostics_.add("map corrector", this, &MapCorrectorNode::diagnose);
  // force_update: Updater::update() paces itself with ros::Time, which stops with a bag's clock.
  diagnostics_timer_ =
      nh_.createWallTimer(ros::WallDuration(1.0 / o->diagnostics_rate_hz),
                          [this](const ros::WallTimerEvent&) { diagnostics_.force_update(); });
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
  if constexpr (std::is_same_v<M, nav_msgs::Odometry>) onOdometryArrived(msg);
  // Never blocks: a full queue drops the message and counts it (diagnostics, ~get_status).
  if (!worker_->push(PipelineMessage(msg)))
    ROS_WARN_THROTTLE(5.0, "map corrector: input queue full, %s message dropped", what);
}

}  // namespace toro_ros
