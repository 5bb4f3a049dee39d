#include "toro_ros/pipeline/keyframer.h"

#include <cmath>

namespace toro_ros {

namespace {

// A variance difference smaller than this fraction of the variances is rounding, not growth.
constexpr double kGrowthTolerance = 1e-9;

// nav_msgs/Odometry gives the pose covariance in the odom frame; the core's error of a constraint
// lives in the frame of its `to` node.  Information rotates as covariance does (the rotation is
// orthogonal and acts alike on both blocks, so it commutes with the quaternion-unit scaling).
toro::Matrix6 toBodyFrame(const toro::Matrix6& odom_information, const toro::Pose3& odom_T_base) {
  toro::Matrix6 b = toro::Matrix6::Zero();
  const toro::Matrix3 base_R_odom = odom_T_base.rotationMatrix().transpose();
  b.block<3, 3>(0, 0) = base_R_odom;
  b.block<3, 3>(3, 3) = base_R_odom;
  toro::Matrix6 out = b * odom_information * b.transpose();
  return 0.5 * (out + out.transpose());
}

bool sameCovariance(const toro::Matrix6& a, const toro::Matrix6& b) {
  for (int i = 0; i < 36; ++i) {
    const double x = a(i / 6, i % 6), y = b(i / 6, i % 6);
    if (!(x == y || (std::isnan(x) && std::isnan(y)))) return false;
  }
  return true;
}

// Whether the sender marks an axis unmeasured: a variance at or above the threshold that the step left
// as it was (diff_drive_controller's 1e6, an EKF's infinite z).  A large variance that changed without
// growing is dead reckoning's accumulated one, shrunk by a fix or by the EKF's correlations: the step's
// own variance is then unknown (the defaults), not unmeasured.  Reading it unmeasured would leave one
// odometry step free along that axis, and the map's exact finish undetermined for good.
bool pinnedUnmeasured(AxisReading older, AxisReading newer, double older_variance, double newer_variance,
                      double scale) {
  if (older != AxisReading::kUnmeasured || newer != AxisReading::kUnmeasured) return false;
  if (!std::isfinite(newer_variance)) return true;   // infinite now: the sender says so
  if (!std::isfinite(older_variance)) return false;  // finite after infinite: it changed
  return std::abs(newer_variance - older_variance) <= kGrowthTolerance * scale;
}

// kDifference: the growth of the covariance over the step, covariance(newer) - F covariance(older)
// F^T with F carrying the older one to the newer pose (carriedCovariance: an EKF's prediction; the
// plain difference of a real EKF's covariances is indefinite in most steps, because a heading
// error before the step moves the newer position sideways), read on the axes where it is meaningful.  An axis
// that grew is read from its growth, however large the accumulated variance (dead reckoning's grows without
// bound).  One that did not grow says nothing about the step: unmeasured if the sender marks it so (a
// variance >= the threshold that the step left as it was, e.g. pinned at 1e6: pinnedUnmeasured), else
// unknown and the default (an EKF's two_d_mode z, roll and pitch held at 1e-6 or 0; a variance, however
// large, that an absolute fix or the EKF's correlations shrank).
InformationResult differenceInformation(const toro::Matrix6& older, const toro::Matrix6& newer,
                                        const toro::Vector3& displacement, const KeyframerOptions& o) {
  // The older covariance carried to the newer pose first, as an EKF's prediction carries it, so
  // the heading uncertainty accumulated before the step does not count as the step's.
  const toro::Matrix6 carried = older.allFinite() ? carriedCovariance(older, displacement) : older;
  toro::Matrix6 difference = newer - carried;
  const AxisReadings read_newer = readAxes(newer, o.unmeasured_variance);
  const AxisReadings read_older = readAxes(older, o.unmeasured_variance);
  AxisReadings axes;
  for (int i = 0; i < 6; ++i) {
    const double grew = difference(i, i);
    const double scale = std::max(std::abs(newer(i, i)), std::abs(older(i, i)));
    if (std::isfinite(grew) && grew > kGrowthTolerance * scale) {
      axes[i] = grew >= o.unmeasured_variance ? AxisReading::kUnmeasured : AxisReading::kMeasured;
    } else if (pinnedUnmeasured(read_older[i], read_newer[i], older(i, i), newer(i, i), scale)) {
      axes[i] = AxisReading::kUnmeasured;
      difference(i, i) = std::max(newer(i, i), older(i, i));  // the variance the sender gave
    } else {
      axes[i] = AxisReading::kUnknown;
    }
  }
  return informationFromAxes(difference, axes, o.default_stddev);
}

// kMotionScaled: the message's covariance is per metre and radian of motion.
InformationResult motionScaledInformation(const OdometrySample& older, const OdometrySample& newer,
                                          const KeyframerOptions& o) {
  const toro::Pose3 step = toro::relativePose(older.odom_T_base, newer.odom_T_base);
  const double motion = std::max(kMinMotionScale, step.translation().norm() + step.angle());
  const AxisReadings axes = readAxes(newer.covariance, o.unmeasured_variance);
  toro::Matrix6 scaled = motion * newer.covariance;
  // An unmeasured axis keeps the variance the sender gave: it is ~0 information either way.
  for (int i = 0; i < 6; ++i)
    if (axes[i] == AxisReading::kUnmeasured) scaled(i, i) = newer.covariance(i, i);
  return informationFromAxes(scaled, axes, o.default_stddev);
}

}  // namespace

std::optional<OdometryCovarianceMode> odometryCovarianceModeFromString(const std::string& s) {
  if (s == "auto") return OdometryCovarianceMode::kAuto;
  if (s == "difference") return OdometryCovarianceMode::kDifference;
  if (s == "motion_scaled") return OdometryCovarianceMode::kMotionScaled;
  if (s == "latest") return OdometryCovarianceMode::kLatest;
  if (s == "default") return OdometryCovarianceMode::kDefault;
  return std::nullopt;
}

std::string toString(OdometryCovarianceMode mode) {
  switch (mode) {
    case OdometryCovarianceMode::kAuto:
      return "auto";
    case OdometryCovarianceMode::kDifference:
      return "difference";
    case OdometryCovarianceMode::kMotionScaled:
      return "motion_scaled";
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
  if (!(std::isfinite(unmeasured_variance) && unmeasured_variance > 0))
    return "odometry unmeasured_variance must be > 0";
  return default_stddev.validate();
}

void Keyframer::observe(const OdometrySample& sample) {
  if (previous_covariance_) {
    if (!sameCovariance(*previous_covariance_, sample.covariance))
      convention_ = OdometryCovarianceConvention::kGrowing;
    else if (convention_ == OdometryCovarianceConvention::kUndetermined)
      convention_ = OdometryCovarianceConvention::kConstant;
  }
  previous_covariance_ = sample.covariance;
}

void Keyframer::setLast(const OdometrySample& sample) {
  last_ = sample;
  previous_covariance_.reset();
  convention_ = OdometryCovarianceConvention::kUndetermined;
}

void Keyframer::reset() {
  last_.reset();
  previous_covariance_.reset();
  convention_ = OdometryCovarianceConvention::kUndetermined;
  last_step_axes_.reset();
}

bool Keyframer::isKeyframe(const OdometrySample& sample) const {
  if (!last_) return true;
  const toro::Pose3 step = toro::relativePose(last_->odom_T_base, sample.odom_T_base);
  if (step.translation().norm() > options_.distance_m) return true;
  if (step.angle() > options_.angle_rad) return true;
  return options_.interval_sec > 0 && (sample.stamp - last_->stamp).toSec() >= options_.interval_sec;
}

OdometryCovarianceMode Keyframer::effectiveMode() const {
  if (options_.covariance_mode != OdometryCovarianceMode::kAuto) return options_.covariance_mode;
  switch (convention_) {
    case OdometryCovarianceConvention::kGrowing:
      return OdometryCovarianceMode::kDifference;
    case OdometryCovarianceConvention::kConstant:
      return OdometryCovarianceMode::kMotionScaled;
    case OdometryCovarianceConvention::kUndetermined:
      break;
  }
  return OdometryCovarianceMode::kDefault;
}

std::string Keyframer::ruleDescription() const {
  std::string out = toString(options_.covariance_mode);
  const OdometryCovarianceMode mode = effectiveMode();
  if (options_.covariance_mode == OdometryCovarianceMode::kAuto) {
    switch (convention_) {
      case OdometryCovarianceConvention::kGrowing:
        out += ": the covariance changes between messages (EKF / dead reckoning)";
        break;
      case OdometryCovarianceConvention::kConstant:
        out += ": the covariance is the same in every message (e.g. diff_drive_controller)";
        break;
      case OdometryCovarianceConvention::kUndetermined:
        out += ": too few messages to tell the covariance convention yet";
        break;
    }
  }
  switch (mode) {
    case OdometryCovarianceMode::kDifference:
      out +=
          " -> step covariance = covariance(newer) - covariance(older) carried to the newer pose, on the "
          "axes "
          "that grew";
      break;
    case OdometryCovarianceMode::kMotionScaled:
      out += " -> step covariance = message covariance x (metres + radians moved)";
      break;
    case OdometryCovarianceMode::kLatest:
      out += " -> step covariance = covariance(newer)";
      break;
    case OdometryCovarianceMode::kDefault:
      out += " -> step covariance = the defaults";
      break;
    case OdometryCovarianceMode::kAuto:
      break;
  }
  if (last_step_axes_ && mode != OdometryCovarianceMode::kDefault)
    out += "; last step: " + describeAxes(*last_step_axes_, options_.unmeasured_variance);
  return out;
}

InformationResult Keyframer::stepInformation(const OdometrySample& older_sample,
                                             const OdometrySample& newer_sample) const {
  // Planar mode reads only the x, y, yaw rows: whatever a sender puts on z, roll and pitch (0, 1e6,
  // correlations) then neither makes a step unusable nor leaks into the plane.
  OdometrySample older = older_sample;
  OdometrySample newer = newer_sample;
  if (options_.planar) {
    older.covariance = planarCovariance(older.covariance);
    newer.covariance = planarCovariance(newer.covariance);
  }
  InformationResult out;
  switch (effectiveMode()) {
    case OdometryCovarianceMode::kDifference:
      // A reference from a loaded graph has a NaN covariance (it is not saved): its axes are
      // unknown, so the step takes the defaults there.
      out =
          differenceInformation(older.covariance, newer.covariance,
                                newer.odom_T_base.translation() - older.odom_T_base.translation(), options_);
      out.information = toBodyFrame(out.information, newer.odom_T_base);
      return out;
    case OdometryCovarianceMode::kMotionScaled:
      out = motionScaledInformation(older, newer, options_);
      out.information = toBodyFrame(out.information, newer.odom_T_base);
      return out;
    case OdometryCovarianceMode::kLatest:
      out =
          informationFromCovariance(newer.covariance, options_.default_stddev, options_.unmeasured_variance);
      out.information = toBodyFrame(out.information, newer.odom_T_base);
      return out;
    case OdometryCovarianceMode::kDefault:
    case OdometryCovarianceMode::kAuto:
      break;
  }
  out.information = defaultInformation(options_.default_stddev);
  out.default_axes = 6;
  out.used_default = true;
  out.reason = "the defaults";
  return out;
}

std::optional<OdometryStep> Keyframer::accept(const OdometrySample& sample) {
  std::optional<OdometryStep> step;
  if (last_) {
    step = OdometryStep{toro::relativePose(last_->odom_T_base, sample.odom_T_base),
                        stepInformation(*last_, sample)};
    last_step_axes_ = step->information.axes;
  }
  last_ = sample;
  return step;
}

}  // namespace toro_ros
