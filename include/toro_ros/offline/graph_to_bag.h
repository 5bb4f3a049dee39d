// graph_to_bag: a pose-graph file (g2o or TORO) turned into a bag that looks like a real robot's:
// nav_msgs/Odometry at a fixed rate, tf odom -> base_link, and the graph's loop closures as
// toro_ros/LoopClosure at the moment the robot reaches the later of their two poses.
//
// Model.  The graph's nodes in id order are the robot's keyframes.  The constraint from node k to
// node k+1 (the first one, if parallel; else one from k+1 to k, inverted) is the odometry step; the odometry
// a robot would report is the chain of those steps composed from the identity (so it drifts as the dataset's
// odometry does), interpolated between keyframes (slerp / lerp).  The pose covariance grows along the chain
// (each step's covariance, from its information, rotated into the odom frame and added), so the
// node (odometry_covariance_mode auto sees a growing covariance and takes the difference) recovers
// each step's information exactly.
// Every other constraint becomes a LoopClosure naming its two poses by their stamps.
//
// Time.  Keyframe k is reached at start_sec + (sum of earlier step durations); a step lasts its
// length / speed_mps (or its angle / angular_speed_radps if longer), or keyframe_period_sec when
// that is > 0, rounded up to whole odometry periods so that every keyframe stamp carries an
// odometry message.  With a constant period the node's keyframes can be made to coincide with the
// graph's (keyframe_interval_sec slightly below the period, distance and angle thresholds off; see
// config/replay_sample.yaml): the node then rebuilds exactly the input graph.
//
// Beside the bag (for scoring): "<stem>.odometry.g2o" (the input's constraints, poses = the
// odometry chain) with its "<stem>.odometry.g2o.stamps" sidecar (persistence.h: the stamp and
// odometry pose of each node, which constraints are loop closures), and, where known,
// "<stem>.truth.g2o": the true poses (from a second graph file with the same ids: its vertices,
// e.g. the synthetic sample whose vertices are its ground truth, or, in a file without VERTEX
// lines, the chain of its noise-free consecutive-id measurements, e.g. GTSAM's
// sphere2500_groundtruth.txt) or, if asked, "<stem>.reference.g2o": the
// input optimised by the core's TORO (a reference optimum, not a truth), both expressed in the
// odom frame (first pose = identity).
#pragma once

#include <string>
#include <vector>

#include <ros/time.h>

#include "toro_ros/core/pose_graph.h"

namespace toro_ros {
namespace offline {

struct GraphToBagOptions {
  std::string input_path;                  // graph file (g2o / TORO by extension)
  std::string output_bag;                  // ".bag"
  std::string ground_truth_path;           // optional graph file whose poses are the truth (same ids)
  int reference_iterations = 0;            // > 0 and no ground truth: write the TORO optimum as reference
  double odometry_rate_hz = 20.0;          // odometry and tf messages per second
  double speed_mps = 1.0;                  // nominal speed between keyframes
  double angular_speed_radps = 0.5;        // nominal turn rate (a step lasts at least its angle / this)
  double keyframe_period_sec = 0.0;        // > 0: every step lasts this long (a multiple of the period)
  double start_sec = 1000.0;               // stamp of the first message (a /clock-friendly epoch)
  double loop_closure_latency_sec = 0.02;  // loop closure published this long after its later pose
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  std::string odom_topic = "/odom";
  std::string loop_closure_topic = "/loop_closure";
  std::string tf_topic = "/tf";
  // Empty when usable, else what is wrong (naming the option).
  std::string validate() const;
};

// The timeline and odometry derived from a graph (exposed for tests and the writer).
struct RobotTimeline {
  std::vector<toro::NodeId> ids;                 // keyframes in id order
  std::vector<toro::Pose3> odom_T_base;          // odometry chain per keyframe
  std::vector<std::size_t> odometry_constraint;  // constraint index of step k -> k+1
  std::vector<bool> odometry_reversed;           // ... which goes from k+1 to k (step = its inverse)
  std::vector<bool> is_loop_closure;             // per constraint index
  std::vector<long> sample_of_keyframe;          // odometry sample index of each keyframe
  std::vector<toro::Matrix6> step_covariance;    // of step k -> k+1, in k+1's body frame (msg units)
  std::vector<toro::Matrix6> covariance;         // odom-frame pose covariance at each keyframe
  ros::Duration sample_period;                   // 1 / odometry_rate_hz, in whole nanoseconds
  ros::Time start;
  ros::Time stampOfSample(long sample) const {
    return start + ros::Duration().fromNSec(sample * sample_period.toNSec());
  }
  ros::Time stampOfKeyframe(std::size_t k) const { return stampOfSample(sample_of_keyframe[k]); }
};

// Throws std::runtime_error naming `source` if the graph has no odometry chain (a pair of
// consecutive ids without a constraint between them).
RobotTimeline makeTimeline(const toro::PoseGraph& graph, const GraphToBagOptions& options,
                           const std::string& source);

struct GraphToBagResult {
  std::size_t keyframes = 0;
  std::size_t odometry_messages = 0;
  std::size_t loop_closures = 0;
  double duration_sec = 0.0;
  std::vector<std::string> written;  // files written
};

// Reads, converts and writes everything.  Throws (toro::ParseError "file:line: why",
// std::runtime_error) with a message naming the file on any problem.
GraphToBagResult graphToBag(const GraphToBagOptions& options);

// "<dir>/<stem>" of a bag path ("out/sample.bag" -> "out/sample").
std::string bagStem(const std::string& bag_path);

}  // namespace offline
}  // namespace toro_ros
