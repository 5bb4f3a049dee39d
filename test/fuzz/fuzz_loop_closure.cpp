// Fuzz target for loop-closure messages as they come off the wire: the bytes are one or more
// serialised toro_ros/LoopClosure messages (ROS serialisation, as a subscriber receives them), each
// fed to a Pipeline that has odometry of a drifting square, followed by one more odometry message
// and the scheduled optimisation.  Properties checked:
// - nothing throws or crashes (a message the pipeline cannot use is refused, with a reason);
// - informationFromCovariance always gives a finite, symmetric, positive definite information;
// - every loop closure is accounted for: received == applied + refused + pending, and every
//   refusal is counted under a "loop closure: ..." reason;
// - the graph stays usable: odometry chain + applied loop closures == constraints, poses finite.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <Eigen/Eigenvalues>
#include <ros/serialization.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/pipeline.h"

namespace {

constexpr int kMaxMessages = 8;

[[noreturn]] void fail(const char* what) {
  // A property violation must stop the fuzzer like a crash does.
  std::fputs(what, stderr);
  std::fputc('\n', stderr);
  std::abort();
}

toro_ros::PipelineOptions options() {
  toro_ros::PipelineOptions o;
  o.keyframer.distance_m = 0.5;
  o.keyframer.angle_rad = 0.5;
  o.keyframer.interval_sec = 0;
  o.matcher.stamp_tolerance_sec = 0.15;
  o.optimization.full_every_keyframes = 4;
  o.optimization.full_every_sec = 0;
  o.optimization.full_iterations = 2;
  return o;
}

// Straight line along x at 1 m/s with a slow yaw drift, one message every 0.1 s from t = 100 s.
nav_msgs::Odometry odometry(int i) {
  nav_msgs::Odometry m;
  m.header.stamp = ros::Time(100.0 + 0.1 * i);
  m.header.frame_id = "odom";
  m.child_frame_id = "base_link";
  m.pose.pose = toro_ros::poseToMsg(toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0.01 * i));
  return m;
}

void checkInformation(const toro_ros::LoopClosure& msg) {
  const toro_ros::InformationResult r = toro_ros::informationFromCovariance(msg.covariance, {0.1, 0.05});
  if (!r.information.allFinite()) fail("information is not finite");
  if ((r.information - r.information.transpose()).cwiseAbs().maxCoeff() > 1e-9 * r.information.cwiseAbs().maxCoeff())
    fail("information is not symmetric");
  Eigen::SelfAdjointEigenSolver<toro::Matrix6> eig(r.information, Eigen::EigenvaluesOnly);
  if (!(eig.eigenvalues().minCoeff() > 0)) fail("information is not positive definite");
  if ((r.default_axes > 0 || r.repaired) == r.reason.empty()) fail("defaults/repair and reason disagree");
  if (r.used_default != (r.default_axes == 6)) fail("used_default and default_axes disagree");
}

void checkAccounting(const toro_ros::Pipeline& p) {
  const toro_ros::PipelineStatus s = p.status();
  const toro_ros::PipelineCounters& c = s.counters;
  if (c.loop_closures_received != c.loop_closures_applied + c.loop_closures_refused + s.pending_loop_closures)
    fail("loop closures received != applied + refused + pending");
  std::uint64_t by_reason = 0;
  for (const auto& [reason, n] : c.refused_by_reason)
    if (reason.rfind("loop closure: ", 0) == 0 && reason.find("default used") == std::string::npos) by_reason += n;
  if (by_reason != c.loop_closures_refused) fail("loop-closure refusals by reason do not add up");
  if (s.constraints != (s.keyframes == 0 ? 0 : s.keyframes - 1) + c.loop_closures_applied)
    fail("constraints != odometry chain + applied loop closures");
  const toro::PoseGraph& g = p.graph();
  for (std::size_t i = 0; i < g.numNodes(); ++i) {
    const toro::Pose3& pose = g.node(i).pose;
    if (!pose.translation().allFinite() || !pose.rotation().coeffs().allFinite()) fail("pose not finite");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  toro_ros::Pipeline pipeline(options());
  int next_odometry = 0;
  for (; next_odometry < 40; ++next_odometry) pipeline.handleOdometry(odometry(next_odometry));
  // IStream takes a non-const pointer but only reads.
  ros::serialization::IStream stream(const_cast<std::uint8_t*>(data), static_cast<std::uint32_t>(size));
  for (int m = 0; m < kMaxMessages && stream.getLength() > 0; ++m) {
    toro_ros::LoopClosure msg;
    try {
      ros::serialization::deserialize(stream, msg);
    } catch (const ros::serialization::StreamOverrunException&) {
      break;  // truncated message: the transport would never deliver it
    }
    checkInformation(msg);
    (void)toro_ros::validateLoopClosure(msg);
    pipeline.handleLoopClosure(msg);
    pipeline.handleOdometry(odometry(next_odometry++));
    pipeline.runScheduledOptimization();
    checkAccounting(pipeline);
  }
  return 0;
}
