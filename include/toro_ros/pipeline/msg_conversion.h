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
#include "toro_ros/pipeline/covariance_rules.h"

namespace toro_ros {

using Covariance6 = boost::array<double, 36>;

toro::Pose3 poseFromMsg(const geometry_msgs::Pose& msg);
geometry_msgs::Pose poseToMsg(const toro::Pose3& pose);
geometry_msgs::Transform transformToMsg(const toro::Pose3& pose);

// covariance_rules.h: informationFromCovariance for a toro::Matrix6; this overload reads the
// message layout (row-major, geometry_msgs order).
InformationResult informationFromCovariance(const Covariance6& covariance, const DefaultStddev& defaults,
                                            double unmeasured_variance = kDefaultUnmeasuredVariance);

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
