// Planar mode in the core: the SE(2) value type, the projection onto the plane, and TORO in SE(2)
// against TORO in SE(3) on the same planar graphs.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "shared_datasets.h"
#include "toro_ros/core/finish_residuals.h"  // wrapAngle
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/planar.h"
#include "toro_ros/core/random_draws.h"
#include "toro_ros/core/tree_optimizer.h"

using namespace toro;

namespace {

Pose3 planarPose(double x, double y, double yaw) { return Pose3::fromRollPitchYaw(x, y, 0, 0, 0, yaw); }

// Planar information with the given standard deviations, lifted as a 2D file's (planar.h).
Matrix6 planarInformation(double translation_sigma, double yaw_sigma) {
  Matrix6 angle_units = Matrix6::Zero();
  angle_units.diagonal() << 1 / (translation_sigma * translation_sigma),
      0.7 / (translation_sigma * translation_sigma), 1, 1, 1, 1 / (yaw_sigma * yaw_sigma);
  angle_units(0, 1) = angle_units(1, 0) = 0.1 / (translation_sigma * translation_sigma);
  return projectInformationToPlane(angleToQuaternionUnits(angle_units));
}

// A planar robot driving `laps` laps of a 10 m x 6 m rectangle (1 m steps), odometry with noise in
// x, y and yaw, loop closures from every third pose of a later lap to the same pose of the first.
// A 2D graph (k2D) whose poses are the truth.
PoseGraph planarLaps(int laps, std::uint32_t seed, double yaw_noise = 0.01) {
  std::vector<Pose3> truth;
  Pose3 pose;
  for (int lap = 0; lap < laps; ++lap) {
    for (int side = 0; side < 4; ++side) {
      const int steps = side % 2 == 0 ? 10 : 6;
      for (int step = 0; step < steps; ++step) {
        truth.push_back(pose);
        pose = pose * planarPose(1.0, 0, step == steps - 1 ? M_PI / 2 : 0.0);
      }
    }
  }
  const std::size_t per_lap = truth.size() / static_cast<std::size_t>(laps);
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  const auto noisy = [&](const Pose3& z) {
    const auto d = drawLastFirst<3>(n, rng);
    return z * planarPose(0.02 * d[0], 0.02 * d[1], yaw_noise * d[2]);
  };
  PoseGraph g;
  g.setDimension(GraphDimension::k2D);
  for (std::size_t i = 0; i < truth.size(); ++i) g.addNode(static_cast<NodeId>(i), truth[i]);
  const Matrix6 info = planarInformation(0.02, 0.01);
  for (std::size_t i = 0; i + 1 < truth.size(); ++i)
    g.addConstraint(Constraint{static_cast<NodeId>(i), static_cast<NodeId>(i + 1),
                               noisy(relativePose(truth[i], truth[i + 1])), info});
  for (std::size_t i = per_lap; i < truth.size(); i += 3)
    g.addConstraint(Constraint{static_cast<NodeId>(i % per_lap), static_cast<NodeId>(i),
                               noisy(relativePose(truth[i % per_lap], truth[i])), info});
  return g;
}

TreeOptimizerOptions withParameterization(Parameterization p, TreeOptimizerOptions o = {}) {
  o.parameterization = p;
  return o;
}

// Largest position and rotation differences between the poses of two graphs with the same nodes.
struct PoseDifference {
  double translation = 0.0;
  double rotation = 0.0;
};
PoseDifference largestDifference(const PoseGraph& a, const PoseGraph& b) {
  PoseDifference d;
  for (std::size_t i = 0; i < a.numNodes(); ++i) {
    const Pose3& p = a.node(i).pose;
    const Pose3& q = b.pose(a.node(i).id);
    d.translation = std::max(d.translation, (p.translation() - q.translation()).norm());
    d.rotation = std::max(d.rotation, relativePose(p, q).angle());
  }
  return d;
}

bool allExactlyPlanar(const PoseGraph& g) {
  for (const Node& n : g.nodes())
    if (!isExactlyPlanar(n.pose)) return false;
  return true;
}

}  // namespace

// ---- the SE(2) value type ----------------------------------------------------------------------

TEST(Pose2, CompositionAndInverseMatchPose3InThePlane) {
  const Pose3 a = planarPose(1.5, -0.3, 2.9), b = planarPose(-0.7, 2.0, -2.2);
  const Pose2 pa = planarPart(a), pb = planarPart(b);
  const Pose3 ab = liftToPose3(pa * pb);
  EXPECT_LT((ab.translation() - (a * b).translation()).norm(), 1e-14);
  EXPECT_LT(relativePose(ab, a * b).angle(), 1e-14);
  const Pose3 inv = liftToPose3(pa.inverse());
  EXPECT_LT((inv.translation() - a.inverse().translation()).norm(), 1e-14);
  EXPECT_LT(relativePose(inv, a.inverse()).angle(), 1e-14);
  EXPECT_TRUE(isExactlyPlanar(ab));
  EXPECT_TRUE(isExactlyPlanar(inv));
  // Every heading, including the half-turn where the quaternion's w vanishes.
  for (double theta : {0.0, 1e-9, 0.5, M_PI / 2, 3.0, M_PI, -M_PI, -3.1, -1e-7}) {
    const Pose3 lifted = liftToPose3(Pose2::fromXYTheta(0.1, 0.2, theta));
    EXPECT_NEAR(relativePose(lifted, planarPose(0.1, 0.2, theta)).angle(), 0.0, 1e-15) << theta;
    EXPECT_NEAR(std::abs(wrapAngle(planarPart(lifted).angle() - theta)), 0.0, 1e-15) << theta;
  }
}

TEST(Pose2, SeriesForSmallAnglesAgreeWithTheLibraryFunctions) {
  // rotation2FromAngle and Rotation2::angle switch to series near 0: on both sides of the switch
  // they must agree with cos, sin and atan2 to rounding.
  for (double theta = -0.3; theta <= 0.3; theta += 0.000731) {
    const Rotation2 r = rotation2FromAngle(theta);
    EXPECT_NEAR(r.cos(), std::cos(theta), 3e-16) << theta;
    EXPECT_NEAR(r.sin(), std::sin(theta), 3e-16) << theta;
    EXPECT_NEAR(Rotation2(std::cos(theta), std::sin(theta)).angle(), theta, 4e-16) << theta;
  }
  EXPECT_NEAR(Rotation2::fromAngle(-2.5).angle(), -2.5, 1e-15);
  EXPECT_NEAR(Rotation2::fromAngle(3.0).angle(), 3.0, 1e-15);
}

TEST(Pose2, PlanarPartDropsZRollAndPitchAndKeepsTheHeading) {
  const Pose3 tilted = Pose3::fromRollPitchYaw(1.0, 2.0, 0.7, 0.2, -0.3, 1.1);
  const Pose2 p = planarPart(tilted);
  EXPECT_DOUBLE_EQ(p.translation().x(), 1.0);
  EXPECT_DOUBLE_EQ(p.translation().y(), 2.0);
  EXPECT_NEAR(p.angle(), tilted.rollPitchYaw().z(), 1e-15);
  const Pose3 projected = projectToPlane(tilted);
  EXPECT_TRUE(isExactlyPlanar(projected));
  EXPECT_EQ(projected.translation().z(), 0.0);
  const Vector3 rpy = projected.rollPitchYaw();
  EXPECT_EQ(rpy.x(), 0.0);
  EXPECT_EQ(rpy.y(), 0.0);
  EXPECT_NEAR(rpy.z(), 1.1, 1e-15);
}

// ---- the projection ------------------------------------------------------------------------------

TEST(ProjectToPlane, KeepsTheXYYawInformationAndChangesNothingOnA2DFile) {
  Matrix6 info = Matrix6::Identity();
  info.diagonal() << 100, 200, 1e-6, 4e-6, 4e-6, 400;  // the ROS planar convention, g2o units
  info(0, 5) = info(5, 0) = 3;
  info(2, 3) = info(3, 2) = 1e-7;  // out-of-plane correlations are dropped
  const Matrix6 projected = projectInformationToPlane(info);
  for (int i : {0, 1, 5})
    for (int j : {0, 1, 5}) EXPECT_EQ(projected(i, j), info(i, j)) << i << ", " << j;
  EXPECT_EQ(projected(2, 3), 0.0);
  EXPECT_EQ(projectInformationToPlane(projected), projected);  // idempotent, bit for bit

  TORO_REQUIRE_DATASETS();
  const PoseGraph g = readGraph(toro_test::datasetPath("2d/intel.g2o"));
  const PoseGraph p = projectToPlane(g);
  ASSERT_EQ(p.dimension(), GraphDimension::k2D);
  ASSERT_EQ(p.numConstraints(), g.numConstraints());
  for (std::size_t c = 0; c < g.numConstraints(); ++c) {
    EXPECT_EQ(p.constraints()[c].information, g.constraints()[c].information) << c;
    EXPECT_EQ(p.constraints()[c].measurement.rotation().coeffs(),
              g.constraints()[c].measurement.rotation().coeffs());
  }
  for (std::size_t i = 0; i < g.numNodes(); ++i)
    EXPECT_EQ(p.node(i).pose.translation(), g.node(i).pose.translation()) << i;
}

// ---- TORO in SE(2) against TORO in SE(3) ---------------------------------------------------------

TEST(PlanarTree, ChoosesTheGroupOnceFromTheOptions) {
  const PoseGraph planar = planarLaps(2, 1);
  PoseGraph spatial = planar;
  spatial.setDimension(GraphDimension::k3D);
  TreeOptimizer from_graph;
  from_graph.setGraph(planar);
  EXPECT_TRUE(from_graph.planar());
  from_graph.setGraph(spatial);
  EXPECT_FALSE(from_graph.planar());
  TreeOptimizer forced_3d(withParameterization(Parameterization::kSpatial));
  forced_3d.setGraph(planar);
  EXPECT_FALSE(forced_3d.planar());
  EXPECT_EQ(forced_3d.graph().dimension(), GraphDimension::k2D);  // the graph keeps its meaning
  TreeOptimizer forced_planar(withParameterization(Parameterization::kPlanar));
  EXPECT_TRUE(forced_planar.planar());  // before any graph: online growth is planar too
  EXPECT_EQ(forced_planar.graph().dimension(), GraphDimension::k2D);
  forced_planar.setGraph(spatial);
  EXPECT_TRUE(forced_planar.planar());
  EXPECT_EQ(forced_planar.graph().dimension(), GraphDimension::k2D);
}

TEST(PlanarTree, EqualsTheSpatialCodeOnAPlanarGraph) {
  const PoseGraph g = planarLaps(3, 5);
  TreeOptimizer planar(withParameterization(Parameterization::kPlanar));
  TreeOptimizer spatial(withParameterization(Parameterization::kSpatial));
  planar.setGraph(g);
  spatial.setGraph(g);
  const PoseDifference start = largestDifference(planar.graph(), spatial.graph());
  EXPECT_LT(start.translation, 1e-12);
  const double chi2_start = g2oChi2(spatial.graph());
  for (int k = 0; k < 30; ++k) {
    planar.iterate();
    spatial.iterate();
  }
  // The same algorithm in two groups: the poses agree to rounding, while TORO moved them by metres.
  const PoseDifference d = largestDifference(planar.graph(), spatial.graph());
  EXPECT_LT(d.translation, 1e-9);
  EXPECT_LT(d.rotation, 1e-11);
  EXPECT_LT(g2oChi2(spatial.graph()), 0.1 * chi2_start);
  EXPECT_NEAR(g2oChi2(planar.graph()), g2oChi2(spatial.graph()), 1e-9 * g2oChi2(spatial.graph()));
  EXPECT_TRUE(allExactlyPlanar(planar.graph()));
}

TEST(PlanarTree, OnlineGrowthEqualsTheSpatialCodeAndABatchStart) {
  const PoseGraph g = planarLaps(2, 9);
  // In the order a robot makes them: each loop closure right after the odometry that reaches it.
  std::vector<Constraint> by_time = g.constraints();
  std::stable_sort(by_time.begin(), by_time.end(), [](const Constraint& a, const Constraint& b) {
    return std::max(a.from, a.to) < std::max(b.from, b.to);
  });
  TreeOptimizer planar(withParameterization(Parameterization::kPlanar));
  TreeOptimizer spatial(withParameterization(Parameterization::kSpatial));
  for (TreeOptimizer* opt : {&planar, &spatial}) {
    // Keyframes as the pipeline adds them: each new node continues from its predecessor's
    // corrected pose; after every loop closure a few affected passes.
    for (const Constraint& c : by_time) {
      if (!opt->graph().hasNode(c.from)) opt->addNode(c.from, g.pose(c.from));
      if (!opt->graph().hasNode(c.to)) opt->addNode(c.to, opt->graph().pose(c.from) * c.measurement);
      opt->addConstraint(c);
      if (isLoopClosure(c))
        for (std::size_t k = 1; k <= 3; ++k) opt->iterateAffected(k);
    }
    for (int k = 0; k < 10; ++k) opt->iterate();
  }
  const PoseDifference d = largestDifference(planar.graph(), spatial.graph());
  EXPECT_LT(d.translation, 1e-9);
  EXPECT_LT(d.rotation, 1e-11);
  EXPECT_TRUE(allExactlyPlanar(planar.graph()));
  EXPECT_EQ(planar.tree().parents(), spatial.tree().parents());
}

TEST(PlanarTree, OneUpdateKeepsTheTopAndMovesOnlyThePathAndItsSubtrees) {
  // Branches 1 -> 2 -> 4 and 1 -> 3 -> 5 below the root 0, a side branch 2 -> 6, and a wrong
  // constraint 4 -> 5 whose path is 4, 2 | 1 (top) | 3, 5.
  const Pose3 step = planarPose(1, 0.5, 0.3);
  PoseGraph g;
  g.setDimension(GraphDimension::k2D);
  for (NodeId i = 0; i < 7; ++i) g.addNode(i, Pose3());
  const Matrix6 info = planarInformation(0.1, 0.05);
  g.addConstraint(Constraint{0, 1, step, info});
  g.addConstraint(Constraint{1, 2, step, info});
  g.addConstraint(Constraint{1, 3, step.inverse(), info});
  g.addConstraint(Constraint{2, 4, step, info});
  g.addConstraint(Constraint{3, 5, step, info});
  g.addConstraint(Constraint{2, 6, step * step, info});
  g.addConstraint(Constraint{4, 5, planarPose(0.3, 0.2, 0.4), info});
  const std::size_t c = g.numConstraints() - 1;
  for (double rate : {0.5, 1e9}) {
    TreeOptimizer opt(withParameterization(Parameterization::kPlanar));
    opt.setGraph(g);
    ASSERT_EQ(opt.tree().topNode(g.indexOf(4), g.indexOf(5)), g.indexOf(1));
    const PoseGraph before = opt.graph();
    const double chi2_before = constraintChi2(before, c);
    opt.applyUpdate(c, rate);
    const double chi2_after = constraintChi2(opt.graph(), c);
    EXPECT_LT(chi2_after, 0.9 * chi2_before) << rate;
    if (rate > 1.0) {
      EXPECT_LT(chi2_after, 1e-20) << "a full step closes the constraint exactly";
    }
    for (NodeId id : {0, 1}) {
      EXPECT_EQ(opt.graph().pose(id).translation(), before.pose(id).translation()) << id;
      EXPECT_EQ(opt.graph().pose(id).rotation().coeffs(), before.pose(id).rotation().coeffs()) << id;
    }
    for (NodeId id : {2, 3, 4, 5})
      EXPECT_GT((opt.graph().pose(id).translation() - before.pose(id).translation()).norm() +
                    relativePose(opt.graph().pose(id), before.pose(id)).angle(),
                1e-4)
          << id;
    // Node 6 hangs off the path at 2: it moves rigidly with 2.
    const Pose3 rigid_before = relativePose(before.pose(2), before.pose(6));
    const Pose3 rigid_after = relativePose(opt.graph().pose(2), opt.graph().pose(6));
    EXPECT_LT((rigid_after.translation() - rigid_before.translation()).norm(), 1e-12);
    EXPECT_LT(relativePose(rigid_after, rigid_before).angle(), 1e-12);
    EXPECT_TRUE(allExactlyPlanar(opt.graph()));
  }
}

TEST(PlanarTree, RobustWeightsBehaveAsInTheSpatialCode) {
  // A wrong loop closure (node 5 claimed to be 4 m from where it is) among right ones.
  PoseGraph g = planarLaps(2, 3);
  Constraint wrong;
  wrong.from = 5;
  wrong.to = 40;
  wrong.measurement = planarPose(4.0, -1.0, 0.6);
  wrong.information = g.constraints().back().information;
  const std::size_t wrong_index = g.addConstraint(wrong);
  TreeOptimizerOptions robust;
  robust.robust = RobustOptions{RobustKernel::kDcs, 1.0};
  TreeOptimizer planar(withParameterization(Parameterization::kPlanar, robust));
  TreeOptimizer spatial(withParameterization(Parameterization::kSpatial, robust));
  for (TreeOptimizer* opt : {&planar, &spatial}) {
    opt->setGraph(g, InitialGuess::kChainOdometry);
    for (int k = 0; k < 30; ++k) opt->iterate();
  }
  ASSERT_EQ(planar.weights().size(), g.numConstraints());
  for (std::size_t c = 0; c < g.numConstraints(); ++c) {
    EXPECT_EQ(planar.isRobust(c), spatial.isRobust(c)) << c;
    EXPECT_NEAR(planar.weights()[c], spatial.weights()[c], 1e-9) << c;
  }
  EXPECT_LT(planar.weights()[wrong_index], 1e-3);
  EXPECT_LT(largestDifference(planar.graph(), spatial.graph()).translation, 1e-8);
  EXPECT_TRUE(allExactlyPlanar(planar.graph()));
}

TEST(PlanarTree, ThreeDimensionalInputEndsExactlyPlanar) {
  // The planar graph with out-of-plane noise on every measurement and pose (2 cm, 0.02 rad, applied
  // in the body frame, so x, y and the heading stay those of the planar graph) and the ROS planar
  // covariance convention (variance 1e6 on z, roll and pitch): the planar optimiser sees the planar
  // graph and stays in the plane exactly, whatever the out-of-plane parts claim.
  const PoseGraph planar_truth = planarLaps(3, 11);
  std::mt19937 rng(4);
  std::normal_distribution<double> n(0.0, 0.02);
  PoseGraph tilted;
  const auto tilt = [&] {
    const auto d = drawLastFirst<3>(n, rng);
    return Pose3::fromRollPitchYaw(0, 0, d[0], d[1], d[2], 0);
  };
  for (const Node& node : planar_truth.nodes()) tilted.addNode(node.id, node.pose * tilt());
  for (Constraint c : planar_truth.constraints()) {
    c.measurement = c.measurement * tilt();
    for (int axis : {2, 3, 4}) c.information(axis, axis) = 1e-6;
    tilted.addConstraint(c);
  }
  TreeOptimizer opt(withParameterization(Parameterization::kPlanar));
  opt.setGraph(tilted, InitialGuess::kFromGraph);
  EXPECT_TRUE(allExactlyPlanar(opt.graph()));
  for (int k = 0; k < 20; ++k) opt.iterate();
  EXPECT_TRUE(allExactlyPlanar(opt.graph()));
  EXPECT_EQ(opt.graph().dimension(), GraphDimension::k2D);
  TreeOptimizer reference(withParameterization(Parameterization::kPlanar));
  reference.setGraph(planar_truth, InitialGuess::kFromGraph);
  for (int k = 0; k < 20; ++k) reference.iterate();
  EXPECT_LT(largestDifference(opt.graph(), reference.graph()).translation, 1e-9);
  // Online growth by 3D poses and constraints as well.
  TreeOptimizer online(withParameterization(Parameterization::kPlanar));
  for (const Node& node : tilted.nodes()) online.addNode(node.id, node.pose);
  for (const Constraint& c : tilted.constraints()) online.addConstraint(c);
  online.iterateAffected(1);
  online.iterate();
  EXPECT_TRUE(allExactlyPlanar(online.graph()));
}

TEST(PlanarTree, NaiveRotationUpdateIsTheExactOneInThePlane) {
  // Planar rotations commute, so spreading angle shares is exact: the naive option must not change
  // the planar result.
  const PoseGraph g = planarLaps(2, 21, 0.05);
  TreeOptimizerOptions naive;
  naive.rotation_update = RotationUpdate::kNaiveEuler;
  TreeOptimizer a(withParameterization(Parameterization::kPlanar, naive));
  TreeOptimizer b(withParameterization(Parameterization::kPlanar));
  a.setGraph(g);
  b.setGraph(g);
  for (int k = 0; k < 10; ++k) {
    a.iterate();
    b.iterate();
  }
  EXPECT_EQ(largestDifference(a.graph(), b.graph()).translation, 0.0);
}

TEST(PlanarTreeDatasets, IntelEqualsTheSpatialCodeAfter100Iterations) {
  TORO_REQUIRE_DATASETS();
  const PoseGraph g = readGraph(toro_test::datasetPath("2d/intel.g2o"));
  TreeOptimizer planar(withParameterization(Parameterization::kPlanar));
  TreeOptimizer spatial(withParameterization(Parameterization::kSpatial));
  planar.setGraph(g);
  spatial.setGraph(g);
  for (int k = 0; k < 100; ++k) {
    planar.iterate();
    spatial.iterate();
  }
  EXPECT_LT(largestDifference(planar.graph(), spatial.graph()).translation, 1e-8);
  EXPECT_NEAR(g2oChi2(planar.graph()), g2oChi2(spatial.graph()), 1e-9 * g2oChi2(spatial.graph()));
  EXPECT_LT(g2oChi2(planar.graph()), 50.0);  // 551.7 at the start, best known 45.0047
}

TEST(PlanarOptimize, ThreeDimensionalGraphIsProjectedAndFinishedInThePlane) {
  // optimizeGraph with a planar TORO: the caller's graph is projected, TORO and the finish run in
  // SE(2), and the result is the planar optimum of the projection.
  PoseGraph tilted;
  const PoseGraph g = planarLaps(2, 13);
  for (const Node& node : g.nodes())
    tilted.addNode(node.id, node.pose * Pose3::fromRollPitchYaw(0, 0, 0.1, 0.05, 0, 0));
  for (Constraint c : g.constraints()) {
    c.measurement = c.measurement * Pose3::fromRollPitchYaw(0, 0, 0.03, 0, 0.02, 0);
    tilted.addConstraint(c);
  }
  OptimizeOptions planar;
  planar.toro.parameterization = Parameterization::kPlanar;
  const OptimizeReport report = optimizeGraph(tilted, planar);
  EXPECT_EQ(tilted.dimension(), GraphDimension::k2D);
  EXPECT_TRUE(allExactlyPlanar(tilted));
  PoseGraph reference = g;
  optimizeGraph(reference, OptimizeOptions{});
  EXPECT_NEAR(report.final_chi2, g2oChi2(reference), 1e-6 * g2oChi2(reference));
  EXPECT_LT(largestDifference(tilted, reference).translation, 1e-6);
}
