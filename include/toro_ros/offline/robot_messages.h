// The messages graph_to_bag writes, built from the graph and its RobotTimeline (graph_to_bag.h).
#pragma once

#include <nav_msgs/Odometry.h>
#include <tf2_msgs/TFMessage.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/offline/graph_to_bag.h"

namespace toro_ros {
namespace offline {

// The same graph with its dense indices in increasing id order (constraints keep their order).
toro::PoseGraph sortedById(const toro::PoseGraph& graph);

// Fills t->step_covariance and t->covariance as an EKF's prediction grows a pose covariance: the
// previous covariance carried to the new pose (carriedCovariance), plus the step's covariance (from
// its information) rotated into the odom frame by the step's end pose (covariance_rules.h).  So the keyframer's
// "difference" (newer - older carried, rotated back into the newer body frame) is exactly the
// step's covariance and recovers the step's information.
void addCovariances(const toro::PoseGraph& graph, RobotTimeline* t);


// Odometry sample `sample` (0 .. last keyframe's sample): the pose interpolated between the two
// keyframes around it, the covariance grown along the chain (carried, plus the current step's
// covariance in proportion), the twist of the current step.
nav_msgs::Odometry odometryAtSample(const RobotTimeline& t, long sample, const GraphToBagOptions& o);
tf2_msgs::TFMessage tfFromOdometry(const nav_msgs::Odometry& odom);

// The loop-closure message of constraint `c`; `publish_time` receives when the robot reaches the
// later of its two poses plus the latency.
LoopClosure loopClosureMessage(const toro::PoseGraph& graph, const RobotTimeline& t, std::size_t c,
                               const GraphToBagOptions& o, ros::Time* publish_time);

// Writes the bag (odometry, tf, loop closures).  Throws std::runtime_error naming the bag.
void writeRobotBag(const toro::PoseGraph& graph, const RobotTimeline& t, const GraphToBagOptions& o,
                   GraphToBagResult* result);

}  // namespace offline
}  // namespace toro_ros
