#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "shared_datasets.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/synthetic.h"
#include "toro_ros/core/tree_optimizer.h"

using namespace toro;

namespace {

Constraint between(NodeId a, NodeId b, const Pose3& measurement, double info = 1.0) {
  Constraint c;
  c.from = a;
  c.to = b;
  c.measurement = measurement;
  c.information = info * Matrix6::Identity();
  return c;
}

double poseDistance(const Pose3& a, const Pose3& b) {
  return (a.translation() - b.translation()).norm() + relativePose(a, b).angle();
}

// Residual of one constraint at the optimiser's current poses: angle + translation of Z^-1 Xi^-1 Xj.
double residual(const TreeOptimizer& opt, std::size_t c) {
  const Constraint& k = opt.graph().constraints()[c];
  const Pose3 d = k.measurement.inverse() * relativePose(opt.graph().pose(k.from), opt.graph().pose(k.to));
  return d.angle() + d.translation().norm();
}


}  // namespace

TEST(TreeOptimizer, ChainedInitialGuessComposesMeasurementsAlongTheTree) {
  PoseGraph g;
  for (NodeId i = 0; i < 4; ++i) g.addNode(i, Pose3());
  const Pose3 z01 = Pose3::fromRollPitchYaw(1, 0, 0, 0, 0, 0.5);
  const Pose3 z12 = Pose3::fromRollPitchYaw(1, 0.2, 0, 0.1, 0, 0);
  const Pose3 z32 = Pose3::fromRollPitchYaw(0, 0, 1, 0, 0.3, 0);  // stored 3 -> 2: inverted when chained
  g.addConstraint(between(0, 1, z01));
  g.addConstraint(between(1, 2, z12));
  g.addConstraint(between(3, 2, z32));
  TreeOptimizer opt;
  opt.setGraph(g, InitialGuess::kChainOnTree);
  EXPECT_LT(poseDistance(opt.graph().pose(2), z01 * z12), 1e-12);
  EXPECT_LT(poseDistance(opt.graph().pose(3), z01 * z12 * z32.inverse()), 1e-12);
  // kFromGraph keeps the stored (identity) poses.
  opt.setGraph(g, InitialGuess::kFromGraph);
  EXPECT_LT(poseDistance(opt.graph().pose(3), Pose3()), 1e-12);
}

namespace {

// Two branches below node 1: 1 -> 2 -> 4 and 1 -> 3 -> 5, a side branch 2 -> 6, the root 0 above 1,
// all measured consistently; then constraint 4 -> 5 (the last one) carries an error.  Its path is
// 4, 2 | 1 (top) | 3, 5.
PoseGraph twoBranchGraph(const Pose3& step, const Pose3& wrong) {
  PoseGraph g;
  for (NodeId i = 0; i < 7; ++i) g.addNode(i, Pose3());
  g.addConstraint(between(0, 1, step));
  g.addConstraint(between(1, 2, step));
  g.addConstraint(between(1, 3, step.inverse()));
  g.addConstraint(between(2, 4, step));
  g.addConstraint(between(3, 5, step));
  g.addConstraint(between(2, 6, step * step));
  g.addConstraint(between(4, 5, wrong));
  return g;
}

}  // namespace

TEST(TreeOptimizer, OneUpdateKeepsTheTopAndMovesOnlyThePathAndItsSubtrees) {
  const PoseGraph g = twoBranchGraph(Pose3::fromRollPitchYaw(1, 0.5, 0, 0.1, 0.2, 0.3),
                                     Pose3::fromRollPitchYaw(0.3, 0.2, 0.1, 0.2, 0.1, 0.4));
  const std::size_t c = g.numConstraints() - 1;
  TreeOptimizer opt;
  opt.setGraph(g);
  ASSERT_EQ(opt.tree().topNode(g.indexOf(4), g.indexOf(5)), g.indexOf(1));
  const PoseGraph before = opt.graph();
  const double residual_before = residual(opt, c);
  opt.applyUpdate(c, 0.5);
  EXPECT_LT(residual(opt, c), residual_before);
  for (NodeId id : {0, 1}) EXPECT_LT(poseDistance(opt.graph().pose(id), before.pose(id)), 1e-12) << id;
  for (NodeId id : {2, 3, 4, 5}) EXPECT_GT(poseDistance(opt.graph().pose(id), before.pose(id)), 1e-4) << id;
  // Node 6 hangs off the path at 2: it moves rigidly with 2.
  EXPECT_LT(poseDistance(relativePose(opt.graph().pose(2), opt.graph().pose(6)),
                         relativePose(before.pose(2), before.pose(6))),
            1e-12);
}

TEST(TreeOptimizer, FullStepRemovesTheWholeErrorEvenForLargeRotations) {
  // Large rotations about different axes along the path: here rotations do not commute, and the
  // slerp update with the incremental decomposition (Eq. 19) must still close the constraint exactly.
  const PoseGraph g = twoBranchGraph(Pose3::fromRollPitchYaw(1.0, 0.2, 0.1, 0.9, -0.7, 1.3),
                                     Pose3::fromRollPitchYaw(2.0, 1.0, -1.0, 2.5, 0.5, -2.2));
  const std::size_t c = g.numConstraints() - 1;
  for (double share_scale : {1.0, 1e-3, 1e3}) {
    // Unequal stiffness along the path must not matter for exactness either.
    PoseGraph h = g;
    h.setDimension(GraphDimension::k3D);
    TreeOptimizer opt;
    opt.setGraph(h);
    ASSERT_GT(residual(opt, c), 1.0);
    opt.applyUpdate(c, 1e9 * share_scale);  // fraction clamps at 1: the whole error
    EXPECT_LT(residual(opt, c), 1e-9) << share_scale;
  }
  // The naive update (equal shares of Euler angle error) cannot close it in one full step.
  TreeOptimizerOptions naive;
  naive.rotation_update = RotationUpdate::kNaiveEuler;
  TreeOptimizer opt(naive);
  opt.setGraph(g);
  opt.applyUpdate(c, 1e9);
  EXPECT_GT(residual(opt, c), 1e-3);
}

TEST(TreeOptimizer, ConvergesOnASyntheticSphere) {
  NoiseOptions noise;
  noise.translation_sigma_m = 0.01;
  noise.rotation_sigma_rad = 0.002;
  noise.seed = 7;
  const SyntheticGraph s = makeSphere(15, 40, 10.0, noise);
  TreeOptimizer opt;
  opt.setGraph(s.graph, InitialGuess::kChainOnTree);
  const double chi2_start = g2oChi2(opt.graph());
  const double error_start = meanPositionError(opt.graph(), s.ground_truth);
  for (int i = 0; i < 100; ++i) opt.iterate();
  const double chi2_end = g2oChi2(opt.graph());
  const double error_end = meanPositionError(opt.graph(), s.ground_truth);
  std::cout << "sphere: chi2 " << chi2_start << " -> " << chi2_end << ", mean position error " << error_start
            << " -> " << error_end << " m, rotation error " << meanRotationError(opt.graph(), s.ground_truth)
            << " rad, dof " << 6.0 * (s.graph.numConstraints() - s.graph.numNodes()) << "\n";
  // At the optimum chi2 is about its number of degrees of freedom, 6 * (edges - nodes).
  const double dof = 6.0 * (s.graph.numConstraints() - s.graph.numNodes());
  // chi2 near its expected value at the maximum-likelihood estimate (the degrees of freedom), from
  // about 50 times that; the remaining distance to the truth is the estimate's own noise.
  EXPECT_LT(chi2_end, 1.3 * dof);
  EXPECT_LT(error_end, 0.3 * error_start);
}

TEST(TreeOptimizer, ConvergesOnASyntheticCube) {
  NoiseOptions noise;
  noise.translation_sigma_m = 0.01;
  noise.rotation_sigma_rad = 0.002;
  noise.seed = 11;
  const SyntheticGraph s = makeCube(6, 1.0, 1.01, noise);
  TreeOptimizer opt;
  opt.setGraph(s.graph, InitialGuess::kChainOnTree);
  const double error_start = meanPositionError(opt.graph(), s.ground_truth);
  for (int i = 0; i < 100; ++i) opt.iterate();
  const double chi2_end = g2oChi2(opt.graph());
  const double error_end = meanPositionError(opt.graph(), s.ground_truth);
  const double dof = 6.0 * (s.graph.numConstraints() - s.graph.numNodes());
  std::cout << "cube: mean position error " << error_start << " -> " << error_end << " m, chi2 " << chi2_end
            << " (dof " << dof << ")\n";
  EXPECT_LT(chi2_end, 1.3 * dof);
  EXPECT_LT(error_end, 0.5 * error_start);
}

namespace {

// The paper's Fig. 2 case, in 3D: a hexagon driven twice.  The hexagon is skew (the cube's Petrie
// polygon: +x, +y, +z, -x, -y, -z), so the robot turns about a different axis at every corner and
// the rotations along the loop do not commute.  Loop closures join each pose of the second lap to
// the same place on the first.
SyntheticGraph hexagonDrivenTwice(std::uint32_t seed) {
  const Vector3 moves[6] = {Vector3::UnitX(), Vector3::UnitY(), Vector3::UnitZ(),
                            -Vector3::UnitX(), -Vector3::UnitY(), -Vector3::UnitZ()};
  const int per_side = 4;
  std::vector<Pose3> truth;
  Vector3 position = Vector3::Zero();
  for (int lap = 0; lap < 2; ++lap) {
    for (int side = 0; side < 6; ++side) {
      const Vector3 forward = moves[side];
      const Vector3 up = moves[(side + 1) % 6];  // never parallel to forward
      Matrix3 r;
      r.col(0) = forward;
      r.col(2) = up;
      r.col(1) = up.cross(forward);
      for (int k = 0; k < per_side; ++k) {
        truth.emplace_back(Quaternion(r), position);
        position += forward * (2.0 / per_side);
      }
    }
  }
  const std::size_t lap = truth.size() / 2;
  std::vector<std::pair<std::size_t, std::size_t>> closures;
  for (std::size_t i = 0; i < lap; ++i) closures.emplace_back(i, i + lap);
  NoiseOptions noise;
  noise.translation_sigma_m = 0.01;
  noise.rotation_sigma_rad = 0.01;
  noise.seed = seed;
  return makeFromTrajectory(truth, closures, noise);
}

}  // namespace

TEST(TreeOptimizer, PaperFigure2SlerpConvergesWhereNaiveEulerSpreadingFails) {
  int slerp_better = 0;
  for (std::uint32_t seed = 1; seed <= 5; ++seed) {
    const SyntheticGraph s = hexagonDrivenTwice(seed);
    double error[2], chi2[2];
    TreeOptimizer start;
    start.setGraph(s.graph);
    const double error_start =
        meanPositionError(start.graph(), s.ground_truth) + meanRotationError(start.graph(), s.ground_truth);
    for (int mode = 0; mode < 2; ++mode) {
      TreeOptimizerOptions options;
      options.rotation_update = mode == 0 ? RotationUpdate::kSlerp : RotationUpdate::kNaiveEuler;
      TreeOptimizer opt(options);
      opt.setGraph(s.graph);
      for (int i = 0; i < 100; ++i) opt.iterate();
      error[mode] = meanPositionError(opt.graph(), s.ground_truth) + meanRotationError(opt.graph(), s.ground_truth);
      chi2[mode] = g2oChi2(opt.graph());
    }
    std::cout << "hexagon seed " << seed << ": chained guess error " << error_start << ", slerp error " << error[0]
              << ", naive Euler error " << error[1] << "; chi2 slerp " << chi2[0] << ", naive " << chi2[1] << "\n";
    // The paper's update ends close to ground truth (the estimate's own noise is ~0.05 here) with
    // chi2 near its expected value at the optimum (the degrees of freedom).
    const double dof = 6.0 * (s.graph.numConstraints() - s.graph.numNodes());
    EXPECT_LT(error[0], 0.15) << "seed " << seed;
    EXPECT_LT(error[0], error_start) << "seed " << seed;
    EXPECT_LT(chi2[0], 2.0 * dof) << "seed " << seed;
    if (error[1] > 5.0 * error[0]) ++slerp_better;
  }
  EXPECT_GE(slerp_better, 4);
}

namespace {

double chi2After100Iterations(const std::string& file) {
  const PoseGraph g = readGraph(file);
  TreeOptimizer opt;
  opt.setGraph(g, InitialGuess::kChainOnTree);
  for (int i = 0; i < 100; ++i) opt.iterate();
  return g2oChi2(opt.graph());
}


}  // namespace

// Bounds: what the original TORO 3D program reaches in 100 iterations from the same start (the
// issue's reference figures); ours must be no worse.
TEST(TreeOptimizerDatasets, Sphere2500After100IterationsBeatsOriginalToro) {
  TORO_REQUIRE_DATASETS();
  const double chi2 = chi2After100Iterations(std::string(TORO_DATASETS_DIR) + "/sphere2500.g2o");
  std::cout << "sphere2500 chi2 after 100 iterations: " << chi2 << "\n";
  EXPECT_LT(chi2, 2655.0);
  EXPECT_GT(chi2, 727.15 * (1 - 1e-4));  // cannot beat the best known minimum
}

TEST(TreeOptimizerDatasets, ParkingGarageAfter100IterationsBeatsOriginalToro) {
  TORO_REQUIRE_DATASETS();
  const double chi2 = chi2After100Iterations(std::string(TORO_DATASETS_DIR) + "/parking-garage.g2o");
  std::cout << "parking-garage chi2 after 100 iterations: " << chi2 << "\n";
  EXPECT_LT(chi2, 32.5);
  EXPECT_GT(chi2, 1.23869 * (1 - 1e-4));
}

TEST(TreeOptimizerOnline, GrowingTheGraphMatchesTheBatchTreeAndCorrectsLoops) {
  NoiseOptions noise;
  noise.translation_sigma_m = 0.02;
  noise.rotation_sigma_rad = 0.005;
  noise.seed = 3;
  const SyntheticGraph s = makeSphere(8, 30, 10.0, noise);
  // Constraints in arrival order: each one as soon as both of its ends exist.
  std::vector<std::vector<std::size_t>> arriving(s.graph.numNodes());
  for (std::size_t c = 0; c < s.graph.numConstraints(); ++c) {
    const Constraint& k = s.graph.constraints()[c];
    arriving[std::max(s.graph.indexOf(k.from), s.graph.indexOf(k.to))].push_back(c);
  }
  TreeOptimizer online;
  online.setGraph(PoseGraph());
  TreeOptimizer odometry_only;
  odometry_only.setGraph(PoseGraph());
  std::size_t loops = 0;
  for (std::size_t v = 0; v < s.graph.numNodes(); ++v) {
    // The new node's guess: the previous node's current estimate times the odometry.
    for (TreeOptimizer* opt : {&online, &odometry_only}) {
      const Pose3 guess = v == 0 ? s.ground_truth[0]
                                 : opt->graph().node(v - 1).pose * s.graph.constraints()[v - 1].measurement;
      opt->addNode(s.graph.node(v).id, guess);
    }
    // Full passes now and then, so the incremental bookkeeping between them is exercised.
    if (v % 40 == 39) online.iterate();
    for (std::size_t c : arriving[v]) {
      const Constraint& k = s.graph.constraints()[c];
      const bool is_odometry = k.to == k.from + 1;
      const PoseGraph before = online.graph();
      const std::size_t added = online.addConstraint(k);
      // Adding a constraint (even one that re-parents a subtree) does not move any pose.
      for (std::size_t i = 0; i < before.numNodes(); ++i) {
        ASSERT_LT(relativePose(before.node(i).pose, online.graph().node(i).pose).angle(), 1e-9);
        ASSERT_LT((before.node(i).pose.translation() - online.graph().node(i).pose.translation()).norm(), 1e-9);
      }
      if (is_odometry) {
        odometry_only.addConstraint(k);
        continue;
      }
      ++loops;
      const double loop_chi2_before = constraintChi2(online.graph(), added);
      for (std::size_t k_iter = 1; k_iter <= 3; ++k_iter) online.iterateAffected(k_iter);
      EXPECT_LT(constraintChi2(online.graph(), added), loop_chi2_before + 1e-9);
    }
  }
  ASSERT_GT(loops, 100u);
  ParameterTree batch;
  batch.build(online.graph());
  EXPECT_EQ(batch.parents(), online.tree().parents());
  EXPECT_EQ(batch.levels(), online.tree().levels());
  const double online_error = meanPositionError(online.graph(), s.ground_truth);
  const double odometry_error = meanPositionError(odometry_only.graph(), s.ground_truth);
  std::cout << "online: mean position error " << online_error << " m vs odometry only " << odometry_error << " m\n";
  EXPECT_LT(online_error, 0.5 * odometry_error);
  // The incremental bookkeeping (tree, parameters, visiting order, preconditioner) matches a fresh
  // start from the same poses: one full iteration of each gives the same poses.
  TreeOptimizer fresh;
  fresh.setGraph(online.graph(), InitialGuess::kFromGraph);
  fresh.setIteration(online.iteration());  // same learning rate
  TreeOptimizer grown = online;
  grown.iterate();
  fresh.iterate();
  for (std::size_t i = 0; i < fresh.graph().numNodes(); ++i) {
    ASSERT_LT((grown.graph().node(i).pose.translation() - fresh.graph().node(i).pose.translation()).norm(), 1e-9);
    ASSERT_LT(relativePose(grown.graph().node(i).pose, fresh.graph().node(i).pose).angle(), 1e-9);
  }
  // A few full iterations afterwards bring it close to the batch result.
  for (int i = 0; i < 20; ++i) online.iterate();
  TreeOptimizer batch_opt;
  batch_opt.setGraph(s.graph);
  for (int i = 0; i < 20; ++i) batch_opt.iterate();
  EXPECT_LT(g2oChi2(online.graph()), 2.0 * g2oChi2(batch_opt.graph()));
}

TEST(TreeOptimizerOnline, GrowingAfterSetGraphMatchesAFreshStart) {
  // Start from a non-empty graph, then grow it online (regression: per-constraint bookkeeping was
  // not sized by setGraph, and growing wrote past its end).
  NoiseOptions noise;
  noise.seed = 5;
  const SyntheticGraph s = makeSphere(4, 20, 5.0, noise);
  const std::size_t initial_nodes = 30;
  PoseGraph start;
  std::vector<std::size_t> later;
  for (std::size_t i = 0; i < initial_nodes; ++i) start.addNode(s.graph.node(i).id, s.graph.node(i).pose);
  for (std::size_t c = 0; c < s.graph.numConstraints(); ++c) {
    const Constraint& k = s.graph.constraints()[c];
    if (s.graph.indexOf(k.from) < initial_nodes && s.graph.indexOf(k.to) < initial_nodes) {
      start.addConstraint(k);
    } else {
      later.push_back(c);
    }
  }
  TreeOptimizer grown;
  grown.setGraph(start, InitialGuess::kFromGraph);  // no pass before growing: nothing resized yet
  for (std::size_t i = initial_nodes; i < s.graph.numNodes(); ++i) grown.addNode(s.graph.node(i).id, s.graph.node(i).pose);
  for (std::size_t c : later) grown.addConstraint(s.graph.constraints()[c]);
  ASSERT_EQ(grown.graph().numConstraints(), s.graph.numConstraints());
  TreeOptimizer fresh;
  fresh.setGraph(grown.graph(), InitialGuess::kFromGraph);
  fresh.setIteration(grown.iteration());
  grown.iterate();
  fresh.iterate();
  for (std::size_t i = 0; i < s.graph.numNodes(); ++i) {
    ASSERT_LT((grown.graph().node(i).pose.translation() - fresh.graph().node(i).pose.translation()).norm(), 1e-9);
    ASSERT_LT(relativePose(grown.graph().node(i).pose, fresh.graph().node(i).pose).angle(), 1e-9);
  }
}

TEST(TreeOptimizerOnline, ConstraintKeptOutOfTheTreeShapesItOnlyWhenAdmitted) {
  // A chain 0..5 and a loop closure 1 -> 4: as a tree edge it makes 1 the parent of 4; kept out
  // (a loop closure on hold) 4 keeps 3; admitted later, the tree and the passes are those of an
  // optimiser that had it as a tree edge from the start.
  TreeOptimizer kept, direct;
  for (TreeOptimizer* opt : {&kept, &direct}) {
    for (NodeId i = 0; i < 6; ++i) opt->addNode(i, Pose3::fromRollPitchYaw(1.1 * i, 0.05 * i, 0, 0, 0, 0.02 * i));
    for (NodeId i = 0; i < 5; ++i) opt->addConstraint(between(i, i + 1, Pose3::fromRollPitchYaw(1, 0, 0, 0, 0, 0)));
  }
  const Constraint loop = between(1, 4, Pose3::fromRollPitchYaw(2.5, 0, 0, 0, 0, 0));
  const std::size_t c = kept.addConstraint(loop, false);
  direct.addConstraint(loop);
  EXPECT_EQ(direct.tree().parent(4), 1u);
  EXPECT_EQ(kept.tree().parent(4), 3u);
  // The path of the kept-out constraint still runs through the tree, so passes can visit it.
  kept.iterate();
  EXPECT_EQ(kept.tree().parent(4), 3u);
  kept.admitToTree(c);
  kept.admitToTree(c);  // twice is once
  for (std::size_t v = 0; v < 6; ++v) EXPECT_EQ(kept.tree().parent(v), direct.tree().parent(v)) << v;
  // From the same poses and iteration, a pass of each gives the same poses: the same tree, the
  // same preconditioner and visiting order after the admission.
  std::vector<Pose3> poses;
  for (const Node& n : direct.graph().nodes()) poses.push_back(n.pose);
  kept.setPoses(poses);
  kept.setIteration(direct.iteration());
  const double before = g2oChi2(direct.graph());
  kept.iterate();
  direct.iterate();
  for (std::size_t v = 0; v < 6; ++v)
    EXPECT_LT(poseDistance(kept.graph().node(v).pose, direct.graph().node(v).pose), 1e-9) << v;
  EXPECT_LT(g2oChi2(direct.graph()), before);
  EXPECT_THROW(kept.admitToTree(99), std::out_of_range);
}
