#include "toro_ros/node/graph_message.h"

#include <limits>

#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/covariance_conversion.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

namespace {

PoseGraphEdge edgeMessage(const toro::Constraint& c, std::uint8_t type, double weight, double chi2) {
  PoseGraphEdge e;
  e.id_from = c.from;
  e.id_to = c.to;
  e.type = type;
  e.from_T_to = poseToMsg(c.measurement);
  // The graph holds only SPD information (validated when added); should one ever not be, NaN
  // says so rather than a made-up covariance.
  try {
    e.covariance = covarianceToMsg(covarianceFromInformation(c.information));
  } catch (const std::invalid_argument&) {
    e.covariance.fill(std::numeric_limits<double>::quiet_NaN());
  }
  e.weight = weight;
  e.chi2 = chi2;
  return e;
}

}  // namespace

PoseGraph graphMessage(const Pipeline& pipeline, const Snapshot& snapshot, const std::string& map_frame) {
  PoseGraph msg;
  msg.header.frame_id = map_frame;
  msg.header.stamp = snapshot.newest_stamp;
  msg.epoch = snapshot.epoch;
  msg.chi2 = snapshot.chi2;
  msg.planar = pipeline.options().planar;
  const toro::PoseGraph& g = pipeline.graph();
  const auto& records = pipeline.keyframes().records();
  msg.nodes.reserve(records.size());
  for (std::size_t i = 0; i < records.size(); ++i) {
    PoseGraphNode n;
    n.id = records[i].id;
    n.stamp = records[i].stamp;
    n.pose = poseToMsg(g.node(i).pose);
    n.odom_pose = poseToMsg(records[i].odom_T_base);
    msg.nodes.push_back(n);
  }
  const std::vector<toro::Constraint>& constraints = g.constraints();
  msg.edges.reserve(constraints.size() + pipeline.rejectedLoopClosures().size());
  for (std::size_t c = 0; c < constraints.size(); ++c) {
    const SnapshotEdge* edge = c < snapshot.edges.size() ? &snapshot.edges[c] : nullptr;
    const bool loop_closure = edge != nullptr && edge->loop_closure;
    msg.edges.push_back(edgeMessage(constraints[c],
                                    loop_closure ? PoseGraphEdge::LOOP_CLOSURE : PoseGraphEdge::ODOMETRY,
                                    edge != nullptr ? edge->weight : 1.0, toro::constraintChi2(g, c)));
  }
  for (const RejectedLoopClosure& r : pipeline.rejectedLoopClosures())
    msg.edges.push_back(edgeMessage(r.constraint, PoseGraphEdge::REJECTED_LOOP_CLOSURE, 0.0, r.chi2));
  return msg;
}

geometry_msgs::PoseWithCovarianceStamped correctedPose(const toro::Pose3& map_T_odom,
                                                       const nav_msgs::Odometry& odom,
                                                       const std::string& map_frame, bool planar) {
  geometry_msgs::PoseWithCovarianceStamped out;
  out.header.stamp = odom.header.stamp;
  out.header.frame_id = map_frame;
  // In planar mode map_T_odom joins planar poses: the odometry pose is projected as the pipeline
  // projects it, so the corrected pose is planar too.
  out.pose.pose =
      poseToMsg(map_T_odom * (planar ? planarPoseFromMsg(odom.pose.pose) : poseFromMsg(odom.pose.pose)));
  toro::Matrix6 rotate = toro::Matrix6::Zero();
  const toro::Matrix3 r = map_T_odom.rotationMatrix();
  rotate.block<3, 3>(0, 0) = r;
  rotate.block<3, 3>(3, 3) = r;
  out.pose.covariance = covarianceToMsg(rotate * covarianceMatrix(odom.pose.covariance) * rotate.transpose());
  return out;
}

}  // namespace toro_ros
