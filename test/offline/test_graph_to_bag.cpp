// graph_to_bag: the bag read back reproduces the graph (constraint count and values), the timeline
// and covariance model, the options' errors; the flat parameter-file reader.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <Eigen/Eigenvalues>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/random_draws.h"
#include "toro_ros/offline/flat_yaml.h"
#include "toro_ros/offline/graph_to_bag.h"
#include "toro_ros/offline/robot_messages.h"
#include "toro_ros/offline/sample_graph.h"
#include "toro_ros/pipeline/keyframer.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {
namespace offline {
namespace {

namespace fs = std::filesystem;

struct BagContents {
  std::vector<nav_msgs::Odometry> odometry;
  std::vector<ros::Time> odometry_times;
  std::vector<LoopClosure> loop_closures;
  std::vector<ros::Time> loop_closure_times;
  std::size_t tf = 0;
};

BagContents readBack(const std::string& path) {
  BagContents out;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    if (auto o = m.instantiate<nav_msgs::Odometry>()) {
      out.odometry.push_back(*o);
      out.odometry_times.push_back(m.getTime());
    } else if (auto l = m.instantiate<LoopClosure>()) {
      out.loop_closures.push_back(*l);
      out.loop_closure_times.push_back(m.getTime());
    } else if (m.getTopic() == "/tf") {
      ++out.tf;
    }
  }
  return out;
}

double relativeDifference(const toro::Matrix6& a, const toro::Matrix6& b) {
  return (a - b).norm() / b.norm();
}

class GraphToBagTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("toro_graph_to_bag_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    SampleOptions s;
    s.laps = 2;
    graph_ = makeSampleGraph(s).graph;
    input_ = (dir_ / "input.g2o").string();
    toro::writeGraph(graph_, input_);
    options_.input_path = input_;
    options_.output_bag = (dir_ / "robot.bag").string();
    options_.ground_truth_path = input_;
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path dir_;
  toro::PoseGraph graph_;
  std::string input_;
  GraphToBagOptions options_;
};

TEST_F(GraphToBagTest, LoopClosuresReproduceTheGraphsConstraints) {
  const GraphToBagResult r = graphToBag(options_);
  const RobotTimeline t = makeTimeline(graph_, options_, input_);
  const BagContents bag = readBack(options_.output_bag);
  const std::size_t odometry_steps = graph_.numNodes() - 1;
  ASSERT_EQ(bag.loop_closures.size(), graph_.numConstraints() - odometry_steps);
  EXPECT_EQ(r.loop_closures, bag.loop_closures.size());
  std::size_t i = 0;
  for (std::size_t c = 0; c < graph_.numConstraints(); ++c) {
    if (!t.is_loop_closure[c]) continue;
    const toro::Constraint& k = graph_.constraints()[c];
    // Written in constraint order; read back in time order: find it by its stamps.
    const auto it =
        std::find_if(bag.loop_closures.begin(), bag.loop_closures.end(), [&](const LoopClosure& m) {
          return m.stamp_from == t.stampOfKeyframe(graph_.indexOf(k.from)) &&
                 m.stamp_to == t.stampOfKeyframe(graph_.indexOf(k.to));
        });
    ASSERT_NE(it, bag.loop_closures.end()) << "constraint " << c;
    EXPECT_EQ(it->id_from, -1);
    const toro::Pose3 z = poseFromMsg(it->from_T_to);
    EXPECT_LT((z.translation() - k.measurement.translation()).norm(), 1e-12);
    EXPECT_LT(toro::relativePose(z, k.measurement).angle(), 1e-9);
    const InformationResult info = informationFromCovariance(it->covariance, DefaultStddev{});
    EXPECT_FALSE(info.used_default);
    EXPECT_LT(relativeDifference(info.information, k.information), 1e-9) << "constraint " << c;
    // Published when the robot reaches the later pose, plus the latency.
    const std::size_t j = static_cast<std::size_t>(it - bag.loop_closures.begin());
    EXPECT_EQ(bag.loop_closure_times[j], std::max(it->stamp_from, it->stamp_to) + ros::Duration(0.02));
    ++i;
  }
  EXPECT_EQ(i, bag.loop_closures.size());
}

TEST_F(GraphToBagTest, OdometryIsTheDriftingChainAtTheRateWithStepInformation) {
  options_.odometry_rate_hz = 10.0;
  options_.speed_mps = 2.0;
  graphToBag(options_);
  const RobotTimeline t = makeTimeline(graph_, options_, input_);
  const BagContents bag = readBack(options_.output_bag);
  ASSERT_EQ(bag.odometry.size(), static_cast<std::size_t>(t.sample_of_keyframe.back() + 1));
  EXPECT_EQ(bag.tf, bag.odometry.size());
  EXPECT_EQ(bag.odometry.front().header.stamp, ros::Time(1000.0));
  for (std::size_t i = 1; i < bag.odometry.size(); ++i)
    ASSERT_EQ((bag.odometry[i].header.stamp - bag.odometry[i - 1].header.stamp).toNSec(), 100000000);
  EXPECT_EQ(bag.odometry.front().header.frame_id, "odom");
  EXPECT_EQ(bag.odometry.front().child_frame_id, "base_link");
  // At keyframe stamps: relative odometry = the odometry constraint, and the keyframer's
  // "difference" covariance mode gives back its information.
  KeyframerOptions ko;
  ko.covariance_mode = OdometryCovarianceMode::kDifference;
  Keyframer keyframer(ko);
  for (std::size_t k = 0; k < t.ids.size(); ++k) {
    const nav_msgs::Odometry& m = bag.odometry[t.sample_of_keyframe[k]];
    const std::optional<OdometryStep> step = keyframer.accept(
        OdometrySample{m.header.stamp, poseFromMsg(m.pose.pose), covarianceMatrix(m.pose.covariance)});
    if (k == 0) continue;
    const toro::Constraint& c = graph_.constraints()[t.odometry_constraint[k - 1]];
    EXPECT_LT((step->previous_T_current.translation() - c.measurement.translation()).norm(), 1e-9) << k;
    EXPECT_LT(toro::relativePose(step->previous_T_current, c.measurement).angle(), 1e-9) << k;
    EXPECT_LT(relativeDifference(step->information.information, c.information), 1e-6) << k;
  }
  // A step lasts length / speed rounded up to whole periods (1 m at 2 m/s and 10 Hz: 5 periods).
  const double length = graph_.constraints()[t.odometry_constraint[0]].measurement.translation().norm();
  EXPECT_EQ(t.sample_of_keyframe[1], static_cast<long>(std::ceil(length / 2.0 * 10.0 - 1e-9)));
}

// An EKF carries one message's covariance to the next and adds a positive semi-definite growth; so
// must the bag, between any two messages (not only at the graph's nodes), or the keyframer's
// "difference" rule reads a shrinking axis there (a long run's accumulated variance passes the
// unmeasured threshold and, before, such a step switched the background finish off).
TEST_F(GraphToBagTest, EveryOdometryMessageGrowsTheCarriedCovarianceOfTheOneBefore) {
  // A heading far less certain than the position, correlated with it (as parking-garage's and
  // sphere2500's are), and few messages per step: the carried heading variance outgrows a step's
  // share of the position variance unless the growth itself is carried.
  toro::Matrix6 step_covariance = toro::Matrix6::Zero();
  step_covariance.diagonal() << 1e-4, 1e-4, 1e-4, 4e-3, 4e-3, 4e-3;
  step_covariance(2, 3) = step_covariance(3, 2) = 3e-4;
  step_covariance(0, 5) = step_covariance(5, 0) = -3e-4;
  toro::PoseGraph graph;
  for (const toro::Node& n : graph_.nodes()) graph.addNode(n.id, n.pose);
  for (toro::Constraint c : graph_.constraints()) {
    c.information = toro::angleToQuaternionUnits(step_covariance.inverse());
    graph.addConstraint(c);
  }
  toro::writeGraph(graph, input_);
  options_.odometry_rate_hz = 2.0;
  options_.speed_mps = 1.0;  // two or three messages per step, across turns
  graphToBag(options_);
  const BagContents bag = readBack(options_.output_bag);
  ASSERT_GT(bag.odometry.size(), 2 * graph_.numNodes());
  KeyframerOptions ko;
  ko.covariance_mode = OdometryCovarianceMode::kDifference;
  Keyframer keyframer(ko);
  double worst = 0.0;
  for (std::size_t i = 0; i < bag.odometry.size(); ++i) {
    const nav_msgs::Odometry& m = bag.odometry[i];
    const OdometrySample sample{m.header.stamp, poseFromMsg(m.pose.pose),
                                covarianceMatrix(m.pose.covariance)};
    if (i > 0) {
      const nav_msgs::Odometry& p = bag.odometry[i - 1];
      const toro::Matrix6 older = covarianceMatrix(p.pose.covariance);
      const toro::Vector3 d = sample.odom_T_base.translation() - poseFromMsg(p.pose.pose).translation();
      const toro::Matrix6 growth = sample.covariance - carriedCovariance(older, d);
      const double smallest = Eigen::SelfAdjointEigenSolver<toro::Matrix6>(growth).eigenvalues()(0);
      worst = std::min(worst, smallest / sample.covariance.diagonal().maxCoeff());
    }
    const std::optional<OdometryStep> step = keyframer.accept(sample);
    if (step &&
        (sample.odom_T_base.translation() - poseFromMsg(bag.odometry[i - 1].pose.pose).translation()).norm() >
            1e-6) {
      ASSERT_EQ(axisNames(step->information.axes, AxisReading::kMeasured), "x y z roll pitch yaw") << i;
    }
  }
  EXPECT_GT(worst, -1e-12);
}

TEST_F(GraphToBagTest, WritesTruthAndOdometryScoringFiles) {
  const GraphToBagResult r = graphToBag(options_);
  const std::string stem = (dir_ / "robot").string();
  ASSERT_TRUE(fs::exists(stem + ".truth.g2o"));
  ASSERT_TRUE(fs::exists(stem + ".odometry.g2o.stamps"));
  const toro::PoseGraph truth = toro::readGraph(stem + ".truth.g2o");
  // Truth expressed from the first pose (the odom origin).
  const toro::Pose3 first_inverse = graph_.node(0).pose.inverse();
  for (std::size_t i = 0; i < graph_.numNodes(); ++i) {
    const toro::Pose3 expected = first_inverse * graph_.node(i).pose;
    EXPECT_LT((truth.node(i).pose.translation() - expected.translation()).norm(), 1e-9);
  }
  EXPECT_EQ(r.written.size(), 4u);
}

TEST_F(GraphToBagTest, TruthWithoutVerticesIsTheChainOfItsMeasurements) {
  // Like GTSAM's sphere2500_groundtruth.txt: noise-free constraints, no VERTEX lines.
  const std::string edges_only = (dir_ / "edges_only.g2o").string();
  {
    std::ifstream in(input_);
    std::ofstream out(edges_only);
    for (std::string line; std::getline(in, line);)
      if (line.rfind("VERTEX", 0) != 0) out << line << "\n";
  }
  options_.ground_truth_path = edges_only;
  graphToBag(options_);
  const RobotTimeline t = makeTimeline(graph_, options_, input_);
  const toro::PoseGraph truth = toro::readGraph((dir_ / "robot.truth.g2o").string());
  ASSERT_EQ(truth.numNodes(), t.ids.size());
  for (std::size_t k = 0; k < t.ids.size(); ++k) {
    EXPECT_LT((truth.pose(t.ids[k]).translation() - t.odom_T_base[k].translation()).norm(), 1e-9) << k;
    EXPECT_LT(toro::relativePose(truth.pose(t.ids[k]), t.odom_T_base[k]).angle(), 1e-9) << k;
  }
}

TEST_F(GraphToBagTest, ConstantPeriodPutsKeyframesOnTheGrid) {
  options_.keyframe_period_sec = 0.25;
  const RobotTimeline t = makeTimeline(graph_, options_, input_);
  for (std::size_t k = 0; k < t.ids.size(); ++k) EXPECT_EQ(t.sample_of_keyframe[k], static_cast<long>(5 * k));
}

TEST_F(GraphToBagTest, OptionErrorsNameTheOption) {
  GraphToBagOptions o = options_;
  EXPECT_EQ(o.validate(), "");
  o.keyframe_period_sec = 0.33;
  EXPECT_NE(o.validate().find("keyframe_period_sec"), std::string::npos);
  o = options_;
  o.odometry_rate_hz = 0;
  EXPECT_NE(o.validate().find("odometry_rate_hz"), std::string::npos);
  o = options_;
  o.output_bag = "x.txt";
  EXPECT_NE(o.validate().find("x.txt"), std::string::npos);
  o = options_;
  o.loop_closure_latency_sec = 0.5;  // longer than a 20 Hz period
  EXPECT_NE(o.validate().find("loop_closure_latency_sec"), std::string::npos);
  o = options_;
  o.input_path = (dir_ / "missing.g2o").string();
  try {
    graphToBag(o);
    FAIL() << "no error for a missing file";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("missing.g2o"), std::string::npos) << e.what();
  }
}

TEST_F(GraphToBagTest, ReversedOdometryConstraintGivesTheEquivalentForwardStep) {
  // Constraint 1 -> 0 measuring Z: the step 0 -> 1 is Z^-1, and its covariance must weigh a small
  // error of node 1 as the reversed constraint does (same chi2 to second order).
  const toro::Pose3 step = toro::Pose3::fromRollPitchYaw(1.0, 0.3, -0.2, 0.1, -0.05, 0.4);
  toro::Matrix6 information;
  information << 50, 3, 1, 2, 0, 1, 3, 40, 2, 0, 1, 0, 1, 2, 60, 1, 0, 2, 2, 0, 1, 900, 20, 5, 0, 1, 0, 20,
      800, 10, 1, 0, 2, 5, 10, 700;
  toro::PoseGraph reversed;
  reversed.addNode(0, toro::Pose3());
  reversed.addNode(1, step);
  reversed.addConstraint(toro::Constraint{1, 0, step.inverse(), information});
  const RobotTimeline t = makeTimeline(reversed, options_, "reversed.g2o");
  ASSERT_TRUE(t.odometry_reversed[0]);
  EXPECT_LT((t.odom_T_base[1].translation() - step.translation()).norm(), 1e-12);
  const toro::Matrix6 forward_information =
      informationFromCovariance(t.step_covariance[0], DefaultStddev{}).information;
  toro::PoseGraph forward = reversed;
  forward.clear();
  forward.addNode(0, toro::Pose3());
  forward.addNode(1, step);
  forward.addConstraint(toro::Constraint{0, 1, step, forward_information});
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1e-4);
  for (int trial = 0; trial < 10; ++trial) {
    const toro::Pose3 moved = step * toro::drawPose3(n, n, rng);
    reversed.setPose(1, moved);
    forward.setPose(1, moved);
    const double a = toro::constraintChi2(reversed, 0), b = toro::constraintChi2(forward, 0);
    EXPECT_NEAR(a, b, 1e-3 * a) << "trial " << trial;
  }
}

TEST_F(GraphToBagTest, BrokenOdometryChainIsAnErrorNamingTheFileAndNodes) {
  toro::PoseGraph g;
  g.addNode(0, toro::Pose3());
  g.addNode(1, toro::Pose3());
  g.addNode(2, toro::Pose3());
  g.addConstraint(toro::Constraint{0, 1, toro::Pose3(), toro::Matrix6::Identity()});
  g.addConstraint(toro::Constraint{0, 2, toro::Pose3(), toro::Matrix6::Identity()});
  try {
    makeTimeline(g, options_, "broken.g2o");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("broken.g2o"), std::string::npos) << what;
    EXPECT_NE(what.find("between node 1 and node 2"), std::string::npos) << what;
  }
}

TEST(FlatYaml, ReadsScalarsAndNamesTheLineOfAnError) {
  const fs::path p = fs::temp_directory_path() / ("toro_flat_" + std::to_string(::getpid()) + ".yaml");
  { std::ofstream(p) << "# comment\na: 1\nb: 2.5  # trailing\nc: true\nd: \"x # y\"\ne: word\n"; }
  XmlRpc::XmlRpcValue v = readFlatYaml(p.string());
  EXPECT_EQ(static_cast<int>(v["a"]), 1);
  EXPECT_DOUBLE_EQ(static_cast<double>(v["b"]), 2.5);
  EXPECT_TRUE(static_cast<bool>(v["c"]));
  EXPECT_EQ(static_cast<std::string>(v["d"]), "x # y");
  EXPECT_EQ(static_cast<std::string>(v["e"]), "word");
  { std::ofstream(p) << "a: 1\nnested:\n  b: 2\n"; }
  try {
    readFlatYaml(p.string());
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(p.string() + ":2:"), std::string::npos) << e.what();
  }
  fs::remove(p);
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros
