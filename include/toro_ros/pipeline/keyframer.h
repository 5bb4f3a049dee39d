// Keyframe selection: which odometry messages become graph nodes, and the odometry constraint
// between consecutive keyframes.
#pragma once

#include <optional>
#include <string>

#include <ros/time.h>

#include "toro_ros/core/pose3.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

// How the information of an odometry constraint is derived from the two odometry covariances.
enum class OdometryCovarianceMode {
  kDifference,  // covariance(newer) - covariance(older): dead reckoning whose covariance grows
  kLatest,      // covariance(newer) as the covariance of the step: sources with a per-step covariance
  kDefault,     // always the configured defaults
};
// "difference" | "latest" | "default"; nullopt for anything else.
std::optional<OdometryCovarianceMode> odometryCovarianceModeFromString(const std::string& s);
std::string toString(OdometryCovarianceMode mode);

struct KeyframerOptions {
  double distance_m = 0.5;     // new keyframe when moved farther than this since the last one
  double angle_rad = 0.35;     // ... or turned more than this
  double interval_sec = 10.0;  // ... or this much time passed (0 = never by time)
  OdometryCovarianceMode covariance_mode = OdometryCovarianceMode::kDifference;
  DefaultStddev default_stddev;  // when the covariance is zero or unusable
  // Read only the x, y, yaw rows of the covariances (planarCovariance); the pipeline sets it from
  // PipelineOptions::planar.
  bool planar = false;
  std::string validate() const;
};

// An odometry sample: stamp, odom_T_base and its covariance (geometry_msgs order).
struct OdometrySample {
  ros::Time stamp;
  toro::Pose3 odom_T_base;
  toro::Matrix6 covariance = toro::Matrix6::Zero();
};

struct OdometryStep {
  toro::Pose3 previous_T_current;  // relative odometry between the two keyframes
  InformationResult information;
};

class Keyframer {
 public:
  explicit Keyframer(const KeyframerOptions& options) : options_(options) {}

  // True if `sample` should become a keyframe given the last keyframe (always true for the first).
  bool isKeyframe(const OdometrySample& sample) const;
  // Records `sample` as the newest keyframe; returns the step from the previous keyframe
  // (nullopt for the first keyframe).
  std::optional<OdometryStep> accept(const OdometrySample& sample);
  // Makes `sample` the reference without producing a step (after loading a graph).
  void setLast(const OdometrySample& sample) { last_ = sample; }

  const std::optional<OdometrySample>& last() const { return last_; }
  void reset() { last_.reset(); }

 private:
  InformationResult stepInformation(const OdometrySample& older, const OdometrySample& newer) const;

  KeyframerOptions options_;
  std::optional<OdometrySample> last_;
};

}  // namespace toro_ros
