// toro_offline: a bag through the node's Pipeline at full speed (no master, no pacing), like
// cartographer_ros's offline node.  Messages are read with rosbag::View in bag-time order (the
// order `rosbag play` would publish them), handed to the pipeline through the shared topic table
// (pipeline/input_table.h), and after each message the scheduled optimisation runs until nothing
// is due, which is what the node's worker does when it keeps up with its input.
#pragma once

#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <rosbag/message_instance.h>

#include "toro_ros/node/node_options.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {
namespace offline {

struct OfflineOptions {
  std::string bag_path;
  std::string config_path;  // node parameter file (config/map_corrector.yaml keys); empty = defaults
  std::string output_dir = "out/offline";
  std::string topic_namespace = "/";  // where the node would run: its relative topics resolve here
  int final_iterations = 20;          // full passes after the bag, as `~optimize` would (0: none)
  bool iteration_curve = true;        // chi2 after each final pass (runs the final passes on a copy too)
  bool progress = true;               // progress bar on stderr
  std::string truth_path;             // optional "<stem>.truth.g2o" (+ the odometry sidecar) for scoring
  // Part of the bag to read, in seconds from its first message on the input topics, as `rosbag
  // play -s START -u DURATION` would play it (duration 0: to the end).
  double start_sec = 0.0;
  double duration_sec = 0.0;
  // Every this many seconds of message time (0: never), the optimum of the graph so far is
  // computed on a copy (the plain sparse finish from the map as published) and its chi2 recorded
  // beside the published map's (OfflineRun::optimality): how far the live map is from the best
  // it could be.  A benchmark's measurement: it costs one finish per sample.
  double optimality_every_sec = 0.0;
  // > 0: the samples are taken this many seconds of message time after a loop closure arrived (the
  // first since the last sample) instead of at regular stamps, still at most one per
  // optimality_every_sec: the "within 1 % within 2 s after each loop closure" measured
  // where it applies.  Loop closures arriving meanwhile are sampled sooner than this after them.
  double optimality_after_loop_closure_sec = 0.0;
  // Threads of the finish (toro::setSolverThreads, process-wide); unset: the config's finish_threads,
  // as the node would set them.
  std::optional<int> solver_threads;
  std::string validate() const;
};

// One point of the error curve: after an optimisation pass.
struct CurvePoint {
  std::size_t pass = 0;    // 1-based over the whole run
  double stamp_sec = 0.0;  // newest odometry stamp when it ran (0 for the final passes)
  std::size_t keyframes = 0;
  std::size_t constraints = 0;
  double chi2 = 0.0;
  bool final_phase = false;  // one of the final full passes after the bag
};

struct OfflineRun {
  std::size_t messages = 0;  // read from the bag on the input topics
  std::map<std::string, std::size_t> messages_by_topic;
  double bag_duration_sec = 0.0;
  double wall_sec = 0.0;          // everything from opening the bag to the end of the final passes
  double optimization_sec = 0.0;  // part of it spent in optimisation passes and finishes
  std::size_t finishes = 0;       // background finishes run (inline, see drainSchedule)
  std::string blas_kernels;       // OpenBLAS's kernels the finishes ran with (toro::selectBlasKernels)
  std::vector<CurvePoint> curve;
  OptimizeResult final_result;
  // Where the node would have shown the robot after each odometry message: map_T_odom of the
  // pipeline then (what its tf timer publishes) applied to that message's pose.  Compared between
  // runs of one bag (bench/run_robust_offline.sh), it shows how far the published map ever moved;
  // map_T_odom itself lets a comparison apply one run's correction at another moment to the same
  // odometry (a correction that came a moment later is latency, not a bend).
  struct RobotInMap {
    double stamp_sec = 0.0;
    toro::Vector3 position = toro::Vector3::Zero();
    toro::Pose3 map_T_odom;
  };
  std::vector<RobotInMap> robot_in_map;
  // OfflineOptions::optimality_every_sec: the published map's chi2 and the optimum's at a stamp.
  struct Optimality {
    double stamp_sec = 0.0;
    double published_chi2 = 0.0;
    double optimum_chi2 = 0.0;
    // The same under the robust weights the map uses (loop closures held or weighed down count
    // by their weight): the objective the map and its finishes minimise.  Equal to the above
    // when every loop closure has full weight.
    double published_weighted_chi2 = 0.0;
    double weighted_optimum_chi2 = 0.0;
    std::size_t constraints = 0;
    // Message time since the newest loop closure received (NaN before the first).
    double since_loop_closure_sec = 0.0;
  };
  std::vector<Optimality> optimality;
};

// Feeds one bag message to the pipeline: the table built from forEachPipelineInput.
using BagHandler = std::function<void(const rosbag::MessageInstance&, Pipeline&)>;
// topic in the bag -> handler.  Throws std::runtime_error for a message whose type does not fit.
std::map<std::string, BagHandler> makeBagHandlers(const std::string& topic_namespace);

// "ns" + "name" as ROS resolves a relative name in a namespace ("/" + "odom" = "/odom").
std::string resolveName(const std::string& ns, const std::string& name);

class OfflineRunner {
 public:
  // Throws std::invalid_argument naming the problem (options, parameter file keys or values), and
  // std::runtime_error if the parameter file's load_path exists but cannot be loaded.
  explicit OfflineRunner(const OfflineOptions& options);
  // Reads the whole bag.  Throws std::runtime_error naming the bag (and topic/stamp) on errors.
  OfflineRun run();
  Pipeline& pipeline() { return *pipeline_; }
  const NodeOptions& nodeOptions() const { return node_options_; }

 private:
  void drainSchedule(double stamp_sec, OfflineRun* run);
  void traceRobot(const rosbag::MessageInstance& m, OfflineRun* run) const;
  void sampleOptimality(double stamp_sec, double since_loop_closure_sec, OfflineRun* run) const;
  void finalPasses(OfflineRun* run);

  OfflineOptions options_;
  NodeOptions node_options_;
  std::unique_ptr<Pipeline> pipeline_;
  std::vector<std::string> warnings_;
};

// Loads node options from a parameter file (or the defaults for an empty path).  Throws
// std::invalid_argument naming the file and every bad or unknown key.
NodeOptions loadNodeOptionsFile(const std::string& path);

}  // namespace offline
}  // namespace toro_ros
