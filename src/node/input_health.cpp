#include "toro_ros/node/input_health.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

#include <diagnostic_msgs/DiagnosticStatus.h>

namespace toro_ros {

namespace {

using diagnostic_msgs::DiagnosticStatus;

std::string seconds(double s) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(1) << s << " s";
  return out.str();
}

// The refusal reason that grew most since `before` ("" when none grew).  Keys that count
// messages used with default covariances are not refusals and are left out.
std::string topReason(const PipelineCounters& now, const PipelineCounters* before,
                      const std::string& prefix) {
  std::string best;
  std::uint64_t most = 0;
  for (const auto& [reason, count] : now.refused_by_reason) {
    if (reason.rfind(prefix, 0) != 0 || reason.find("default used") != std::string::npos) continue;
    std::uint64_t earlier = 0;
    if (before != nullptr) {
      const auto it = before->refused_by_reason.find(reason);
      if (it != before->refused_by_reason.end()) earlier = it->second;
    }
    if (count - earlier > most) {
      most = count - earlier;
      best = reason;
    }
  }
  return best.empty() ? "" : " (mostly '" + best + "')";
}

}  // namespace

std::string InputHealthOptions::validate() const {
  if (!(std::isfinite(stale_odometry_sec) && stale_odometry_sec >= 0))
    return "diagnostics_stale_odometry_sec must be >= 0";
  if (!(std::isfinite(max_refusals_per_sec) && max_refusals_per_sec > 0))
    return "diagnostics_max_refusals_per_sec must be > 0";
  return "";
}

std::vector<HealthFinding> InputHealth::update(const InputSample& s) {
  std::vector<HealthFinding> found;
  const PipelineCounters& c = s.counters;
  const PipelineCounters* before = previous_ ? &previous_->counters : nullptr;

  // Odometry arrives and none of it enters the graph: the map cannot follow the robot.
  if (c.odometry_messages > 0 && c.odometry_refused == c.odometry_messages) {
    found.push_back({DiagnosticStatus::ERROR, "all " + std::to_string(c.odometry_messages) + " of " +
                                                  std::to_string(c.odometry_messages) +
                                                  " odometry messages refused" +
                                                  topReason(c, nullptr, "odometry: ")});
  } else if (before != nullptr && c.odometry_messages > before->odometry_messages &&
             c.odometry_refused - before->odometry_refused ==
                 c.odometry_messages - before->odometry_messages) {
    const std::uint64_t n = c.odometry_messages - before->odometry_messages;
    found.push_back({DiagnosticStatus::ERROR, "all " + std::to_string(n) + " odometry messages of the last " +
                                                  seconds(s.now_sec - previous_->now_sec) + " refused" +
                                                  topReason(c, before, "odometry: ")});
  }

  if (options_.stale_odometry_sec > 0) {
    if (s.last_odometry_sec && s.now_sec - *s.last_odometry_sec > options_.stale_odometry_sec)
      found.push_back(
          {DiagnosticStatus::WARN, "no odometry for " + seconds(s.now_sec - *s.last_odometry_sec)});
    else if (!s.last_odometry_sec && s.now_sec - s.start_sec > options_.stale_odometry_sec)
      found.push_back({DiagnosticStatus::WARN, "no odometry received in the " +
                                                   seconds(s.now_sec - s.start_sec) + " since the start"});
  }

  refusal_rate_ = 0.0;
  if (before != nullptr && s.now_sec > previous_->now_sec) {
    const std::uint64_t refused = (c.odometry_refused + c.loop_closures_refused) -
                                  (before->odometry_refused + before->loop_closures_refused);
    refusal_rate_ = static_cast<double>(refused) / (s.now_sec - previous_->now_sec);
    if (refusal_rate_ > options_.max_refusals_per_sec) {
      std::ostringstream m;
      m << std::setprecision(3) << refusal_rate_ << " refusals/s over the last "
        << seconds(s.now_sec - previous_->now_sec) << " (more than " << options_.max_refusals_per_sec << "/s)"
        << topReason(c, before, "");
      found.push_back({DiagnosticStatus::WARN, m.str()});
    }
  }

  // Loop closures come but none was ever applied: the map is never corrected.
  if (c.loop_closures_received > 0 && c.loop_closures_applied == 0 &&
      c.loop_closures_refused == c.loop_closures_received)
    found.push_back({DiagnosticStatus::WARN, "none of the " + std::to_string(c.loop_closures_received) +
                                                 " loop closures received was applied" +
                                                 topReason(c, nullptr, "loop closure: ")});

  queue_lengths_.push_back(s.queue_length);
  if (queue_lengths_.size() > kGrowingQueueUpdates + 1) queue_lengths_.pop_front();
  if (queue_lengths_.size() == kGrowingQueueUpdates + 1 && s.queue_length >= kGrowingQueueMin &&
      std::adjacent_find(queue_lengths_.begin(), queue_lengths_.end(), std::greater_equal<std::size_t>()) ==
          queue_lengths_.end()) {
    std::string lengths;
    for (std::size_t n : queue_lengths_) lengths += (lengths.empty() ? "" : " -> ") + std::to_string(n);
    found.push_back(
        {DiagnosticStatus::WARN, "input queue growing (" + lengths + " messages): the worker falls behind"});
  }

  std::stable_sort(found.begin(), found.end(),
                   [](const HealthFinding& a, const HealthFinding& b) { return a.level > b.level; });
  previous_ = s;
  return found;
}

}  // namespace toro_ros
