// rostest client for replay_sample.test: waits for the replay's finisher, then checks
// (1) the live node's saved graph equals toro_offline's on the same bag (same keyframes, stamps,
//     constraints; poses within the stated tolerance),
// (2) both beat the raw odometry against the truth by a wide margin,
// (3) the final corrected pose on /tf (map -> base_link) is near the truth's final pose.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>

#include <ros/ros.h>
#include <std_msgs/String.h>
#include <tf2_ros/transform_listener.h>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/offline/scoring.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {
namespace {

namespace fs = std::filesystem;

// Live and offline run the same passes in the same order when the node's worker keeps up with
// the 3x replay (it does by orders of magnitude on this 144-keyframe graph); the tolerance allows
// for a pass landing on the other side of a message should the machine stall.
constexpr double kPositionTolerance = 1e-3;  // m
constexpr double kAngleTolerance = 1e-4;     // rad

std::string sampleDir() {
  std::string dir;
  ros::param::get("~sample_dir", dir);
  return dir.empty() ? TORO_SAMPLE_DIR : dir;
}

struct Saved {
  toro::PoseGraph graph;
  Sidecar sidecar;
};

Saved load(const std::string& path) { return Saved{toro::readGraph(path), readSidecar(sidecarPath(path))}; }

std::vector<toro::Pose3> poses(const toro::PoseGraph& g) {
  std::vector<toro::Pose3> out;
  for (const toro::Node& n : g.nodes()) out.push_back(n.pose);
  return out;
}

// The path the finisher saved the live graph to (its latched ~result "saved <path>"), waiting in
// wall time: under use_sim_time a ros::Time timeout would expire when the first /clock jumps to
// the bag's epoch.  Empty if it did not come.
std::string livePath() {
  static std::string path;
  static bool waited = false;
  if (waited) return path;
  waited = true;
  std::string result;
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe<std_msgs::String>(
      "/replay_finish/result", 1, [&result](const std_msgs::String::ConstPtr& m) { result = m->data; });
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(80.0);
  while (result.empty() && ros::WallTime::now() < deadline && ros::ok()) ros::WallDuration(0.1).sleep();
  if (result.rfind("saved ", 0) == 0) path = result.substr(6);
  if (path.empty()) ADD_FAILURE() << "the replay did not finish within 80 s (result: '" << result << "')";
  return path;
}

class ReplaySample : public ::testing::Test {
 protected:
  void SetUp() override { live_path_ = livePath(); }
  std::string live_path_;
};

TEST_F(ReplaySample, LiveNodeAndOfflineRunnerGiveTheSameGraph) {
  ASSERT_FALSE(live_path_.empty());
  const fs::path out = fs::path(sampleDir()) / "replay_test_offline";
  const std::string cmd = std::string(TORO_OFFLINE_BIN) + " " + sampleDir() + "/sample.bag --config " +
                          TORO_SOURCE_DIR +
                          "/config/replay_sample.yaml --final-iterations 20 --quiet --no-curve " +
                          "--output-dir " + out.string() + " > /dev/null";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  const Saved live = load(live_path_), offline = load((out / "corrected.g2o").string());
  ASSERT_EQ(live.graph.numNodes(), offline.graph.numNodes());
  ASSERT_EQ(live.graph.numConstraints(), offline.graph.numConstraints());
  ASSERT_EQ(live.sidecar.keyframes.size(), offline.sidecar.keyframes.size());
  double max_position = 0, max_angle = 0;
  for (std::size_t i = 0; i < live.graph.numNodes(); ++i) {
    EXPECT_EQ(live.sidecar.keyframes[i].stamp, offline.sidecar.keyframes[i].stamp) << i;
    const toro::Pose3 &a = live.graph.node(i).pose, &b = offline.graph.node(i).pose;
    max_position = std::max(max_position, (a.translation() - b.translation()).norm());
    max_angle = std::max(max_angle, toro::relativePose(a, b).angle());
  }
  // The same constraints, in any order: the node takes odometry and loop closures from two topics,
  // so on a busy machine a loop closure may join the graph a few keyframes later than offline
  // (seen in CI-like runs beside a build: the lists were shifted by one from index 52 on).
  const auto endpoints = [](const toro::PoseGraph& g) {
    std::vector<std::pair<toro::NodeId, toro::NodeId>> out;
    for (const toro::Constraint& k : g.constraints()) out.emplace_back(k.from, k.to);
    std::sort(out.begin(), out.end());
    return out;
  };
  EXPECT_EQ(endpoints(live.graph), endpoints(offline.graph));
  EXPECT_LT(max_position, kPositionTolerance);
  EXPECT_LT(max_angle, kAngleTolerance);
  RecordProperty("max_position_difference_m", std::to_string(max_position));
  std::cout << "live vs offline: max position difference " << max_position << " m, max angle " << max_angle
            << " rad\n";
  // Both beat the raw odometry by a wide margin (at least 3x lower position RMSE).
  const TruthTrajectory truth = TruthTrajectory::load(sampleDir() + "/sample.truth.g2o");
  for (const Saved* s : {&live, &offline}) {
    const Score score = scoreKeyframes(s->sidecar.keyframes, poses(s->graph), truth);
    EXPECT_EQ(score.corrected.poses, s->graph.numNodes());
    EXPECT_LT(score.corrected.rmse_m, score.odometry.rmse_m / 3) << describeScore(score);
  }
}

// Listens from the start: once the bag has ended nothing republishes odom -> base_link, and the
// node's map -> odom timer stands still with sim time.
tf2_ros::Buffer* g_tf_buffer = nullptr;

TEST_F(ReplaySample, FinalCorrectedPoseOnTfIsNearTheTruth) {
  ASSERT_FALSE(live_path_.empty());
  ASSERT_NE(g_tf_buffer, nullptr);
  tf2_ros::Buffer& buffer = *g_tf_buffer;
  // The bag has ended: sim time stands at its last stamp, and the latest map -> base_link is the
  // final pose (map -> odom from the node, odom -> base_link from the bag).
  geometry_msgs::TransformStamped t;
  // Wait for the tf in wall time (sim time has stopped with the bag).
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(10.0);
  while (!buffer.canTransform("map", "base_link", ros::Time(0)) && ros::WallTime::now() < deadline)
    ros::WallDuration(0.1).sleep();
  ASSERT_NO_THROW(t = buffer.lookupTransform("map", "base_link", ros::Time(0)));
  const toro::Vector3 corrected(t.transform.translation.x, t.transform.translation.y,
                                t.transform.translation.z);
  const TruthTrajectory truth = TruthTrajectory::load(sampleDir() + "/sample.truth.g2o");
  toro::Pose3 true_final;
  ASSERT_TRUE(truth.at(truth.stamps().back(), &true_final));
  const Sidecar odometry = readSidecar(sidecarPath(sampleDir() + "/sample.odometry.g2o"));
  const double corrected_error = (corrected - true_final.translation()).norm();
  const double odometry_error =
      (odometry.keyframes.back().odom_T_base.translation() - true_final.translation()).norm();
  std::cout << "final pose error: corrected " << corrected_error << " m, odometry " << odometry_error
            << " m\n";
  EXPECT_LT(corrected_error, 0.5);
  EXPECT_LT(corrected_error, odometry_error / 3);
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "replay_sample_test");
  ros::AsyncSpinner spinner(1);
  spinner.start();
  tf2_ros::Buffer buffer(ros::Duration(120.0));
  tf2_ros::TransformListener listener(buffer);
  toro_ros::offline::g_tf_buffer = &buffer;
  return RUN_ALL_TESTS();
}
