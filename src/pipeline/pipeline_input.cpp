// Pipeline: where a loop closure's stamps are on the odometry, and how the covariances of the
// input were read (counted per rule, said once in the log).
#include <algorithm>
#include <cmath>

#include "toro_ros/core/carried_measurement.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

namespace {

// Loop-closure axis readings logged at most this many distinct times (one sender has one or two).
constexpr std::size_t kMaxLoggedLoopClosureReadings = 4;

}  // namespace

std::optional<toro::Pose3> Pipeline::odometryPoseAt(const ros::Time& stamp) const {
  if (const auto pose = odometry_history_.at(stamp)) return pose;
  if (const auto pose = keyframes_.odometryAt(stamp)) return pose;
  // Between the newest keyframe and the newest odometry (the history may be off or shorter).
  if (keyframes_.empty() || !last_odometry_ || next_keyframe_after_gap_) return std::nullopt;
  const KeyframeRecord& newest = keyframes_.newest();
  if (stamp <= newest.stamp || stamp > last_odometry_->stamp) return std::nullopt;
  const double fraction = (stamp - newest.stamp).toSec() / (last_odometry_->stamp - newest.stamp).toSec();
  return toro::slerp(newest.odom_T_base, last_odometry_->odom_T_base, fraction);
}

toro::Pose3 Pipeline::keyframeToStamp(toro::NodeId keyframe, const ros::Time& stamp) const {
  const KeyframeRecord* k = keyframes_.find(keyframe);
  const std::optional<toro::Pose3> odom_T_stamp = odometryPoseAt(stamp);
  // Not on the odometry: a stamp just before the first keyframe or across a restart, attached
  // within the tolerance as it is.
  if (k == nullptr || !odom_T_stamp) return toro::Pose3();
  return toro::relativePose(k->odom_T_base, *odom_T_stamp);
}

toro::Matrix6 Pipeline::keyframeToStampCovariance(toro::NodeId keyframe, const ros::Time& stamp,
                                                  const toro::Pose3& keyframe_T_stamp) {
  const KeyframeRecord* k = keyframes_.find(keyframe);
  if (k == nullptr || stamp == k->stamp) return toro::Matrix6::Zero();
  // The odometry step the offset lies on: towards the neighbour on the stamp's side; past the
  // newest keyframe (or before the first), the step on the other side, the nearest sample of the
  // odometry's noise there is.
  const bool after = stamp > k->stamp;
  const std::optional<toro::NodeId> towards =
      after ? keyframes_.next(keyframe) : keyframes_.previous(keyframe);
  const std::optional<toro::NodeId> neighbour = towards ? towards
                                                : after ? keyframes_.previous(keyframe)
                                                        : keyframes_.next(keyframe);
  const KeyframeRecord* n = neighbour ? keyframes_.find(*neighbour) : nullptr;
  if (n == nullptr || n->stamp == k->stamp) return toro::Matrix6::Zero();
  const std::optional<toro::Matrix6> step = map_.odometryInformation(keyframe, n->id);
  if (!step) return toro::Matrix6::Zero();
  // The odometry's noise grows with the motion (a random walk): the part of the step's covariance
  // the offset's share of its time is.
  const double fraction = std::abs((stamp - k->stamp).toSec()) / std::abs((n->stamp - k->stamp).toSec());
  const toro::Matrix6 covariance =
      fraction *
      toro::measuredCovariance(toro::quaternionToAngleUnits(*step), options_.keyframer.unmeasured_variance);
  if (after) return covariance;
  // Measured from the stamp to the keyframe: (X exp(e))^-1 = X^-1 exp(-Ad(X) e), X = stamp_T_keyframe.
  const toro::Matrix6 ad = toro::adjoint(keyframe_T_stamp.inverse());
  return ad * covariance * ad.transpose();
}

void Pipeline::countOdometryStep(const InformationResult& information) {
  const bool configured_default = options_.keyframer.covariance_mode == OdometryCovarianceMode::kDefault;
  if (!configured_default) {  // defaults that were asked for are no fallback
    if (information.used_default)
      ++counters_.odometry_steps_default;
    else if (information.default_axes > 0)
      ++counters_.odometry_steps_partly_default;
  }
  if (information.repaired) ++counters_.odometry_steps_repaired;
  const std::string key = toString(keyframer_.effectiveMode());
  if (key == logged_odometry_rule_) return;
  const bool changed = !logged_odometry_rule_.empty();
  logged_odometry_rule_ = key;
  const std::string line = std::string("odometry covariance ") + (changed ? "rule changed: " : "rule: ") +
                           keyframer_.ruleDescription();
  // Defaults on every axis, or a source that changed its convention, deserve a warning.
  if (((information.used_default && !configured_default) || changed) && warn_)
    warn_(line);
  else if (info_)
    info_(line);
}

void Pipeline::countLoopClosureInformation(const InformationResult& information) {
  if (information.used_default)
    ++counters_.loop_closures_default;
  else if (information.default_axes > 0)
    ++counters_.loop_closures_partly_default;
  if (information.repaired) ++counters_.loop_closures_repaired;
  loop_closure_rule_ = describeAxes(information.axes, options_.loop_closure_unmeasured_variance);
  if (information.repaired) loop_closure_rule_ += "; " + information.reason;
  const auto& logged = logged_loop_closure_axes_;
  if (logged.size() >= kMaxLoggedLoopClosureReadings ||
      std::find(logged.begin(), logged.end(), information.axes) != logged.end())
    return;
  logged_loop_closure_axes_.push_back(information.axes);
  const std::string line =
      "loop closure covariance: " + loop_closure_rule_ +
      (logged.size() == kMaxLoggedLoopClosureReadings ? " (further readings not logged)" : "");
  if (information.default_axes > 0 && warn_)
    warn_(line);
  else if (info_)
    info_(line);
}

}  // namespace toro_ros
