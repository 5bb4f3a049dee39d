// Bad input at the pipeline level (issue 6): each kind of unusable message is refused or repaired
// with a counted reason and a warning naming the stamp and the problem, and leaves the graph
// usable.  Transport-level cases (frames, queue overflow) are in the node's rostest.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;
using toro_ros::testing::odometryMsg;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

PipelineOptions options() { return toro_ros::testing::baseTestOptions(); }

// A pipeline with warnings collected and odometry along x at 1 m/s, every 0.1 s from t = 100 s.
struct Fixture {
  std::vector<std::string> warnings;
  Pipeline pipeline{options(), [this](const std::string& w) { warnings.push_back(w); }};
  int next = 0;
  void drive(int messages) {
    for (int end = next + messages; next < end; ++next)
      pipeline.handleOdometry(
          odometryMsg(stamp(next), toro::Pose3::fromRollPitchYaw(0.1 * next, 0, 0, 0, 0, 0)));
  }
  static ros::Time stamp(int i) { return ros::Time(100.0 + 0.1 * i); }
  std::uint64_t count(const std::string& reason) const {
    const auto& m = pipeline.status().counters.refused_by_reason;
    const auto it = m.find(reason);
    return it == m.end() ? 0 : it->second;
  }
  ~Fixture() {
    if (::testing::Test::HasFailure())
      for (const std::string& w : warnings) std::printf("warning: %s\n", w.c_str());
  }
  bool warned(const std::string& a, const std::string& b) const {
    for (const std::string& w : warnings)
      if (w.find(a) != std::string::npos && w.find(b) != std::string::npos) return true;
    return false;
  }
};

LoopClosure loopClosure(int from_sample, int to_sample, double stddev = 0.02) {
  LoopClosure lc;
  lc.stamp_from = Fixture::stamp(from_sample);
  lc.stamp_to = Fixture::stamp(to_sample);
  lc.id_from = lc.id_to = -1;
  lc.from_T_to = poseToMsg(toro::Pose3::fromRollPitchYaw(0.1 * (to_sample - from_sample), 0, 0, 0, 0, 0));
  for (int k = 0; k < 6; ++k) lc.covariance[7 * k] = stddev * stddev;
  return lc;
}

LoopClosure byIds(long long from, long long to) {
  LoopClosure lc = loopClosure(0, 30);
  lc.id_from = from;
  lc.id_to = to;
  return lc;
}

}  // namespace

TEST(BadInput, NonFiniteOdometryPoseIsRefusedNamingTheStamp) {
  Fixture f;
  f.drive(10);
  const std::size_t keyframes = f.pipeline.status().keyframes;
  for (double bad : {kNaN, kInf}) {
    nav_msgs::Odometry m = odometryMsg(Fixture::stamp(f.next++), toro::Pose3());
    m.pose.pose.position.y = bad;
    f.pipeline.handleOdometry(m);
  }
  nav_msgs::Odometry zero_q = odometryMsg(Fixture::stamp(f.next++), toro::Pose3());
  zero_q.pose.pose.orientation.w = 0;
  f.pipeline.handleOdometry(zero_q);
  EXPECT_EQ(f.count("odometry: invalid message"), 3u);
  EXPECT_EQ(f.pipeline.status().counters.odometry_refused, 3u);
  EXPECT_EQ(f.pipeline.status().keyframes, keyframes);
  EXPECT_TRUE(f.warned("odometry at 101.000000000", "refused"));
  f.drive(10);  // the stream continues after the refusals
  EXPECT_GT(f.pipeline.status().keyframes, keyframes);
}

TEST(BadInput, UnusableOdometryCovarianceFallsBackToTheDefaultAndIsCounted) {
  Fixture f;
  f.drive(3);
  for (double bad : {kNaN, -1.0}) {
    nav_msgs::Odometry m =
        odometryMsg(Fixture::stamp(f.next), toro::Pose3::fromRollPitchYaw(0.1 * f.next, 0, 0, 0, 0, 0));
    ++f.next;
    m.pose.covariance[0] = bad;
    f.pipeline.handleOdometry(m);
  }
  f.drive(10);
  // The messages themselves are used (their pose is fine); the keyframes are 0.5 m apart, so
  // every odometry constraint made gets the default information.
  EXPECT_EQ(f.pipeline.status().counters.odometry_refused, 0u);
  const PipelineCounters c = f.pipeline.status().counters;
  EXPECT_EQ(c.odometry_steps_default, f.pipeline.status().keyframes - 1);
  EXPECT_EQ(c.odometry_steps_partly_default, 0u);
  EXPECT_TRUE(c.refused_by_reason.empty());  // nothing was refused
  EXPECT_TRUE(f.warned("odometry covariance rule", "step covariance"));
}

TEST(BadInput, RepeatedOdometryStampIsRefusedAsOutOfOrder) {
  Fixture f;
  f.drive(10);
  f.pipeline.handleOdometry(odometryMsg(Fixture::stamp(f.next - 1), toro::Pose3()));
  EXPECT_EQ(f.count("odometry: out of order"), 1u);
  EXPECT_EQ(f.pipeline.status().counters.time_jump_resets, 0u);
  EXPECT_TRUE(f.warned("odometry at 100.900000000", "not after the newest"));
}

TEST(BadInput, LoopClosureCovariancesAreReadPerAxisAndCounted) {
  // Zero, infinite, asymmetric and negative entries: the constraint is kept (its pose is fine), each
  // axis read on its own (covariance_rules.h), and what took defaults or a repair is counted.  The
  // stamps are keyframes' own, so the constraints hold the information as read (a stamp between
  // keyframes adds the odometry's uncertainty: test_stamp_attachment).
  Fixture f;
  f.drive(40);
  LoopClosure on_keyframes = loopClosure(0, 30);
  on_keyframes.stamp_from = f.pipeline.keyframes().records().front().stamp;
  on_keyframes.stamp_to = f.pipeline.keyframes().records().at(5).stamp;
  on_keyframes.from_T_to = poseToMsg(toro::relativePose(f.pipeline.keyframes().records().front().odom_T_base,
                                                        f.pipeline.keyframes().records().at(5).odom_T_base));
  std::vector<LoopClosure> bad(4, on_keyframes);
  bad[0].covariance.fill(0.0);
  bad[1].covariance[0] = kInf;    // x not measured at all
  bad[2].covariance[1] = 1e-4;    // (0,1) without (1,0)
  bad[3].covariance[35] = -1e-4;  // negative variance of yaw
  for (const LoopClosure& lc : bad) f.pipeline.handleLoopClosure(lc);
  const PipelineStatus s = f.pipeline.status();
  const PipelineCounters& c = s.counters;
  EXPECT_EQ(c.loop_closures_applied, 4u);
  EXPECT_EQ(c.loop_closures_refused, 0u);
  EXPECT_TRUE(c.refused_by_reason.empty());
  EXPECT_EQ(c.loop_closures_default, 1u);         // all zero
  EXPECT_EQ(c.loop_closures_partly_default, 1u);  // yaw
  EXPECT_EQ(c.loop_closures_repaired, 1u);        // the asymmetric one, averaged
  const toro::Matrix6 defaults = defaultInformation(options().loop_closure_default_stddev);
  const toro::PoseGraph& g = f.pipeline.graph();
  const std::size_t first = g.numConstraints() - 4;
  EXPECT_TRUE(g.constraints()[first].information.isApprox(defaults));
  EXPECT_LE(g.constraints()[first + 1].information(0, 0), 1e-6);  // unmeasured: ~0, not the default
  EXPECT_NEAR(g.constraints()[first + 1].information(1, 1), 1 / (0.02 * 0.02), 1e-6);
  EXPECT_NEAR(g.constraints()[first + 3].information(5, 5), defaults(5, 5), 1e-9);
  EXPECT_NEAR(g.constraints()[first + 3].information(4, 4), 4 / (0.02 * 0.02), 1e-6);
  EXPECT_NE(s.loop_closure_covariance_rule.find("unknown"), std::string::npos)
      << s.loop_closure_covariance_rule;
  EXPECT_TRUE(f.warned("loop closure covariance", "unknown"));
}

TEST(BadInput, ALoopClosureWithEveryAxisUnmeasuredIsRefusedWithTheReason) {
  // Variance 1e6 (or infinity) on all six axes: it would constrain nothing, so it is refused and
  // counted rather than applied with ~0 information; one measured axis is enough to apply it.
  Fixture f;
  f.drive(40);
  LoopClosure nothing = loopClosure(0, 30);
  nothing.covariance.fill(0.0);
  for (int i = 0; i < 6; ++i) nothing.covariance[i * 7] = i == 5 ? kInf : 1e6;
  const std::size_t constraints = f.pipeline.graph().numConstraints();
  f.pipeline.handleLoopClosure(nothing);
  EXPECT_EQ(f.count("loop closure: no measured axis"), 1u);
  EXPECT_EQ(f.pipeline.graph().numConstraints(), constraints);
  EXPECT_TRUE(f.warned("loop closure", "constrains nothing"));
  LoopClosure yaw_only = nothing;
  yaw_only.covariance[35] = 1e-4;
  f.pipeline.handleLoopClosure(yaw_only);
  EXPECT_EQ(f.pipeline.status().counters.loop_closures_applied, 1u);
  EXPECT_EQ(f.pipeline.graph().numConstraints(), constraints + 1);
  // The same message again after its refusal is refused for the same reason, not as a duplicate.
  f.pipeline.handleLoopClosure(nothing);
  EXPECT_EQ(f.count("loop closure: no measured axis"), 2u);
}

TEST(BadInput, NonFiniteLoopClosurePoseIsRefused) {
  Fixture f;
  f.drive(40);
  LoopClosure lc = loopClosure(0, 30);
  lc.from_T_to.orientation.x = kNaN;
  f.pipeline.handleLoopClosure(lc);
  EXPECT_EQ(f.count("loop closure: invalid message"), 1u);
  EXPECT_EQ(f.pipeline.status().counters.loop_closures_applied, 0u);
  EXPECT_TRUE(f.warned("loop closure", "from_T_to"));
}

TEST(BadInput, SelfLoopsAreRefusedTwoStampsNearOneKeyframeSpanTwo) {
  Fixture f;
  f.drive(40);
  f.pipeline.handleLoopClosure(byIds(3, 3));          // one id twice
  f.pipeline.handleLoopClosure(loopClosure(30, 30));  // one stamp twice
  LoopClosure near = loopClosure(0, 30);              // two stamps, one keyframe
  near.stamp_from = f.pipeline.keyframes().records().at(3).stamp;
  near.stamp_to = near.stamp_from + ros::Duration(0.05);
  f.pipeline.handleLoopClosure(near);
  EXPECT_EQ(f.count("loop closure: invalid message"), 2u);
  // The later stamp moves on to the next keyframe, the odometry between carrying the measurement.
  EXPECT_EQ(f.count("loop closure: both ends on one keyframe"), 0u);
  ASSERT_EQ(f.pipeline.status().counters.loop_closures_applied, 1u);
  const toro::Constraint& c = f.pipeline.graph().constraints().back();
  EXPECT_EQ(c.from, f.pipeline.keyframes().records().at(3).id);
  EXPECT_EQ(c.to, f.pipeline.keyframes().records().at(4).id);
}

TEST(BadInput, FarPastStampIsRefusedFarFutureWaitsAndIsBounded) {
  Fixture f;
  f.drive(40);
  const std::size_t constraints = f.pipeline.status().constraints;
  f.pipeline.handleLoopClosure(loopClosure(-900, 30));  // 10 s before the first odometry
  EXPECT_EQ(f.count("loop closure: no keyframe within tolerance"), 1u);
  LoopClosure future = loopClosure(0, 30);
  future.stamp_to = ros::Time(4000000000u, 0);  // year 2096: waits for odometry to get there
  f.pipeline.handleLoopClosure(future);
  f.drive(20);
  EXPECT_EQ(f.pipeline.status().pending_loop_closures, 1u);
  EXPECT_EQ(f.pipeline.status().constraints, f.pipeline.status().keyframes - 1);  // odometry only
  EXPECT_GT(f.pipeline.status().constraints, constraints);
  EXPECT_EQ(f.pipeline.status().counters.loop_closures_applied, 0u);
  f.pipeline.reset("test");
  EXPECT_EQ(f.pipeline.status().pending_loop_closures, 0u);
  EXPECT_EQ(f.count("loop closure: dropped by reset"), 1u);
}

TEST(BadInput, UnknownIdIsRefused) {
  Fixture f;
  f.drive(40);
  f.pipeline.handleLoopClosure(byIds(0, 1000));
  EXPECT_EQ(f.count("loop closure: unknown node id"), 1u);
  EXPECT_TRUE(f.warned("loop closure", "1000"));
}

TEST(BadInput, ResentLoopClosureIsRefusedAsDuplicateASecondMeasurementIsKept) {
  // The same message twice (resent by a bridge) is one measurement: the copy is refused.  A
  // second, different measurement of the same pair is independent and kept (twice the
  // information, which the optimiser handles).
  Fixture f;
  f.drive(40);
  const std::size_t constraints = f.pipeline.status().constraints;
  const LoopClosure first = loopClosure(0, 30);
  f.pipeline.handleLoopClosure(first);
  f.pipeline.handleLoopClosure(first);
  EXPECT_EQ(f.pipeline.status().counters.loop_closures_applied, 1u);
  EXPECT_EQ(f.count("loop closure: duplicate message"), 1u);
  EXPECT_TRUE(f.warned("loop closure", "applied before"));
  LoopClosure second = first;
  second.from_T_to.position.x += 0.01;
  f.pipeline.handleLoopClosure(second);
  EXPECT_EQ(f.pipeline.status().counters.loop_closures_applied, 2u);
  EXPECT_EQ(f.pipeline.status().constraints, constraints + 2);
  const OptimizeResult r = f.pipeline.optimize(5, "full");
  EXPECT_TRUE(r.success) << r.message;
  EXPECT_LE(r.chi2_after, r.chi2_before + 1e-9);
}

TEST(BadInput, ServicesOnAnEmptyGraph) {
  Fixture f;
  const OptimizeResult r = f.pipeline.optimize(0, "full");
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("no constraints"), std::string::npos) << r.message;
  const std::string path = ::testing::TempDir() + "/toro_empty.g2o";
  std::remove(path.c_str());
  EXPECT_EQ(f.pipeline.saveGraph(path), "nothing to save: the graph is empty");
  EXPECT_NE(f.pipeline.loadGraph(path).find("cannot open"), std::string::npos);
  EXPECT_EQ(f.pipeline.status().keyframes, 0u);
  f.drive(10);  // usable afterwards
  EXPECT_GT(f.pipeline.status().keyframes, 0u);
}

TEST(BadInput, SaveToAnUnwritablePathAndLoadOfAMissingFileSayWhy) {
  Fixture f;
  f.drive(20);
  const std::string save_error = f.pipeline.saveGraph("/nonexistent_dir_toro/graph.g2o");
  EXPECT_NE(save_error.find("/nonexistent_dir_toro/graph.g2o"), std::string::npos) << save_error;
  const std::string load_error = f.pipeline.loadGraph("/nonexistent_dir_toro/missing.g2o");
  EXPECT_NE(load_error.find("missing.g2o"), std::string::npos) << load_error;
  EXPECT_EQ(f.pipeline.status().keyframes, 4u);  // a failed load leaves the pipeline untouched
}

TEST(BadInput, TruncatedOrGarbageGraphFilesAreRefusedWithTheLine) {
  Fixture f;
  f.drive(20);
  const std::string good = ::testing::TempDir() + "/toro_good.g2o";
  ASSERT_EQ(f.pipeline.saveGraph(good), "");
  std::ifstream in(good);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string truncated = ::testing::TempDir() + "/toro_truncated.g2o";
  // Cut in the middle of the last edge's numbers.  (A cut inside a tag, "ED", cannot be told from
  // a tag of another tool, which g2o readers skip; see the report of issue 6.)
  std::ofstream(truncated) << text.substr(0, text.rfind("EDGE_SE3:QUAT") + 30);
  const std::string garbage = ::testing::TempDir() + "/toro_garbage.g2o";
  std::ofstream(garbage) << "VERTEX_SE3:QUAT 0 1 2 3\n\x01\x02 garbage \xff\n";
  for (const std::string& path : {truncated, garbage}) {
    const std::string error = f.pipeline.loadGraph(path);
    EXPECT_NE(error.find(":"), std::string::npos) << error;  // "file:line: reason"
    std::printf("%s\n", error.c_str());
    EXPECT_EQ(f.pipeline.status().keyframes, 4u) << path;
  }
}
