#include "toro_ros/pipeline/msg_conversion.h"

#include <cmath>
#include <cstdio>

#include "toro_ros/core/planar.h"
#include "toro_ros/core/pose_graph.h"

namespace toro_ros {

namespace {

bool quaternionUsable(const geometry_msgs::Quaternion& q) {
  const double n2 = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w;
  return std::isfinite(n2) && n2 > 1e-12;
}

bool pointFinite(const geometry_msgs::Point& p) {
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
}

std::string validatePose(const geometry_msgs::Pose& pose) {
  if (!pointFinite(pose.position)) return "position is not finite";
  if (!quaternionUsable(pose.orientation))
    return "orientation is not a usable quaternion (zero or not finite)";
  return "";
}

}  // namespace

toro::Pose3 poseFromMsg(const geometry_msgs::Pose& msg) {
  const auto& q = msg.orientation;
  return toro::Pose3(toro::Quaternion(q.w, q.x, q.y, q.z),
                     toro::Vector3(msg.position.x, msg.position.y, msg.position.z));
}

geometry_msgs::Pose poseToMsg(const toro::Pose3& pose) {
  geometry_msgs::Pose msg;
  msg.position.x = pose.translation().x();
  msg.position.y = pose.translation().y();
  msg.position.z = pose.translation().z();
  msg.orientation.w = pose.rotation().w();
  msg.orientation.x = pose.rotation().x();
  msg.orientation.y = pose.rotation().y();
  msg.orientation.z = pose.rotation().z();
  return msg;
}

geometry_msgs::Transform transformToMsg(const toro::Pose3& pose) {
  const geometry_msgs::Pose p = poseToMsg(pose);
  geometry_msgs::Transform t;
  t.translation.x = p.position.x;
  t.translation.y = p.position.y;
  t.translation.z = p.position.z;
  t.rotation = p.orientation;
  return t;
}

toro::Matrix6 covarianceMatrix(const Covariance6& covariance) {
  toro::Matrix6 m;
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) m(r, c) = covariance[6 * r + c];
  return m;
}

InformationResult informationFromCovariance(const Covariance6& covariance, const DefaultStddev& defaults,
                                            double unmeasured_variance) {
  return informationFromCovariance(covarianceMatrix(covariance), defaults, unmeasured_variance);
}

toro::Pose3 planarPoseFromMsg(const geometry_msgs::Pose& msg) {
  return toro::projectToPlane(poseFromMsg(msg));
}

toro::Matrix6 planarCovariance(const toro::Matrix6& covariance) {
  constexpr int kPlanar[3] = {0, 1, 5};      // x, y, yaw in geometry_msgs order
  constexpr int kOutOfPlane[3] = {2, 3, 4};  // z, roll, pitch
  toro::Matrix6 out = toro::Matrix6::Zero();
  for (int i : kPlanar)
    for (int j : kPlanar) out(i, j) = covariance(i, j);
  // A non-finite planar block stays non-finite (and is refused); an all-zero one stays zero.
  const double scale = (std::abs(out(0, 0)) + std::abs(out(1, 1)) + std::abs(out(5, 5))) / 3.0;
  for (int k : kOutOfPlane) out(k, k) = scale;
  return out;
}

std::string validateOdometry(const nav_msgs::Odometry& msg) {
  if (msg.header.stamp.isZero()) return "stamp is zero";
  const std::string pose = validatePose(msg.pose.pose);
  return pose.empty() ? "" : "pose: " + pose;
}

std::string validateLoopClosure(const LoopClosure& msg) {
  const bool by_id = msg.id_from >= 0 && msg.id_to >= 0;
  if (by_id && msg.id_from == msg.id_to) return "id_from equals id_to";
  if (!by_id && (msg.stamp_from.isZero() || msg.stamp_to.isZero()))
    return "ids negative and a stamp is zero: names no pose";
  if (!by_id && msg.stamp_from == msg.stamp_to) return "stamp_from equals stamp_to";
  const std::string pose = validatePose(msg.from_T_to);
  // An unusable covariance is not a reason to refuse: informationFromCovariance falls back to the
  // configured defaults and says so.
  return pose.empty() ? "" : "from_T_to: " + pose;
}

std::string stampString(const ros::Time& stamp) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%u.%09u", stamp.sec, stamp.nsec);
  return buf;
}

}  // namespace toro_ros
