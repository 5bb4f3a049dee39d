// Run-time tuning without a master: cfg/MapCorrector.cfg against the node's options (names known,
// defaults equal, every value between min and max valid), the Config -> parameters -> options
// path with its change list, and Pipeline::applyLiveOptions.
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "../pipeline/drift_scenario.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/node/live_options.h"
#include "toro_ros/node/node_options.h"

using namespace toro_ros;
using toro_ros::testing::makeDriftingSquare;

TEST(LiveOptions, EveryCfgParameterIsAKnownKeyWithTheNodesDefault) {
  const std::set<std::string> known = knownParameterKeys();
  const std::set<std::string> live = liveParameterKeys();
  EXPECT_GE(live.size(), 20u);
  for (const std::string& key : live)
    EXPECT_TRUE(known.count(key)) << key << " (cfg) is not a parameter of the node";
  // Defaults: the cfg's default config read as parameters changes nothing against no parameters.
  const XmlRpc::XmlRpcValue none;
  const XmlRpc::XmlRpcValue defaults = withConfig(none, MapCorrectorConfig::__getDefault__());
  for (const std::string& change : changedParameters(none, defaults))
    ADD_FAILURE() << "cfg default differs: " << change;
}

TEST(LiveOptions, EveryValueTheCfgOffersPassesValidation) {
  for (const MapCorrectorConfig* bound :
       {&MapCorrectorConfig::__getMin__(), &MapCorrectorConfig::__getMax__()}) {
    OptionsReport report;
    loadNodeOptions(withConfig(XmlRpc::XmlRpcValue(), *bound), &report);
    for (const std::string& e : report.errors)
      ADD_FAILURE() << (bound == &MapCorrectorConfig::__getMin__() ? "min: " : "max: ") << e;
  }
}

TEST(LiveOptions, ConfigOverridesTheStartParametersAndTheChangesAreListed) {
  XmlRpc::XmlRpcValue start;
  start["map_frame"] = std::string("world");
  start["keyframe_distance_m"] = 0.5;
  MapCorrectorConfig config = MapCorrectorConfig::__getDefault__();
  config.keyframe_distance_m = 2.0;
  config.marker_draw_odometry_edges = false;
  config.optimization_full_iterations = 7;
  XmlRpc::XmlRpcValue next = withConfig(start, config);
  EXPECT_EQ(static_cast<std::string>(next["map_frame"]), "world");  // not live: kept
  OptionsReport report;
  const NodeOptions o = loadNodeOptions(next, &report);
  EXPECT_TRUE(report.errors.empty());
  EXPECT_EQ(o.map_frame, "world");
  EXPECT_EQ(o.pipeline.keyframer.distance_m, 2.0);
  EXPECT_FALSE(o.markers.draw_odometry_edges);
  EXPECT_EQ(o.pipeline.optimization.full_iterations, 7);
  const std::vector<std::string> changes = changedParameters(start, next);
  ASSERT_EQ(changes.size(), 3u);
  EXPECT_EQ(changes[0], "keyframe_distance_m: 0.5 -> 2");
  EXPECT_EQ(changes[1], "marker_draw_odometry_edges: true -> false");
  EXPECT_EQ(changes[2], "optimization_full_iterations: 5 -> 7");
  EXPECT_TRUE(changedParameters(next, next).empty());
}

TEST(ApplyLiveOptions, KeyframeThresholdsApplyFromTheNextMessageAndKeepTheReferenceKeyframe) {
  const auto scenario = makeDriftingSquare();
  Pipeline p(toro_ros::testing::baseTestOptions());
  const std::size_t half = scenario.odometry.size() / 2;
  for (std::size_t i = 0; i < half; ++i) p.handleOdometry(scenario.odometry[i]);
  const std::size_t before = p.keyframes().size();
  PipelineOptions wider = p.options();
  wider.keyframer.distance_m = 2.0;
  wider.keyframer.angle_rad = 3.15;  // only the distance makes keyframes now
  ASSERT_EQ(p.applyLiveOptions(wider), "");
  EXPECT_EQ(p.options().keyframer.distance_m, 2.0);
  for (std::size_t i = half; i < scenario.odometry.size(); ++i) p.handleOdometry(scenario.odometry[i]);
  const auto& k = p.keyframes().records();
  ASSERT_GT(k.size(), before + 3);
  // Every keyframe from the change on (the first measured from the last one before it) is the
  // first odometry message more than 2 m from the previous keyframe (messages 0.103 m apart).
  for (std::size_t i = before; i < k.size(); ++i) {
    const double step = toro::relativePose(k[i - 1].odom_T_base, k[i].odom_T_base).translation().norm();
    EXPECT_GT(step, 2.0) << i;
    EXPECT_LT(step, 2.0 + 0.11) << i;
  }
}

TEST(ApplyLiveOptions, InvalidValuesChangeNothingAndOtherOptionsAreKept) {
  Pipeline p(toro_ros::testing::baseTestOptions());
  PipelineOptions bad = p.options();
  bad.keyframer.distance_m = 0.0;
  bad.loop_closure_gate_confidence = 0.99;
  EXPECT_NE(p.applyLiveOptions(bad).find("distance_m"), std::string::npos);
  EXPECT_EQ(p.options().keyframer.distance_m, 0.5);
  EXPECT_EQ(p.gateThreshold(), std::numeric_limits<double>::infinity());
  PipelineOptions other = p.options();
  other.odom_frame = "elsewhere";           // not live
  other.matcher.stamp_tolerance_sec = 9.0;  // not live
  other.optimization.gamma = 3.0;           // not live (the optimiser holds the graph)
  ASSERT_EQ(p.applyLiveOptions(other), "");
  EXPECT_EQ(p.options().odom_frame, "");
  EXPECT_EQ(p.options().matcher.stamp_tolerance_sec, 0.15);
  EXPECT_EQ(p.options().optimization.gamma, 1.0);
}

TEST(ApplyLiveOptions, GateThresholdFollowsConfidenceAndVarianceFactor) {
  Pipeline p(toro_ros::testing::baseTestOptions());
  PipelineOptions o = p.options();
  o.loop_closure_gate_confidence = 0.99;
  o.loop_closure_gate_variance_factor = 0.5;
  ASSERT_EQ(p.applyLiveOptions(o), "");
  // 3 degrees of freedom: no measurement has left the plane yet (test_pipeline_planar).
  EXPECT_DOUBLE_EQ(p.gateThreshold(), toro::chiSquareQuantile(0.99, 3) * 0.5);
  EXPECT_NEAR(p.gateThreshold(), 11.345 * 0.5, 0.01);
  o.loop_closure_gate_confidence = 0.0;
  ASSERT_EQ(p.applyLiveOptions(o), "");
  EXPECT_EQ(p.gateThreshold(), std::numeric_limits<double>::infinity());
}

TEST(ApplyLiveOptions, PlanarModeAndTheLearntCovarianceConventionSurvive) {
  const auto scenario = makeDriftingSquare();
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.planar = true;
  o.keyframer.covariance_mode = OdometryCovarianceMode::kAuto;
  o.loop_closure_gate_confidence = 0.99;
  Pipeline p(o);
  const std::size_t half = scenario.odometry.size() / 2;
  // A constant covariance (diff_drive_controller style) on an uneven floor.
  const auto message = [&](std::size_t i) {
    nav_msgs::Odometry m = scenario.odometry[i];
    m.pose.pose.position.z += 0.2 * std::sin(0.1 * static_cast<double>(i));
    for (int a = 0; a < 6; ++a) m.pose.covariance[a * 7] = a == 2 || a == 3 || a == 4 ? 1e6 : 1e-3;
    return m;
  };
  for (std::size_t i = 0; i < half; ++i) p.handleOdometry(message(i));
  const std::string rule = p.status().odometry_covariance_rule;
  ASSERT_NE(rule.find("the same in every message"), std::string::npos) << rule;
  PipelineOptions wider = p.options();
  wider.keyframer.distance_m = 1.0;
  wider.loop_closure_gate_confidence = 0.95;
  ASSERT_EQ(p.applyLiveOptions(wider), "");
  EXPECT_TRUE(p.options().planar);
  // The gate counts the plane's 3 degrees of freedom, as at start-up.
  EXPECT_DOUBLE_EQ(p.gateThreshold(), toro::chiSquareQuantile(0.95, 3));
  for (std::size_t i = half; i < scenario.odometry.size(); ++i) p.handleOdometry(message(i));
  // The convention seen before the change is kept (no step made with the defaults after it) and
  // the keyframes after it are still planar.
  EXPECT_EQ(p.status().odometry_covariance_rule.substr(0, 40), rule.substr(0, 40));
  EXPECT_EQ(p.status().counters.odometry_steps_default, 0u);
  for (const toro::Node& n : p.graph().nodes()) EXPECT_EQ(n.pose.translation().z(), 0.0);
}

TEST(ApplyLiveOptions, ARoundInProgressEndsWithinTheNewNumberOfPasses) {
  const auto scenario = makeDriftingSquare();
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.optimization.full_iterations = 5;
  o.optimization.full_every_keyframes = 10;
  Pipeline p(o);
  for (const auto& m : scenario.odometry) p.handleOdometry(m);
  p.handleLoopClosure(toro_ros::testing::trueLoopClosure(scenario, 0, scenario.odometry.size() - 1));
  ASSERT_TRUE(p.runScheduledOptimization());  // the loop closure's affected pass
  ASSERT_TRUE(p.runScheduledOptimization());  // first pass of the due round: 4 left
  ASSERT_TRUE(p.hasScheduledWork());
  o.optimization.full_iterations = 1;
  ASSERT_EQ(p.applyLiveOptions(o), "");
  EXPECT_TRUE(p.runScheduledOptimization());
  EXPECT_FALSE(p.hasScheduledWork());
  EXPECT_FALSE(p.runScheduledOptimization());
}

TEST(ApplyLiveOptions, RobustWidthReweighsNowTheKernelStays) {
  const auto scenario = makeDriftingSquare();
  Pipeline p(toro_ros::testing::baseTestOptions());
  ASSERT_TRUE(p.options().robust.enabled());  // on by default
  for (const auto& m : scenario.odometry) p.handleOdometry(m);
  p.handleLoopClosure(toro_ros::testing::trueLoopClosure(scenario, 0, scenario.odometry.size() - 1));
  while (p.runScheduledOptimization()) {
  }
  const std::uint64_t revision = p.revision();
  PipelineOptions o = p.options();
  o.robust.width = 3.0;
  o.robust.adaptive_width_factor = 0.0;
  o.robust.kernel = toro::RobustKernel::kCauchy;  // not live
  ASSERT_EQ(p.applyLiveOptions(o), "");
  EXPECT_EQ(p.options().robust.width, 3.0);
  EXPECT_EQ(p.options().robust.adaptive_width_factor, 0.0);
  EXPECT_EQ(p.status().robust_width, 3.0);
  EXPECT_EQ(p.optimizerOptions().robust.width, 3.0);
  EXPECT_EQ(p.options().robust.kernel, toro::RobustKernel::kDcs);
  EXPECT_GT(p.revision(), revision);  // the weights were refreshed: the snapshot shows it
  o.robust.width = 0.0;               // invalid
  EXPECT_NE(p.applyLiveOptions(o), "");
  EXPECT_EQ(p.options().robust.width, 3.0);
}
