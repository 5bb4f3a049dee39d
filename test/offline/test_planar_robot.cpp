// The planar test robot of issue 11 (make_planar_robot, planar_robot.h) in each covariance style,
// written as a bag and replayed through toro_offline's runner with the default parameters (no
// config file): no loop closure may be refused for its stamps (they are scan stamps between
// keyframes more than twice the stamp tolerance apart), the covariance counters must say what the
// style means, and the corrected map must be within the issue's target of the truth.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "toro_ros/offline/offline_runner.h"
#include "toro_ros/offline/planar_robot.h"
#include "toro_ros/offline/scoring.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {
namespace offline {
namespace {

namespace fs = std::filesystem;

// The issue's targets for this robot with default parameters.
constexpr double kTargetRmseM = 0.2;
// The map's shape (rigidly aligned RMSE; the unaligned one also holds the rotation about the first
// pose that no loop closure can observe, measured 0.27 m of 0.31 m on seed 4).
constexpr double kTargetAlignedRmseM = 0.1;

struct TempDir {
  TempDir() {
    char t[] = "/tmp/toro_planar_XXXXXX";
    path = mkdtemp(t);
  }
  ~TempDir() { fs::remove_all(path); }
  std::string path;
};

struct Replay {
  PipelineStatus status;
  Score score;
  double max_abs_z_m = 0.0;      // of the corrected keyframes
  std::size_t scan_stamped = 0;  // loop-closure stamps that are neither an odometry nor a keyframe stamp
};

Replay replay(const PlanarRobotOptions& options) {
  const PlanarRobot robot = makePlanarRobot(options);
  TempDir dir;
  const std::string bag = dir.path + "/robot.bag";
  writePlanarRobot(robot, bag);
  OfflineOptions o;
  o.bag_path = bag;
  o.output_dir = dir.path + "/out";
  o.truth_path = dir.path + "/robot.truth.g2o";
  o.progress = false;
  o.iteration_curve = false;
  OfflineRunner runner(o);  // no config file: the node's defaults
  runner.run();
  Replay r;
  Pipeline& p = runner.pipeline();
  r.status = p.status();
  std::vector<toro::Pose3> corrected;
  for (const toro::Node& n : p.graph().nodes()) {
    corrected.push_back(n.pose);
    r.max_abs_z_m = std::max(r.max_abs_z_m, std::abs(n.pose.translation().z()));
  }
  r.score = scoreKeyframes(p.keyframes().records(), corrected, TruthTrajectory::load(o.truth_path));
  std::set<ros::Time> taken;
  for (const nav_msgs::Odometry& m : robot.odometry) taken.insert(m.header.stamp);
  for (const KeyframeRecord& k : p.keyframes().records()) taken.insert(k.stamp);
  for (const auto& [when, lc] : robot.loop_closures)
    r.scan_stamped += !taken.count(lc.stamp_from) + !taken.count(lc.stamp_to);
  std::printf(
      "%s%s: %zu keyframes, %llu/%llu loop closures applied; odometry steps default %llu, partly %llu, "
      "repaired %llu; RMSE %.4f m (odometry %.3f m), aligned %.4f m; max |z| %.4f m\n  rule: %s\n",
      toString(options.covariance_style).c_str(),
      options.loop_closure_out_of_plane_stddev > 0 ? " + out-of-plane noise" : "", r.status.keyframes,
      static_cast<unsigned long long>(r.status.counters.loop_closures_applied),
      static_cast<unsigned long long>(r.status.counters.loop_closures_received),
      static_cast<unsigned long long>(r.status.counters.odometry_steps_default),
      static_cast<unsigned long long>(r.status.counters.odometry_steps_partly_default),
      static_cast<unsigned long long>(r.status.counters.odometry_steps_repaired), r.score.corrected.rmse_m,
      r.score.odometry.rmse_m, r.score.corrected.rmse_aligned_m, r.max_abs_z_m,
      r.status.odometry_covariance_rule.c_str());
  return r;
}

PlanarRobotOptions style(OdometryCovarianceStyle s) {
  PlanarRobotOptions o;
  o.covariance_style = s;
  return o;
}

// What every style shares: every loop closure applied (none refused for its stamps, every stamp a
// scan's), their 1e6 axes read as unmeasured (no defaults), and the map within the targets.
void expectCommon(const Replay& r) {
  const PipelineCounters& c = r.status.counters;
  EXPECT_GE(c.loop_closures_received, 95u);
  EXPECT_EQ(c.loop_closures_refused, 0u);
  EXPECT_EQ(c.loop_closures_applied, c.loop_closures_received);
  EXPECT_EQ(r.status.pending_loop_closures, 0u);
  EXPECT_EQ(r.scan_stamped, 2 * c.loop_closures_received);
  EXPECT_EQ(c.loop_closures_default, 0u);
  EXPECT_EQ(c.loop_closures_partly_default, 0u);
  EXPECT_NE(r.status.loop_closure_covariance_rule.find("unmeasured"), std::string::npos);
  EXPECT_TRUE(c.refused_by_reason.empty());
  EXPECT_GT(r.score.odometry.rmse_m, 2.0);  // the odometry drifts by metres
  EXPECT_LT(r.score.corrected.rmse_m, kTargetRmseM);
  EXPECT_LT(r.score.corrected.rmse_aligned_m, kTargetAlignedRmseM);
}

TEST(PlanarRobot, GeneratorIsTheIssuesRobot) {
  PlanarRobotOptions o;
  const PlanarRobot a = makePlanarRobot(o);
  EXPECT_NEAR(o.path.perimeter(), 71.7, 0.1);
  EXPECT_NEAR(a.path_length_m, 3 * o.path.perimeter(), 0.1);
  EXPECT_EQ(a.odometry.size(), 4303u);  // 215 s at 20 Hz
  EXPECT_GE(a.loop_closures.size(), 95u);
  EXPECT_LE(a.loop_closures.size(), 110u);
  const auto [largest, last] = odometryDrift(a);
  EXPECT_GT(largest, 4.0);
  EXPECT_LT(largest, 8.0);
  for (const auto& [when, lc] : a.loop_closures) {
    // Scan stamps: 0.03 s after an odometry message, so never an odometry stamp.
    EXPECT_EQ((lc.stamp_to.toNSec() - 30000000) % 100000000, 0u);
    EXPECT_EQ(covarianceMatrix(lc.covariance)(2, 2), 1e6);
    EXPECT_EQ(when, lc.header.stamp);
    EXPECT_GT(when, lc.stamp_to);
  }
  for (const toro::Pose3& t : a.truth) ASSERT_EQ(t.translation().z(), 0.0);
  // The styles differ only in the covariance; the seed decides the noise.
  const PlanarRobot zero = makePlanarRobot(style(OdometryCovarianceStyle::kZero));
  EXPECT_EQ(zero.odometry[100].pose.pose, a.odometry[100].pose.pose);
  EXPECT_EQ(covarianceMatrix(zero.odometry[100].pose.covariance), toro::Matrix6::Zero());
  EXPECT_EQ(a.odometry[100].pose.covariance, a.odometry[2000].pose.covariance);  // constant
  const PlanarRobot ekf = makePlanarRobot(style(OdometryCovarianceStyle::kEkfTwoD));
  EXPECT_GT(covarianceMatrix(ekf.odometry[2000].pose.covariance)(0, 0),
            covarianceMatrix(ekf.odometry[100].pose.covariance)(0, 0));
  EXPECT_EQ(covarianceMatrix(ekf.odometry[2000].pose.covariance)(3, 3), 1e-6);
  PlanarRobotOptions other = o;
  other.seed = 2;
  EXPECT_NE(makePlanarRobot(other).odometry[100].pose.pose, a.odometry[100].pose.pose);
  EXPECT_EQ(makePlanarRobot(o).odometry[4000].pose.pose, a.odometry[4000].pose.pose);
  other.laps = 1;
  EXPECT_THROW(makePlanarRobot(other), std::invalid_argument);
}

TEST(PlanarRobot, ConstantCovarianceLikeDiffDriveController) {
  const Replay r = replay(style(OdometryCovarianceStyle::kConstant));
  expectCommon(r);
  const PipelineCounters& c = r.status.counters;
  EXPECT_EQ(c.odometry_steps_default, 0u);
  EXPECT_EQ(c.odometry_steps_partly_default, 0u);  // z/roll/pitch are unmeasured, not unknown
  EXPECT_NE(r.status.odometry_covariance_rule.find("same in every message"), std::string::npos);
}

TEST(PlanarRobot, GrowingCovarianceLikeRobotLocalizationTwoDMode) {
  for (OdometryCovarianceStyle s :
       {OdometryCovarianceStyle::kEkfTwoD, OdometryCovarianceStyle::kEkfTwoDZero}) {
    const Replay r = replay(style(s));
    expectCommon(r);
    const PipelineCounters& c = r.status.counters;
    EXPECT_EQ(c.odometry_steps_default, 0u);
    // z, roll and pitch do not grow (held at 1e-6 or 0): every step takes the defaults there only.
    EXPECT_EQ(c.odometry_steps_partly_default, r.status.keyframes - 1);
    EXPECT_EQ(c.odometry_steps_repaired, 0u);  // the growth carried as an EKF predicts is definite
    EXPECT_NE(r.status.odometry_covariance_rule.find("changes between messages"), std::string::npos);
  }
}

TEST(PlanarRobot, AllZeroCovarianceTakesTheDefaultsAndSaysSo) {
  const Replay r = replay(style(OdometryCovarianceStyle::kZero));
  expectCommon(r);
  EXPECT_EQ(r.status.counters.odometry_steps_default, r.status.keyframes - 1);
  EXPECT_EQ(r.status.counters.odometry_steps_partly_default, 0u);
}

TEST(PlanarRobot, OutOfPlaneNoiseOnTheLoopClosures) {
  // 2 cm / 0.02 rad of noise on the axes the loop closures declare unmeasured (1e6).
  PlanarRobotOptions o = style(OdometryCovarianceStyle::kConstant);
  o.loop_closure_out_of_plane_stddev = 0.02;
  const Replay r = replay(o);
  expectCommon(r);
  RecordProperty("max_abs_z_m", std::to_string(r.max_abs_z_m));
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros
