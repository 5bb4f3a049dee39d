#include "toro_ros/offline/robot_messages.h"

#include <algorithm>
#include <stdexcept>

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>

#include "toro_ros/pipeline/covariance_conversion.h"

namespace toro_ros {
namespace offline {

namespace {

// Block-diagonal rotation acting on a (translation, rotation) 6-vector.
toro::Matrix6 blockRotation(const toro::Pose3& pose) {
  toro::Matrix6 b = toro::Matrix6::Zero();
  b.block<3, 3>(0, 0) = pose.rotationMatrix();
  b.block<3, 3>(3, 3) = pose.rotationMatrix();
  return b;
}

}  // namespace

void addCovariances(const toro::PoseGraph& graph, RobotTimeline* t) {
  t->covariance.assign(1, toro::Matrix6::Zero());
  t->step_covariance.clear();
  for (std::size_t k = 0; k + 1 < t->ids.size(); ++k) {
    const toro::Constraint& c = graph.constraints()[t->odometry_constraint[k]];
    toro::Matrix6 covariance = covarianceFromInformation(c.information);
    if (t->odometry_reversed[k]) {
      // With S the forward step and Z = S^-1 the reverse constraint's measurement, the reverse
      // error Z^-1 Xj^-1 Xi is S (S^-1 Xi^-1 Xj)^-1 S^-1: to first order -Ad(S) times the forward
      // error.  So the forward covariance is Ad(Z) Sigma Ad(Z)^T ((translation, rotation) order,
      // rotation in rad; Ad(X) = [R, [p]x R; 0, R] for X = (R, p)).
      const toro::Pose3& s = c.measurement;
      toro::Matrix6 ad = toro::Matrix6::Zero();
      const toro::Matrix3 r = s.rotationMatrix();
      toro::Matrix3 p_cross;
      p_cross << 0, -s.translation().z(), s.translation().y(), s.translation().z(), 0, -s.translation().x(),
          -s.translation().y(), s.translation().x(), 0;
      ad.block<3, 3>(0, 0) = r;
      ad.block<3, 3>(0, 3) = p_cross * r;
      ad.block<3, 3>(3, 3) = r;
      covariance = ad * covariance * ad.transpose();
    }
    t->step_covariance.push_back(covariance);
    const toro::Matrix6 b = blockRotation(t->odom_T_base[k + 1]);
    const toro::Vector3 displacement = t->odom_T_base[k + 1].translation() - t->odom_T_base[k].translation();
    t->covariance.push_back(carriedCovariance(t->covariance.back(), displacement) +
                            b * t->step_covariance.back() * b.transpose());
  }
}

toro::PoseGraph sortedById(const toro::PoseGraph& graph) {
  std::vector<toro::Node> nodes = graph.nodes();
  std::sort(nodes.begin(), nodes.end(), [](const toro::Node& a, const toro::Node& b) { return a.id < b.id; });
  toro::PoseGraph out;
  out.setDimension(graph.dimension());
  for (const toro::Node& n : nodes) out.addNode(n.id, n.pose);
  for (const toro::Constraint& c : graph.constraints()) out.addConstraint(c);
  for (toro::NodeId id : graph.fixedNodes()) out.addFixed(id);
  return out;
}

nav_msgs::Odometry odometryAtSample(const RobotTimeline& t, long sample, const GraphToBagOptions& o) {
  // Keyframe k is the last one at or before the sample.
  const auto it = std::upper_bound(t.sample_of_keyframe.begin(), t.sample_of_keyframe.end(), sample);
  const std::size_t k = static_cast<std::size_t>(std::distance(t.sample_of_keyframe.begin(), it)) - 1;
  nav_msgs::Odometry msg;
  msg.header.stamp = t.stampOfSample(sample);
  msg.header.frame_id = o.odom_frame;
  msg.child_frame_id = o.base_frame;
  toro::Pose3 pose = t.odom_T_base[k];
  toro::Matrix6 covariance = t.covariance[k];
  if (k + 1 < t.ids.size()) {
    const long n = t.sample_of_keyframe[k + 1] - t.sample_of_keyframe[k];
    const double f = static_cast<double>(sample - t.sample_of_keyframe[k]) / static_cast<double>(n);
    if (f > 0) {
      // The step's covariance accrues at a constant rate, each part as it will stand at the step's
      // end (rotated by the end pose, carried back from the end position): an EKF's prediction then
      // carries one sample's covariance into the next plus a positive semi-definite growth (the
      // keyframer's "difference" rule reads exactly that), also across a turn on the spot, and the
      // step's end gets the step's covariance exactly.  (Added as it stands at the end but not carried
      // back, the growth between two samples is indefinite: f_j Q - f_i C Q C^T.)
      pose = toro::slerp(t.odom_T_base[k], t.odom_T_base[k + 1], f);
      const toro::Matrix6 b = blockRotation(t.odom_T_base[k + 1]);
      const toro::Matrix6 accrued = carriedCovariance(
          b * t.step_covariance[k] * b.transpose(), pose.translation() - t.odom_T_base[k + 1].translation());
      covariance =
          carriedCovariance(covariance, pose.translation() - t.odom_T_base[k].translation()) + f * accrued;
    }
    // Body-frame velocity of the current step (constant over the step).
    const toro::Pose3 step = toro::relativePose(t.odom_T_base[k], t.odom_T_base[k + 1]);
    const double sec = n * t.sample_period.toSec();
    const toro::Vector3 v = step.translation() / sec,
                        w = toro::rotationVectorFromQuaternion(step.rotation()) / sec;
    msg.twist.twist.linear.x = v.x(), msg.twist.twist.linear.y = v.y(), msg.twist.twist.linear.z = v.z();
    msg.twist.twist.angular.x = w.x(), msg.twist.twist.angular.y = w.y(), msg.twist.twist.angular.z = w.z();
  }
  msg.pose.pose = poseToMsg(pose);
  msg.pose.covariance = covarianceToMsg(covariance);
  return msg;
}

tf2_msgs::TFMessage tfFromOdometry(const nav_msgs::Odometry& odom) {
  geometry_msgs::TransformStamped t;
  t.header = odom.header;
  t.child_frame_id = odom.child_frame_id;
  t.transform.translation.x = odom.pose.pose.position.x;
  t.transform.translation.y = odom.pose.pose.position.y;
  t.transform.translation.z = odom.pose.pose.position.z;
  t.transform.rotation = odom.pose.pose.orientation;
  tf2_msgs::TFMessage msg;
  msg.transforms.push_back(t);
  return msg;
}

LoopClosure loopClosureMessage(const toro::PoseGraph& graph, const RobotTimeline& t, std::size_t c,
                               const GraphToBagOptions& o, ros::Time* publish_time) {
  const toro::Constraint& k = graph.constraints()[c];
  LoopClosure msg;
  msg.stamp_from = t.stampOfKeyframe(graph.indexOf(k.from));
  msg.stamp_to = t.stampOfKeyframe(graph.indexOf(k.to));
  msg.id_from = msg.id_to = -1;  // named by stamp, as a place recogniser would
  msg.from_T_to = poseToMsg(k.measurement);
  msg.covariance = covarianceToMsg(covarianceFromInformation(k.information));
  *publish_time = std::max(msg.stamp_from, msg.stamp_to) + ros::Duration(o.loop_closure_latency_sec);
  msg.header.stamp = *publish_time;
  msg.header.frame_id = o.odom_frame;
  return msg;
}

void writeRobotBag(const toro::PoseGraph& graph, const RobotTimeline& t, const GraphToBagOptions& o,
                   GraphToBagResult* result) {
  // Loop closures by publication time, merged into the odometry stream so that the bag is written
  // in time order (as a recording is; readers then stay within one chunk at a time).
  std::vector<std::pair<ros::Time, LoopClosure>> closures;
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    if (!t.is_loop_closure[c]) continue;
    ros::Time when;
    LoopClosure msg = loopClosureMessage(graph, t, c, o, &when);
    closures.emplace_back(when, std::move(msg));
  }
  std::stable_sort(closures.begin(), closures.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  try {
    rosbag::Bag bag(o.output_bag, rosbag::bagmode::Write);
    auto next = closures.begin();
    const long last = t.sample_of_keyframe.back();
    for (long s = 0; s <= last; ++s) {
      const nav_msgs::Odometry odom = odometryAtSample(t, s, o);
      for (; next != closures.end() && next->first < odom.header.stamp; ++next)
        bag.write(o.loop_closure_topic, next->first, next->second);
      bag.write(o.odom_topic, odom.header.stamp, odom);
      bag.write(o.tf_topic, odom.header.stamp, tfFromOdometry(odom));
      ++result->odometry_messages;
    }
    for (; next != closures.end(); ++next) bag.write(o.loop_closure_topic, next->first, next->second);
    bag.close();
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(o.output_bag + ": cannot write the bag: " + e.what());
  }
  result->loop_closures = closures.size();
  result->keyframes = t.ids.size();
  result->duration_sec = (t.stampOfSample(t.sample_of_keyframe.back()) - t.start).toSec();
  result->written.insert(result->written.begin(), o.output_bag);
}

}  // namespace offline
}  // namespace toro_ros
