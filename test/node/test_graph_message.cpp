// graphMessage and correctedPose without a master: the ~graph message against the file
// saveGraph writes from the same pipeline (ids, stamps, poses, constraints, types, covariances),
// rejected loop closures after the graph's constraints, and the corrected pose's numbers.
#include <unistd.h>
#include <cmath>
#include <set>

#include <gtest/gtest.h>

#include "../pipeline/drift_scenario.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/node/graph_message.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/persistence.h"

using namespace toro_ros;
using toro_ros::testing::makeDriftingSquare;
using toro_ros::testing::trueLoopClosure;

namespace {

std::string tempDir() {
  char dir[] = "/tmp/toro_graph_message_XXXXXX";
  return mkdtemp(dir) != nullptr ? dir : "/tmp";
}

double positionError(const geometry_msgs::Pose& a, const toro::Pose3& b) {
  return (poseFromMsg(a).translation() - b.translation()).norm();
}

}  // namespace

TEST(GraphMessage, EqualsTheSavedGraph) {
  const auto scenario = makeDriftingSquare();
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  // Odometry covariances that cover the scenario's drift (as test_pipeline_gate), so that the
  // gate keeps the right loop closure and rejects only the wrong one below.
  o.keyframer.distance_m = 1.0;
  o.keyframer.covariance_mode = OdometryCovarianceMode::kDefault;
  o.keyframer.default_stddev = DefaultStddev{0.1, 0.05};
  o.loop_closure_gate_confidence = 0.99;
  Pipeline p(o);
  for (const auto& m : scenario.odometry) p.handleOdometry(m);
  const std::size_t last = scenario.odometry.size() - 1;
  p.handleLoopClosure(trueLoopClosure(scenario, 0, 80));  // right, early in the second lap
  while (p.runScheduledOptimization()) {
  }
  // A loop closure 20 m off between two keyframes: the gate rejects it, and it follows the
  // graph's edges in the message.
  const auto& k = p.keyframes().records();
  LoopClosure wrong = trueLoopClosure(scenario, 0, last);
  wrong.stamp_from = k[1].stamp;
  wrong.stamp_to = k[k.size() - 2].stamp;
  wrong.from_T_to.position.x += 20.0;
  p.handleLoopClosure(wrong);
  while (p.runScheduledOptimization()) {
  }
  ASSERT_EQ(p.rejectedLoopClosures().size(), 1u);
  ASSERT_EQ(p.status().counters.loop_closures_applied, 1u);

  const std::shared_ptr<const Snapshot> snapshot = p.makeSnapshot();
  const PoseGraph msg = graphMessage(p, *snapshot, "map");
  const std::string path = tempDir() + "/graph.g2o";
  ASSERT_EQ(p.saveGraph(path), "");
  const toro::PoseGraph file = toro::readGraph(path);
  const Sidecar sidecar = readSidecar(sidecarPath(path));

  EXPECT_EQ(msg.header.frame_id, "map");
  EXPECT_EQ(msg.header.stamp, sidecar.keyframes.back().stamp);
  EXPECT_EQ(msg.epoch, snapshot->epoch);
  EXPECT_DOUBLE_EQ(msg.chi2, snapshot->chi2);
  EXPECT_FALSE(msg.planar);
  ASSERT_EQ(msg.nodes.size(), file.numNodes());
  for (std::size_t i = 0; i < file.numNodes(); ++i) {
    EXPECT_EQ(msg.nodes[i].id, file.node(i).id);
    EXPECT_EQ(msg.nodes[i].stamp, sidecar.keyframes[i].stamp);
    EXPECT_LT(positionError(msg.nodes[i].pose, file.node(i).pose), 1e-12);
    EXPECT_LT(positionError(msg.nodes[i].odom_pose, sidecar.keyframes[i].odom_T_base), 1e-12);
  }
  ASSERT_EQ(msg.edges.size(), file.numConstraints() + 1);
  const std::set<std::size_t> loop_closures(sidecar.loop_closures.begin(), sidecar.loop_closures.end());
  for (std::size_t c = 0; c < file.numConstraints(); ++c) {
    const PoseGraphEdge& e = msg.edges[c];
    const toro::Constraint& k = file.constraints()[c];
    EXPECT_EQ(e.id_from, k.from);
    EXPECT_EQ(e.id_to, k.to);
    EXPECT_EQ(e.type, loop_closures.count(c) ? PoseGraphEdge::LOOP_CLOSURE : PoseGraphEdge::ODOMETRY);
    EXPECT_LT(positionError(e.from_T_to, k.measurement), 1e-12);
    const toro::Matrix6 info = informationFromCovariance(e.covariance, DefaultStddev{}).information;
    EXPECT_LT((info - k.information).norm(), 1e-9 * k.information.norm()) << c;
    EXPECT_EQ(e.weight, 1.0);
    EXPECT_NEAR(e.chi2, toro::constraintChi2(file, c), 1e-9 * (1 + e.chi2));
  }
  const PoseGraphEdge& rejected = msg.edges.back();
  ASSERT_EQ(sidecar.rejected.size(), 1u);
  EXPECT_EQ(rejected.type, PoseGraphEdge::REJECTED_LOOP_CLOSURE);
  EXPECT_EQ(rejected.id_from, sidecar.rejected[0].constraint.from);
  EXPECT_EQ(rejected.id_to, sidecar.rejected[0].constraint.to);
  EXPECT_EQ(rejected.weight, 0.0);
  EXPECT_DOUBLE_EQ(rejected.chi2, p.rejectedLoopClosures()[0].chi2);
  EXPECT_GT(rejected.chi2, p.gateThreshold());
  // The loop closure was sent with 0.02 m / 0.01 rad: its covariance comes back as sent.
  const PoseGraphEdge& applied = msg.edges[*loop_closures.begin()];
  EXPECT_NEAR(applied.covariance[0], 0.02 * 0.02, 1e-15);
  EXPECT_NEAR(applied.covariance[35], 0.01 * 0.01, 1e-15);
  EXPECT_NEAR(applied.covariance[1], 0.0, 1e-15);
}

TEST(GraphMessage, PlanarModeGivesAPlanarGraphAndPose) {
  const auto scenario = makeDriftingSquare();
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.planar = true;
  Pipeline p(o);
  // The floor is uneven: odometry leaves the plane by up to 0.3 m and 0.1 rad.
  for (std::size_t i = 0; i < scenario.odometry.size(); ++i) {
    nav_msgs::Odometry m = scenario.odometry[i];
    m.pose.pose.position.z += 0.3 * std::sin(0.05 * static_cast<double>(i));
    const toro::Pose3 tilted =
        poseFromMsg(m.pose.pose) * toro::Pose3::fromRollPitchYaw(0, 0, 0, 0.1 * std::cos(0.07 * i), 0.05, 0);
    m.pose.pose = poseToMsg(tilted);
    p.handleOdometry(m);
  }
  p.handleLoopClosure(trueLoopClosure(scenario, 0, 80));
  while (p.runScheduledOptimization()) {
  }
  const PoseGraph msg = graphMessage(p, *p.makeSnapshot(), "map");
  EXPECT_TRUE(msg.planar);
  ASSERT_GT(msg.nodes.size(), 10u);
  for (const PoseGraphNode& n : msg.nodes) {
    EXPECT_EQ(n.pose.position.z, 0.0);
    EXPECT_NEAR(n.pose.orientation.x, 0.0, 1e-12);
    EXPECT_NEAR(n.pose.orientation.y, 0.0, 1e-12);
  }
  // The corrected pose of a tilted, raised odometry message is planar too, and 3D without planar.
  const nav_msgs::Odometry& last = scenario.odometry.back();
  nav_msgs::Odometry raised = last;
  raised.pose.pose.position.z = 0.4;
  raised.pose.pose =
      poseToMsg(poseFromMsg(raised.pose.pose) * toro::Pose3::fromRollPitchYaw(0, 0, 0, 0.2, 0.1, 0));
  const toro::Pose3 map_T_odom = p.makeSnapshot()->map_T_odom;
  const geometry_msgs::PoseWithCovarianceStamped planar = correctedPose(map_T_odom, raised, "map", true);
  EXPECT_EQ(planar.pose.pose.position.z, 0.0);
  EXPECT_NEAR(planar.pose.pose.orientation.x, 0.0, 1e-12);
  EXPECT_NEAR(planar.pose.pose.orientation.y, 0.0, 1e-12);
  const geometry_msgs::PoseWithCovarianceStamped spatial = correctedPose(map_T_odom, raised, "map", false);
  EXPECT_NEAR(spatial.pose.pose.position.z, 0.4, 1e-9);
  // Both agree in the plane.
  EXPECT_NEAR(planar.pose.pose.position.x, spatial.pose.pose.position.x, 1e-9);
  EXPECT_NEAR(planar.pose.pose.position.y, spatial.pose.pose.position.y, 1e-9);
}

TEST(GraphMessage, EmptyPipelineGivesAnEmptyGraph) {
  Pipeline p(PipelineOptions{});
  const PoseGraph msg = graphMessage(p, *p.makeSnapshot(), "world");
  EXPECT_EQ(msg.header.frame_id, "world");
  EXPECT_TRUE(msg.nodes.empty());
  EXPECT_TRUE(msg.edges.empty());
  EXPECT_TRUE(std::isnan(msg.chi2));
}

TEST(CorrectedPose, IsMapToOdomTimesTheOdometryWithItsCovarianceRotated) {
  const toro::Pose3 map_T_odom = toro::Pose3::fromRollPitchYaw(1.0, -2.0, 0.5, 0.0, 0.0, M_PI / 2);
  nav_msgs::Odometry odom =
      toro_ros::testing::odometryMsg(ros::Time(12.5), toro::Pose3::fromRollPitchYaw(3, 0, 0, 0, 0, 0));
  odom.pose.covariance[0] = 0.04;   // x
  odom.pose.covariance[7] = 0.01;   // y
  odom.pose.covariance[14] = 0.09;  // z
  odom.pose.covariance[35] = 0.25;  // yaw
  const geometry_msgs::PoseWithCovarianceStamped p = correctedPose(map_T_odom, odom, "map");
  EXPECT_EQ(p.header.frame_id, "map");
  EXPECT_EQ(p.header.stamp, ros::Time(12.5));
  // 3 m along odom's x is 3 m along map's y after the 90 degree yaw.
  EXPECT_NEAR(p.pose.pose.position.x, 1.0, 1e-12);
  EXPECT_NEAR(p.pose.pose.position.y, 1.0, 1e-12);
  EXPECT_NEAR(p.pose.pose.position.z, 0.5, 1e-12);
  // The x and y variances swap; z and yaw stay.
  EXPECT_NEAR(p.pose.covariance[0], 0.01, 1e-15);
  EXPECT_NEAR(p.pose.covariance[7], 0.04, 1e-15);
  EXPECT_NEAR(p.pose.covariance[14], 0.09, 1e-15);
  EXPECT_NEAR(p.pose.covariance[35], 0.25, 1e-15);
  EXPECT_NEAR(p.pose.covariance[1], 0.0, 1e-15);
}
