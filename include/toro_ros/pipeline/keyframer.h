// Keyframe selection: which odometry messages become graph nodes, and the odometry constraint
// between consecutive keyframes.
#pragma once

#include <optional>
#include <string>

#include <ros/time.h>

#include "toro_ros/core/pose3.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

// How the information of an odometry constraint is derived from the odometry covariances.  Every
// mode reads the covariance axis by axis (covariance_rules.h): huge variances are unmeasured axes
// (information ~0), zero or missing ones unknown (that axis takes the default).
enum class OdometryCovarianceMode {
  // Per source, from what the messages show: kDifference once the covariance has changed between
  // two messages (an EKF or dead reckoning whose covariance grows), kMotionScaled while it is the
  // same in every message (diff_drive_controller publishes its configured pose_covariance_diagonal).
  kAuto,
  kDifference,    // covariance(newer) - covariance(older) carried to the newer pose, where it grew
  kMotionScaled,  // covariance(newer) x the step's motion (m + rad): a per-metre covariance
  kLatest,        // covariance(newer) as the covariance of the step (a per-step covariance)
  kDefault,       // always the configured defaults
};
// "auto" | "difference" | "motion_scaled" | "latest" | "default"; nullopt for anything else.
std::optional<OdometryCovarianceMode> odometryCovarianceModeFromString(const std::string& s);
std::string toString(OdometryCovarianceMode mode);

// What kAuto has seen of the source: nothing yet, the same covariance in every message, or one
// that changed (it stays kGrowing until a reset).
enum class OdometryCovarianceConvention { kUndetermined, kConstant, kGrowing };

// kMotionScaled: the step's covariance is the message's times this much motion: metres travelled
// plus radians turned (odometry error grows with motion, not time: a stopped wheel does not slip),
// at least kMinMotionScale, so a keyframe made while standing still is trusted, not infinitely.
constexpr double kMinMotionScale = 0.01;

struct KeyframerOptions {
  double distance_m = 0.5;     // new keyframe when moved farther than this since the last one
  double angle_rad = 0.35;     // ... or turned more than this
  double interval_sec = 10.0;  // ... or this much time passed (0 = never by time)
  OdometryCovarianceMode covariance_mode = OdometryCovarianceMode::kAuto;
  DefaultStddev default_stddev;  // on axes whose covariance is unknown (zero, not finite)
  double unmeasured_variance = kDefaultUnmeasuredVariance;  // m^2 / rad^2 at or above: unmeasured
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

  // Every odometry message in stamp order, keyframe or not, before isKeyframe/accept: kAuto watches
  // whether the covariance changes from one message to the next.
  void observe(const OdometrySample& sample);
  // True if `sample` should become a keyframe given the last keyframe (always true for the first).
  bool isKeyframe(const OdometrySample& sample) const;
  // Records `sample` as the newest keyframe; returns the step from the previous keyframe
  // (nullopt for the first keyframe).
  std::optional<OdometryStep> accept(const OdometrySample& sample);
  // Makes `sample` the reference without producing a step (after loading a graph); what kAuto saw
  // of the source is forgotten (the new run's odometry may come from another source).
  void setLast(const OdometrySample& sample);

  // New keyframe thresholds (run-time tuning); the reference keyframe and the convention stay.
  void setThresholds(double distance_m, double angle_rad, double interval_sec) {
    options_.distance_m = distance_m;
    options_.angle_rad = angle_rad;
    options_.interval_sec = interval_sec;
  }
  const std::optional<OdometrySample>& last() const { return last_; }
  void reset();

  OdometryCovarianceConvention convention() const { return convention_; }
  // The mode that makes the next step (kAuto resolved by the convention; kDefault while kAuto has
  // seen too little, i.e. right after a load).
  OdometryCovarianceMode effectiveMode() const;
  // One line for the log and ~get_status: the rule in use and how the last step read the axes.
  std::string ruleDescription() const;

 private:
  InformationResult stepInformation(const OdometrySample& older, const OdometrySample& newer) const;

  KeyframerOptions options_;
  std::optional<OdometrySample> last_;
  std::optional<toro::Matrix6> previous_covariance_;  // of the previous message (kAuto)
  OdometryCovarianceConvention convention_ = OdometryCovarianceConvention::kUndetermined;
  std::optional<AxisReadings> last_step_axes_;
};

}  // namespace toro_ros
