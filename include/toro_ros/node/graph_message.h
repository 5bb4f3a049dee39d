// The node's machine-readable outputs, made from the pipeline's state (no publishing here, no
// master needed: test/node/test_graph_message.cpp): the whole graph as toro_ros/PoseGraph and the
// robot's corrected pose at the odometry rate.
#pragma once

#include <string>

#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Odometry.h>

#include "toro_ros/PoseGraph.h"
#include "toro_ros/pipeline/pipeline.h"
#include "toro_ros/pipeline/snapshot.h"

namespace toro_ros {

// The graph as it is now.  `snapshot` must have been made from `pipeline` with nothing in between
// (PipelineWorker::SnapshotObserver guarantees it): its edges give each constraint's loop-closure
// flag and robust weight, the pipeline the measurements, information and odometry poses.
// Rejected loop closures follow the graph's constraints (type REJECTED_LOOP_CLOSURE).
PoseGraph graphMessage(const Pipeline& pipeline, const Snapshot& snapshot, const std::string& map_frame);

// map_T_base = map_T_odom * odom_T_base for one odometry message, stamped as the message, in
// `map_frame`.  The covariance is the message's pose covariance rotated into the map frame
// (blockdiag(R, R) Sigma blockdiag(R, R)^T with R the rotation of map_T_odom): the odometry
// source's uncertainty, without the uncertainty of map_T_odom itself (TORO computes no marginal
// covariances).  `planar` (the pipeline's planar mode): the odometry pose is projected onto the
// plane first, so the result is planar (its covariance's z, roll, pitch rows stay as sent).
geometry_msgs::PoseWithCovarianceStamped correctedPose(const toro::Pose3& map_T_odom,
                                                       const nav_msgs::Odometry& odom,
                                                       const std::string& map_frame, bool planar = false);

}  // namespace toro_ros
