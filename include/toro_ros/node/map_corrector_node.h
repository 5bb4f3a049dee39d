// The ROS adapter around Pipeline: parameters in, messages into a bounded queue, one worker thread
// that owns the pipeline, results out as tf / pose / graph / path / markers / diagnostics, services
// and dynamic_reconfigure changes as commands.  The plain node (map_corrector_node_main.cpp) and
// the nodelet (map_corrector_nodelet.cpp) are thin wrappers around this one class.
//
// Threads: the node handle's callback queue (the global one for the plain node, the manager's for
// the nodelet) runs the subscriptions and the wall timers of visualisation and diagnostics;
// services and dynamic_reconfigure run on their own callback queue and spinner so a service
// waiting for the worker never delays the subscriptions; the tf timer has its own queue and
// spinner so map->odom keeps its rate whatever else is busy; the ~graph message is built on the
// worker thread (PipelineWorker::SnapshotObserver), where the graph lives.
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>

#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <nav_msgs/Odometry.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>

#include "toro_ros/GetStatus.h"
#include "toro_ros/GraphFile.h"
#include "toro_ros/LoopClosure.h"
#include "toro_ros/MapCorrectorConfig.h"
#include "toro_ros/Optimize.h"
#include "toro_ros/node/input_health.h"
#include "toro_ros/node/map_to_odom_schedule.h"
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
  void advertiseServices();
  void startTimers();
  template <class M>
  void enqueue(const boost::shared_ptr<const M>& msg, const char* what);

  // Outputs (map_corrector_outputs.cpp).
  void tfTimerCallback(const ros::TimerEvent&);
  // Sends map->odom stamped transform_tolerance_sec ahead of now, unless that stamp went out
  // already.  nullptr: the tick, from the worker's snapshot.  A snapshot (the worker's observer,
  // after it became the worker's): only when an optimisation moved the map since the last one
  // sent; when that cannot go out yet (MapToOdomSchedule) the correction timer retries.
  void sendMapToOdom(const Snapshot* correction);
  // Retries a deferred correction, from the worker's newest snapshot.
  void correctionTimerCallback(const ros::WallTimerEvent&);
  // Wall time: under simulated time the clock stops with the bag, and the final state must still
  // go out (path, markers, graph, pose).
  void visualizationTimerCallback(const ros::WallTimerEvent&);
  void onOdometryArrived(const nav_msgs::Odometry::ConstPtr& msg);
  // ~graph, on the worker thread, at most visualization_rate_hz (later changes are flushed by the
  // visualisation timer).
  void onSnapshot(const Pipeline& pipeline, const Snapshot& snapshot);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);

  // dynamic_reconfigure (map_corrector_reconfigure.cpp): validated like the start-up parameters,
  // applied to the pipeline as a worker command, logged change by change; a refused change puts
  // the previous values back into `config` (which the server then publishes).
  void reconfigure(MapCorrectorConfig& config, std::uint32_t level);

  // Runs `f` on the worker and waits (service_timeout_sec) for its result; nullopt on timeout.
  // `f` must own what it uses (capture by value): after a timeout it still runs later.
  template <class R>
  std::optional<R> runOnWorker(std::function<R(Pipeline&)> f) {
    return worker_->call<R>(std::move(f), std::chrono::duration<double>(options()->service_timeout_sec));
  }

  bool optimizeService(Optimize::Request& req, Optimize::Response& res);
  bool pauseService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool resumeService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool resetService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool saveGraphService(GraphFile::Request& req, GraphFile::Response& res);
  bool loadGraphService(GraphFile::Request& req, GraphFile::Response& res);
  bool getStatusService(GetStatus::Request& req, GetStatus::Response& res);

  // The options now (replaced as a whole by reconfigure; readers on any thread take a copy).
  std::shared_ptr<const NodeOptions> options() const {
    std::lock_guard<std::mutex> lock(options_mutex_);
    return options_;
  }

  ros::NodeHandle nh_, private_nh_;
  // Declared (so constructed) before options_, whose initialiser fills them.
  std::vector<std::string> unknown_parameters_;  // private keys nobody reads (shown in diagnostics)
  // The private parameters as last applied (start-up values, then each accepted reconfigure);
  // only the reconfigure callback touches them after construction (dynamic_reconfigure's server
  // serialises its callbacks).
  XmlRpc::XmlRpcValue params_;
  mutable std::mutex options_mutex_;  // guards options_ (the pointer)
  std::shared_ptr<const NodeOptions> options_;
  MapCorrectorConfig applied_config_;
  // ~save_graph / ~load_graph names are confined to it (set before the services are advertised).
  GraphDirectory graph_directory_;

  ros::Publisher path_pub_, markers_pub_, graph_pub_, pose_pub_;
  std::unique_ptr<PipelineWorker> worker_;

  // Visualisation timer state (only its callback touches these).
  std::uint64_t published_generation_ = 0;
  std::uint64_t published_epoch_ = 0;
  double next_visualization_wall_sec_ = 0.0;  // ~path and ~graph_markers wait until then
  // ~graph state, touched only by onSnapshot (the worker thread, or the constructor before it).
  std::uint64_t graph_revision_ = 0;
  bool graph_published_ = false;
  double next_graph_wall_sec_ = 0.0;
  std::atomic<bool> graph_pending_{false};  // a change not yet on ~graph (set by the worker)

  // The newest usable odometry message and the map_T_odom its ~pose used (the visualisation
  // timer republishes it when map_T_odom changed after odometry stopped).
  std::mutex pose_mutex_;  // guards the two below
  nav_msgs::Odometry::ConstPtr pose_odometry_;
  toro::Pose3 pose_map_T_odom_;
  std::atomic<double> last_odometry_wall_sec_;  // NaN before the first odometry message
  double start_wall_sec_ = 0.0;
  InputHealth input_health_;  // only diagnose() touches it

  tf2_ros::TransformBroadcaster tf_broadcaster_;
  std::vector<ros::Subscriber> input_subs_;
  std::vector<ros::ServiceServer> services_;
  ros::CallbackQueue tf_queue_, service_queue_;
  ros::Timer tf_timer_;
  ros::WallTimer visualization_timer_, diagnostics_timer_, correction_timer_;
  // The last map->odom sent: the tf timer and, for a correction, the worker send it.
  std::mutex tf_mutex_;  // guards the two below
  MapToOdomSchedule tf_schedule_;
  toro::Pose3 last_tf_map_T_odom_;
  std::unique_ptr<ros::AsyncSpinner> tf_spinner_, service_spinner_;
  diagnostic_updater::Updater diagnostics_;
  std::unique_ptr<dynamic_reconfigure::Server<MapCorrectorConfig>> reconfigure_server_;
};

}  // namespace toro_ros
