// Run-time tuning of MapCorrectorNode through dynamic_reconfigure (cfg/MapCorrector.cfg).  A
// change is read and validated exactly like the start-up parameters (loadNodeOptions on the
// parameter struct with the new values), handed to the pipeline as a command of the worker (so
// it lands between passes and never races one), then applied to the node's own timers and
// options, and logged change by change.
#include "toro_ros/node/live_options.h"
#include "toro_ros/node/map_corrector_node.h"

namespace toro_ros {

void MapCorrectorNode::reconfigure(MapCorrectorConfig& config, std::uint32_t) {
  const XmlRpc::XmlRpcValue requested = withConfig(params_, config);
  const std::vector<std::string> changes = changedParameters(params_, requested);
  if (changes.empty()) {
    // The server's first call (the start-up values), or a request that changes nothing.
    applied_config_ = config;
    return;
  }
  OptionsReport report;
  NodeOptions next = loadNodeOptions(requested, &report);
  // The start-up paths as resolved against graph_directory (not live: they stay as they were).
  const std::shared_ptr<const NodeOptions> current = options();
  next.load_path = current->load_path;
  next.pipeline.persistence.autosave_path = current->pipeline.persistence.autosave_path;
  if (!report.errors.empty()) {
    std::string all;
    for (const std::string& e : report.errors) all += "\n  " + e;
    ROS_ERROR_STREAM("map corrector: reconfigure refused, nothing changed:" << all);
    config = applied_config_;
    return;
  }
  const auto applied = runOnWorker<std::string>(
      [pipeline_options = next.pipeline](Pipeline& p) { return p.applyLiveOptions(pipeline_options); });
  if (applied && !applied->empty()) {
    ROS_ERROR_STREAM("map corrector: reconfigure refused, nothing changed: " << *applied);
    config = applied_config_;
    return;
  }
  if (!applied)
    ROS_WARN_STREAM(
        "map corrector: reconfigure: the worker did not answer within service_timeout_sec; "
        "the pipeline takes the change when it gets to it");

  const std::shared_ptr<const NodeOptions>& before = current;
  {
    std::lock_guard<std::mutex> lock(options_mutex_);
    options_ = std::make_shared<const NodeOptions>(next);
  }
  if (next.tf_rate_hz != before->tf_rate_hz) tf_timer_.setPeriod(ros::Duration(1.0 / next.tf_rate_hz));
  if (next.visualization_rate_hz != before->visualization_rate_hz)
    visualization_timer_.setPeriod(ros::WallDuration(1.0 / next.visualization_rate_hz));
  if (next.diagnostics_rate_hz != before->diagnostics_rate_hz)
    diagnostics_timer_.setPeriod(ros::WallDuration(1.0 / next.diagnostics_rate_hz));
  params_ = requested;
  applied_config_ = config;
  for (const std::string& change : changes) ROS_INFO_STREAM("map corrector: reconfigured " << change);
}

}  // namespace toro_ros
