// What the node's diagnostics say about its input, from the counters and the clock at each
// diagnostics update (no ROS transport: test/node/test_input_health.cpp).  WARN when odometry
// stopped, when refusals come faster than a limit, when no loop closure was ever applied, when
// the input queue keeps growing; ERROR when odometry arrives but none is accepted.
#pragma once

#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "toro_ros/pipeline/snapshot.h"

namespace toro_ros {

struct InputHealthOptions {
  // WARN when no odometry arrived for this long, in wall seconds (0: never).
  double stale_odometry_sec = 2.0;
  // WARN when messages (odometry and loop closures) are refused faster than this, per wall second
  // between two updates; > 0.
  double max_refusals_per_sec = 1.0;
  std::string validate() const;
};

// The node's state at one diagnostics update.  Times are wall seconds (any common origin):
// under simulated time the bag's clock stops with the bag, and stale input is a wall-time fact.
struct InputSample {
  double now_sec = 0.0;
  double start_sec = 0.0;                   // when the node started
  std::optional<double> last_odometry_sec;  // arrival of the newest odometry message
  std::size_t queue_length = 0;
  PipelineCounters counters;
};

struct HealthFinding {
  std::uint8_t level = 0;  // diagnostic_msgs/DiagnosticStatus OK, WARN or ERROR
  std::string message;
};

class InputHealth {
 public:
  // Queue lengths that grew at this many updates in a row, ending at kGrowingQueueMin or more,
  // mean the worker falls behind its input.
  static constexpr std::size_t kGrowingQueueUpdates = 3;
  static constexpr std::size_t kGrowingQueueMin = 10;

  explicit InputHealth(const InputHealthOptions& options) : options_(options) {}
  void setOptions(const InputHealthOptions& options) { options_ = options; }

  // Findings for this update (empty: nothing wrong), most severe first; rates are taken over the
  // time since the previous call.
  std::vector<HealthFinding> update(const InputSample& sample);
  // Refusals per second between the last two updates (0 before the second).
  double refusalRate() const { return refusal_rate_; }

 private:
  InputHealthOptions options_;
  std::optional<InputSample> previous_;
  std::deque<std::size_t> queue_lengths_;  // the last kGrowingQueueUpdates + 1 queue lengths
  double refusal_rate_ = 0.0;
};

}  // namespace toro_ros
