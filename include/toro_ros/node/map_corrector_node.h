// The ROS adapter around Pipeline: parameters in, messages into a bounded queue, one worker thread
// that owns the pipeline, results out as tf / path / markers / diagnostics, services as commands.
//
// Threads: the global callback queue (subscriptions, visualisation and diagnostics timers) is spun
// by the caller (ros::spin in main); services run on their own callback queue and spinner so a
// service waiting for the worker never delays the subscriptions; the tf timer has its own queue
// and spinner so map->odom keeps its rate whatever else is busy.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <optional>

#include <diagnostic_updater/diagnostic_updater.h>
#include <nav_msgs/Odometry.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>

#include "toro_ros/GetStatus.h"
#include "toro_ros/GraphFile.h"
#include "toro_ros/LoopClosure.h"
#include "toro_ros/Optimize.h"
#include "toro_ros/node/node_options.h"
#include "toro_ros/node/pipeline_worker.h"
#include "toro_ros/pipeline/graph_directory.h"
#include "toro_ros/pipeline/input_table.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

class MapCorrectorNode {
 public:
  // Reads ~ parameters (throws std::invalid_argument naming the bad ones), advertises, subscribes
  // and starts the worker.
  MapCorrectorNode(ros::NodeHandle nh, ros::NodeHandle private_nh);
  // Stops the producers and the worker, then autosaves (persistence.autosave_path) what it applied.
  ~MapCorrectorNode();

  MapCorrectorNode(const MapCorrectorNode&) = delete;
  MapCorrectorNode& operator=(const MapCorrectorNode&) = delete;

 private:
  // One subscription per row of the input table (pipeline/input_table.h), shared with the
  // offline runner so both feed the pipeline the same way.
  void subscribeInputs();
  template <class M>
  void enqueue(const boost::shared_ptr<const M>& msg, const char* what);
  void tfTimerCallback(const ros::TimerEvent&);
  void visualizationTimerCallback(const ros::TimerEvent&);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);

  // Runs `f` on the worker and waits (service_timeout_sec) for its result; nullopt on timeout.
  // `f` must own what it uses (capture by value): after a timeout it still runs later.
  template <class R>
  std::optional<R> runOnWorker(std::function<R(Pipeline&)> f) {
    return worker_->call<R>(std::move(f), std::chrono::duration<double>(options_.service_timeout_sec));
  }

  bool optimizeService(Optimize::Request& req, Optimize::Response& res);
  bool pauseService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool resumeService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool resetService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool saveGraphService(GraphFile::Request& req, GraphFile::Response& res);
  bool loadGraphService(GraphFile::Request& req, GraphFile::Response& res);
  bool getStatusService(GetStatus::Request& req, GetStatus::Response& res);

  ros::NodeHandle nh_, private_nh_;
  std::vector<std::string> unknown_parameters_;  // private keys nobody reads (shown in diagnostics)
  NodeOptions options_;
  // ~save_graph / ~load_graph names are confined to it (set before the services are advertised).
  GraphDirectory graph_directory_;
  std::unique_ptr<PipelineWorker> worker_;

  // Visualisation timer state (only its callback touches these).
  std::uint64_t published_generation_ = 0;
  std::uint64_t published_epoch_ = 0;

  tf2_ros::TransformBroadcaster tf_broadcaster_;
  ros::Publisher path_pub_, markers_pub_;
  std::vector<ros::Subscriber> input_subs_;
  std::vector<ros::ServiceServer> services_;
  ros::CallbackQueue tf_queue_, service_queue_;
  ros::Timer tf_timer_, visualization_timer_, diagnostics_timer_;
  // Stamp of the last map->odom sent; only the tf timer's callback (one thread) touches it.
  ros::Time last_tf_stamp_;
  std::unique_ptr<ros::AsyncSpinner> tf_spinner_, service_spinner_;
  diagnostic_updater::Updater diagnostics_;
};

}  // namespace toro_ros
