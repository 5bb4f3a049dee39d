// Conversions between ROS messages and the core's value types, in one place (free functions,
// tested without a master).  Nothing here touches a NodeHandle.
#pragma once

#include <string>

#include <geometry_msgs/Pose.h>
#include <geometry_msgs/Transform.h>
#include <nav_msgs/Odometry.h>
#include <boost/array.hpp>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/core/pose3.h"

namespace toro_ros {

using Covariance6 = boost::array<double, 36>;

toro::Pose3 poseFromMsg(const geometry_msgs::Pose& msg);
geometry_msgs::Pose poseToMsg(const toro::Pose3& pose);
geometry_msgs::Transform transformToMsg(const toro::Pose3& pose);

// Standard deviations used when a message's covariance is unusable.
struct DefaultStddev {
  double translation_m = 0.05;
  double rotation_rad = 0.02;
  std::string validate() const;  // empty when both are finite and > 0
};

// Result of turning a covariance into the core's information matrix.
struct InformationResult {
  toro::Matrix6 information;  // g2o order, rotation block in quaternion-vector units
  bool used_default = false;
  std::string reason;  // why the default was used (empty otherwise)
};

// Diagonal information of the defaults, in the core's units.
toro::Matrix6 defaultInformation(const DefaultStddev& defaults);

// Covariance in geometry_msgs order and units (x y z, rotation about X Y Z in rad, row-major) ->
// the core's information.  The core's rotational error is the quaternion vector part, about half
// the rotation vector, so with J = diag(1,1,1,1/2,1/2,1/2): Omega_q = J^-T Sigma^-1 J^-1, i.e. the
// rotation block times 4 and the translation/rotation cross blocks times 2.  A covariance that is
// all zero, not finite, asymmetric or not positive definite yields the defaults and the reason.
InformationResult informationFromCovariance(const Covariance6& covariance, const DefaultStddev& defaults);
InformationResult informationFromCovariance(const toro::Matrix6& covariance, const DefaultStddev& defaults);

toro::Matrix6 covarianceMatrix(const Covariance6& covariance);

// Planar mode (PipelineOptions::planar).  The pose as the planar pipeline takes it: projected onto
// the plane (x, y, heading; z, roll and pitch dropped).
toro::Pose3 planarPoseFromMsg(const geometry_msgs::Pose& msg);
// A covariance as the planar pipeline reads it: the x, y, yaw rows and columns as given; those of
// z, roll and pitch (whatever a sender puts there: 0, 1e6, correlations) replaced by uncorrelated
// variances of the planar ones' scale, so that only the planar block decides whether the
// covariance is usable, and the planar information is the inverse of that block.
toro::Matrix6 planarCovariance(const toro::Matrix6& covariance);

// Empty if the message can be used, else why not (non-finite pose, zero quaternion, zero stamp).
std::string validateOdometry(const nav_msgs::Odometry& msg);
std::string validateLoopClosure(const LoopClosure& msg);

// "12.345678901" for log messages.
std::string stampString(const ros::Time& stamp);

}  // namespace toro_ros
