// Planar mode of the pipeline (PipelineOptions::planar): 3D input with out-of-plane noise, and
// everything the pipeline gives out exactly planar.
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/planar.h"
#include "toro_ros/core/random_draws.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;
using toro_ros::testing::drain;
using toro_ros::testing::DriftScenario;
using toro_ros::testing::makeDriftingSquare;
using toro_ros::testing::trueLoopClosure;

namespace {

// The drifting square of the other pipeline tests on an uneven floor: the odometry pose gets z
// bumps of a few cm and roll/pitch wobble of ~0.02 rad (what a 3D odometry source reports), the
// loop closures 2 cm / 0.02 rad of out-of-plane noise and the ROS planar covariance convention:
// z, roll and pitch with variance 1e6 (odometry) and 0 (loop closures: two_d_mode style).
struct UnevenFloor {
  DriftScenario s;
  std::vector<LoopClosure> loop_closures;  // lap 2 to lap 1 every 10th sample, and the end to the start
};

UnevenFloor makeUnevenFloor() {
  UnevenFloor u;
  u.s = makeDriftingSquare();
  std::mt19937 rng(17);
  std::normal_distribution<double> n(0.0, 1.0);
  for (std::size_t i = 0; i < u.s.odometry.size(); ++i) {
    nav_msgs::Odometry& m = u.s.odometry[i];
    const double t = 0.1 * static_cast<double>(i);
    const toro::Pose3 bump = toro::Pose3::fromRollPitchYaw(0, 0, 0.03 * std::sin(t), 0.02 * std::sin(1.3 * t),
                                                           0.02 * std::cos(0.7 * t), 0);
    m.pose.pose = poseToMsg(poseFromMsg(m.pose.pose) * bump);
    for (int k = 0; k < 36; ++k) m.pose.covariance[k] = 0.0;
    const double grow = 1e-4 * (1.0 + t);  // an EKF's growing covariance in x, y and yaw
    m.pose.covariance[0] = m.pose.covariance[7] = m.pose.covariance[35] = grow;
    m.pose.covariance[14] = m.pose.covariance[21] = m.pose.covariance[28] = 1e6;
  }
  const std::size_t lap = u.s.odometry.size() / 2;
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (std::size_t j = lap + 5; j + 1 < u.s.odometry.size(); j += 10) pairs.emplace_back(j - lap, j);
  pairs.emplace_back(0, u.s.odometry.size() - 1);  // back at the start
  for (const auto& [i, j] : pairs) {
    LoopClosure lc = trueLoopClosure(u.s, i, j);
    const auto d = toro::drawLastFirst<3>(n, rng);
    lc.from_T_to = poseToMsg(poseFromMsg(lc.from_T_to) *
                             toro::Pose3::fromRollPitchYaw(0, 0, 0.02 * d[0], 0.02 * d[1], 0.02 * d[2], 0));
    for (int k : {14, 21, 28}) lc.covariance[k] = 0.0;  // z, roll, pitch "not measured"
    u.loop_closures.push_back(lc);
  }
  return u;
}

PipelineOptions planarOptions(bool planar) {
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.optimization.full_every_keyframes = 10;
  o.optimization.full_iterations = 10;
  o.planar = planar;
  return o;
}

// Feeds the scenario in stamp order, each loop closure right after the odometry it names.
void run(Pipeline& p, const UnevenFloor& u) {
  std::size_t next = 0;
  for (const nav_msgs::Odometry& m : u.s.odometry) {
    p.handleOdometry(m);
    while (next < u.loop_closures.size() && u.loop_closures[next].stamp_to <= m.header.stamp)
      p.handleLoopClosure(u.loop_closures[next++]);
    drain(p);
  }
}

bool exactlyPlanar(const toro::Pose3& p) {
  const toro::Vector3 rpy = p.rollPitchYaw();
  return p.translation().z() == 0.0 && rpy.x() == 0.0 && rpy.y() == 0.0 && toro::isExactlyPlanar(p);
}

double largestZ(const Snapshot& s) {
  double z = 0.0;
  for (const SnapshotKeyframe& k : s.keyframes) z = std::max(z, std::abs(k.map_T_base.translation().z()));
  return z;
}

std::uint64_t count(const PipelineCounters& c, const std::string& reason) {
  const auto it = c.refused_by_reason.find(reason);
  return it == c.refused_by_reason.end() ? 0 : it->second;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class PlanarPipeline : public ::testing::Test {
 protected:
  void SetUp() override { path_ = ::testing::TempDir() + "planar_" + std::to_string(::getpid()) + ".g2o"; }
  void TearDown() override {
    std::remove(path_.c_str());
    std::remove((path_ + ".stamps").c_str());
  }
  std::string path_;
};

}  // namespace

TEST_F(PlanarPipeline, ThreeDimensionalInputEndsExactlyPlanarEverywhere) {
  const UnevenFloor u = makeUnevenFloor();
  Pipeline p(planarOptions(true));
  run(p, u);
  const PipelineStatus status = p.status();
  EXPECT_EQ(status.counters.loop_closures_applied, u.loop_closures.size());
  EXPECT_EQ(status.counters.loop_closures_refused, 0u);
  // Only the x, y, yaw rows of the covariances are read: 1e6 and 0 on z, roll and pitch are not
  // "unusable".
  EXPECT_EQ(count(status.counters, "odometry: covariance unusable, default used"), 0u);
  EXPECT_EQ(count(status.counters, "loop closure: covariance unusable, default used"), 0u);
  ASSERT_TRUE(p.optimize(0, "full").success);
  const OptimizeResult finish = p.optimize(0, "finish");
  ASSERT_TRUE(finish.success) << finish.message;

  const auto snapshot = p.makeSnapshot();
  ASSERT_GT(snapshot->keyframes.size(), 50u);
  for (const SnapshotKeyframe& k : snapshot->keyframes) EXPECT_TRUE(exactlyPlanar(k.map_T_base)) << k.id;
  ASSERT_TRUE(snapshot->has_map_T_odom);
  EXPECT_TRUE(exactlyPlanar(snapshot->map_T_odom));
  EXPECT_EQ(p.graph().dimension(), toro::GraphDimension::k2D);
  // The correction works in the plane: the newest keyframe much nearer the truth than the odometry.
  const toro::Vector2 truth = u.s.truth.back().translation().head<2>();
  const double raw = (poseFromMsg(u.s.odometry.back().pose.pose).translation().head<2>() - truth).norm();
  const double corrected = (snapshot->keyframes.back().map_T_base.translation().head<2>() - truth).norm();
  EXPECT_GT(raw, 1.0);
  EXPECT_LT(corrected, 0.1 * raw);

  // The saved graph is a 2D file.
  ASSERT_EQ(p.saveGraph(path_), "");
  const std::string text = slurp(path_);
  EXPECT_NE(text.find("VERTEX_SE2 "), std::string::npos);
  EXPECT_NE(text.find("EDGE_SE2 "), std::string::npos);
  EXPECT_EQ(text.find("SE3"), std::string::npos);
  const toro::PoseGraph saved = toro::readGraph(path_);
  EXPECT_EQ(saved.dimension(), toro::GraphDimension::k2D);
  EXPECT_EQ(saved.numNodes(), snapshot->keyframes.size());
}

TEST_F(PlanarPipeline, WithoutPlanarModeTheSameInputLeavesThePlane) {
  // The check above can fail: the 3D pipeline on the same input has poses off the plane.
  const UnevenFloor u = makeUnevenFloor();
  Pipeline p(planarOptions(false));
  run(p, u);
  ASSERT_TRUE(p.optimize(0, "full").success);
  const auto snapshot = p.makeSnapshot();
  EXPECT_GT(largestZ(*snapshot), 0.01);
  EXPECT_FALSE(exactlyPlanar(snapshot->map_T_odom));
  ASSERT_EQ(p.saveGraph(path_), "");
  EXPECT_NE(slurp(path_).find("VERTEX_SE3:QUAT "), std::string::npos);
}

TEST_F(PlanarPipeline, ALoaded3DGraphIsProjectedAndGrowsInThePlane) {
  const UnevenFloor u = makeUnevenFloor();
  DriftScenario first = u.s, second = u.s;
  const std::size_t half = u.s.odometry.size() / 2;
  first.odometry.resize(half);
  second.odometry.erase(second.odometry.begin(), second.odometry.begin() + static_cast<long>(half));
  {
    Pipeline spatial(planarOptions(false));
    for (const nav_msgs::Odometry& m : first.odometry) spatial.handleOdometry(m);
    ASSERT_EQ(spatial.saveGraph(path_), "");
  }
  ASSERT_NE(slurp(path_).find("VERTEX_SE3:QUAT "), std::string::npos);
  Pipeline planar(planarOptions(true));
  ASSERT_EQ(planar.loadGraph(path_), "");
  EXPECT_EQ(planar.graph().dimension(), toro::GraphDimension::k2D);
  for (const nav_msgs::Odometry& m : second.odometry) planar.handleOdometry(m);
  for (const LoopClosure& lc : u.loop_closures) planar.handleLoopClosure(lc);
  drain(planar);
  EXPECT_EQ(planar.status().counters.loop_closures_applied, u.loop_closures.size());
  const auto snapshot = planar.makeSnapshot();
  ASSERT_GT(snapshot->keyframes.size(), 50u);
  for (const SnapshotKeyframe& k : snapshot->keyframes) EXPECT_TRUE(exactlyPlanar(k.map_T_base)) << k.id;
  EXPECT_TRUE(exactlyPlanar(snapshot->map_T_odom));
  for (const KeyframeRecord& k : planar.keyframes().records())
    EXPECT_TRUE(exactlyPlanar(k.odom_T_base)) << k.id;
}

// The gate counts the degrees of freedom the input has: 3 in planar mode whatever comes in, and in
// the 3D pipeline while every measurement is planar (a 2D robot's bag); 6 once one leaves the plane.
TEST(PlanarPipelineGate, ThresholdCountsTheInputsDegreesOfFreedom) {
  const double three = toro::chiSquareQuantile(0.99, 3), six = toro::chiSquareQuantile(0.99, 6);
  const DriftScenario flat = makeDriftingSquare();
  const UnevenFloor uneven = makeUnevenFloor();
  for (const bool planar : {true, false}) {
    SCOPED_TRACE(planar ? "planar mode" : "3D pipeline");
    PipelineOptions o = planarOptions(planar);
    o.loop_closure_gate_confidence = 0.99;
    o.loop_closure_gate_variance_factor = 0.5;
    Pipeline on_flat(o);
    EXPECT_DOUBLE_EQ(on_flat.gateThreshold(), 0.5 * three);  // nothing seen yet
    for (const nav_msgs::Odometry& m : flat.odometry) on_flat.handleOdometry(m);
    ASSERT_GT(on_flat.status().keyframes, 10u);
    EXPECT_DOUBLE_EQ(on_flat.gateThreshold(), 0.5 * three);
    Pipeline on_uneven(o);
    for (const nav_msgs::Odometry& m : uneven.s.odometry) on_uneven.handleOdometry(m);
    ASSERT_GT(on_uneven.status().keyframes, 10u);
    EXPECT_DOUBLE_EQ(on_uneven.gateThreshold(), 0.5 * (planar ? three : six));
  }
}

TEST(PlanarCovariance, KeepsThePlanarRowsAndIgnoresTheOthers) {
  toro::Matrix6 c = toro::Matrix6::Zero();
  c(0, 0) = 0.04;
  c(1, 1) = 0.09;
  c(5, 5) = 0.01;
  c(0, 5) = c(5, 0) = 0.005;
  c(2, 2) = 0.0;            // z "exact" (two_d_mode)
  c(3, 3) = 1e6;            // roll unknown
  c(0, 3) = c(3, 0) = 0.3;  // a correlation with an axis that is dropped
  const toro::Matrix6 planar = planarCovariance(c);
  for (int i : {0, 1, 5})
    for (int j : {0, 1, 5}) EXPECT_EQ(planar(i, j), c(i, j));
  EXPECT_EQ(planar(0, 3), 0.0);
  EXPECT_GT(planar(2, 2), 0.0);
  // The planar information is the inverse of the planar covariance block.
  const InformationResult info = informationFromCovariance(planar, DefaultStddev{});
  ASSERT_FALSE(info.used_default) << info.reason;
  Eigen::Matrix3d block;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      block(i, j) = c(std::array<int, 3>{0, 1, 5}[i], std::array<int, 3>{0, 1, 5}[j]);
  const Eigen::Matrix3d expected = block.inverse();
  const toro::Matrix6 angle_units = toro::quaternionToAngleUnits(info.information);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      EXPECT_NEAR(angle_units(std::array<int, 3>{0, 1, 5}[i], std::array<int, 3>{0, 1, 5}[j]), expected(i, j),
                  1e-9 * expected.norm());
  // A planar block that is unusable stays unusable (defaults, with the reason).
  toro::Matrix6 zero_planar = toro::Matrix6::Zero();
  zero_planar(2, 2) = zero_planar(3, 3) = zero_planar(4, 4) = 1.0;
  EXPECT_TRUE(informationFromCovariance(planarCovariance(zero_planar), DefaultStddev{}).used_default);
}
