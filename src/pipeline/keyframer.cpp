#include "toro_ros/pipeline/keyframer.h"

#include <cmath>

namespace toro_ros {

std::optional<OdometryCovarianceMode> odometryCovarianceModeFromString(const std::string& s) {
  if (s == "difference") return OdometryCovarianceMode::kDifference;
  if (s == "latest") return OdometryCovarianceMode::kLatest;
  if (s == "default") return OdometryCovarianceMode::kDefault;
  return std::nullopt;
}

std::string toString(OdometryCovarianceMode mode) {
  switch (mode) {
    case OdometryCovarianceMode::kDifference:
      return "difference";
    case OdometryCovarianceMode::kLatest:
      return "latest";
    case OdometryCovarianceMode::kDefault:
      return "default";
  }
  return "?";
}

std::string KeyframerOptions::validate() const {
  if (!(std::isfinite(distance_m) && distance_m > 0)) return "keyframe distance_m must be > 0";
  if (!(std::isfinite(angle_rad) && angle_rad > 0)) return "keyframe angle_rad must be > 0";
  if (!(std::isfinite(interval_sec) && interval_sec >= 0)) return "keyframe interval_sec must be >= 0";
  return default_stddev.validate();
}

bool Keyframer::isKeyframe(const OdometrySample& sample) const {
  if (!last_) return true;
  const toro::Pose3 step = toro::relativePose(last_->odom_T_base, sample.odom_T_base);
  if (step.translation().norm() > options_.distance_m) return true;
  if (step.angle() > options_.angle_rad) return true;
  return options_.interval_sec > 0 && (sample.stamp - last_->stamp).toSec() >= options_.interval_sec;
}

namespace {

// nav_msgs/Odometry gives the pose covariance in the odom frame; the core's error of a constraint
// lives in the frame of its `to` node, so rotate both blocks into that frame.
toro::Matrix6 toBodyFrame(const toro::Matrix6& odom_covariance, const toro::Pose3& odom_T_base) {
  toro::Matrix6 b = toro::Matrix6::Zero();
  const toro::Matrix3 base_R_odom = odom_T_base.rotationMatrix().transpose();
  b.block<3, 3>(0, 0) = base_R_odom;
  b.block<3, 3>(3, 3) = base_R_odom;
  return b * odom_covariance * b.transpose();
}

}  // namespace

InformationResult Keyframer::stepInformation(const OdometrySample& older, const OdometrySample& newer) const {
  const auto information = [&](const toro::Matrix6& covariance) {
    return informationFromCovariance(options_.planar ? planarCovariance(covariance) : covariance,
                                     options_.default_stddev);
  };
  switch (options_.covariance_mode) {
    case OdometryCovarianceMode::kDifference:
      return information(toBodyFrame(newer.covariance - older.covariance, newer.odom_T_base));
    case OdometryCovarianceMode::kLatest:
      return information(toBodyFrame(newer.covariance, newer.odom_T_base));
    case OdometryCovarianceMode::kDefault:
      break;
  }
  InformationResult out;
  out.information = defaultInformation(options_.default_stddev);
  return out;
}

std::optional<OdometryStep> Keyframer::accept(const OdometrySample& sample) {
  std::optional<OdometryStep> step;
  if (last_) {
    step = OdometryStep{toro::relativePose(last_->odom_T_base, sample.odom_T_base),
                        stepInformation(*last_, sample)};
  }
  last_ = sample;
  return step;
}

}  // namespace toro_ros
