// The per-update bookkeeping of TreeOptimizer: the chi2 record (chi2(), constraintChi2()) agrees
// with toro::g2oChi2 (and weightedChi2() with its definition) after every kind of change, an affected pass recomputes only the subtrees it
// moved (the same poses as a full recompute), and the change journal lists every pose that moved.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <set>

#include "toro_ros/core/metrics.h"
#include "toro_ros/core/synthetic.h"
#include "toro_ros/core/tree_optimizer.h"

using namespace toro;

namespace {

void expectChi2Agrees(TreeOptimizer& opt, const char* after) {
  const double exact = g2oChi2(opt.graph());
  EXPECT_NEAR(opt.chi2(), exact, 1e-9 * std::max(1.0, exact)) << after;
  double weighted = 0.0;
  for (std::size_t c = 0; c < opt.graph().numConstraints(); ++c) {
    const double w = opt.weights()[c];
    if (!(w < opt.options().weighted_chi2_set_aside)) weighted += w * toro::constraintChi2(opt.graph(), c);
  }
  EXPECT_NEAR(opt.weightedChi2(), weighted, 1e-9 * std::max(1.0, weighted)) << after;
  for (std::size_t c = 0; c < opt.graph().numConstraints(); ++c) {
    const double one = toro::constraintChi2(opt.graph(), c);
    ASSERT_NEAR(opt.constraintChi2(c), one, 1e-9 * std::max(1.0, one)) << after << ", constraint " << c;
  }
}

bool samePose(const Pose3& a, const Pose3& b) {
  return a.translation() == b.translation() && a.rotation().coeffs() == b.rotation().coeffs();
}

// Every node whose pose changed (bit for bit) between `before` and the optimiser's graph is in
// `changes` (or it says all); returns the listed nodes.
std::set<std::size_t> expectJournalCovers(const PoseGraph& before, const TreeOptimizer& opt,
                                          const OptimizerChanges& changes) {
  const std::set<std::size_t> listed(changes.nodes.begin(), changes.nodes.end());
  EXPECT_EQ(listed.size(), changes.nodes.size()) << "a node listed twice";
  if (changes.all) return listed;
  for (std::size_t v = 0; v < before.numNodes(); ++v) {
    if (!samePose(before.node(v).pose, opt.graph().node(v).pose)) {
      EXPECT_TRUE(listed.count(v)) << "node " << v;
    }
  }
  return listed;
}

// The largest difference between two graphs' poses (translation + rotation angle).
double largestPoseDifference(const PoseGraph& a, const PoseGraph& b) {
  double worst = 0.0;
  for (std::size_t v = 0; v < a.numNodes(); ++v)
    worst = std::max(worst, (a.node(v).pose.translation() - b.node(v).pose.translation()).norm() +
                                relativePose(a.node(v).pose, b.node(v).pose).angle());
  return worst;
}

// An optimiser grown online from a sphere (odometry, loop closures to the previous ring), with an
// affected pass after each loop closure, checking the record and the journal at every step.
void growAndCheck(const TreeOptimizerOptions& options) {
  const SyntheticGraph s = makeSphere(8, 40, 10.0, NoiseOptions{});
  TreeOptimizer opt(options);
  std::size_t loop_closures = 0, listed_passes = 0;
  std::size_t next_constraint = 0;
  const auto& constraints = s.graph.constraints();
  for (std::size_t v = 0; v < s.graph.numNodes(); ++v) {
    const Pose3 guess = v == 0 ? s.ground_truth[0] : opt.graph().node(v - 1).pose * constraints[v - 1].measurement;
    opt.addNode(s.graph.node(v).id, guess);
    // Constraints whose later end is v (the sphere lists odometry and loop closures interleaved).
    for (std::size_t c = 0; c < constraints.size(); ++c) {
      const std::size_t later = std::max(s.graph.indexOf(constraints[c].from), s.graph.indexOf(constraints[c].to));
      if (later != v) continue;
      opt.addConstraint(constraints[c]);
      ++next_constraint;
      if (isLoopClosure(constraints[c])) {
        ++loop_closures;
        opt.takeChanges();
        const PoseGraph before = opt.graph();
        opt.iterateAffected(1);
        const OptimizerChanges changes = opt.takeChanges();
        expectJournalCovers(before, opt, changes);
        // The sphere's tree has shortcuts (a pass can move half of it: then the journal says
        // "all"); the lists must be exercised too.
        if (!changes.all) ++listed_passes;
        expectChi2Agrees(opt, "an affected pass");
        // The subtree recompute gives the poses a full recompute would (applyUpdate with learning
        // rate 0 moves nothing and recomputes every pose from the parameters).
        TreeOptimizer full = opt;
        full.applyUpdate(0, 0.0);
        ASSERT_LT(largestPoseDifference(opt.graph(), full.graph()), 1e-9) << "after loop closure " << c;
      }
    }
    if (v % 97 == 96) {
      opt.iterate();
      EXPECT_TRUE(opt.takeChanges().all);  // a full pass may move every pose
      expectChi2Agrees(opt, "a full pass");
    }
  }
  EXPECT_EQ(next_constraint, constraints.size());
  ASSERT_GT(loop_closures, 200u);
  EXPECT_GT(listed_passes, 20u);
}

}  // namespace

TEST(TreeOptimizerIncremental, Chi2AndJournalFollowOnlineGrowth) { growAndCheck(TreeOptimizerOptions{}); }

TEST(TreeOptimizerIncremental, Chi2AndJournalFollowOnlineGrowthWithRobustWeights) {
  TreeOptimizerOptions o;
  o.robust.kernel = RobustKernel::kDcs;
  growAndCheck(o);
}

TEST(TreeOptimizerIncremental, Chi2AndJournalFollowOnlineGrowthInThePlane) {
  TreeOptimizerOptions o;
  o.parameterization = Parameterization::kPlanar;
  growAndCheck(o);
}

TEST(TreeOptimizerIncremental, AffectedPassMovesOnlyTheLoopsSubtree) {
  // A chain of 2000 nodes and one loop closure from the newest to node 1900: the affected pass
  // visits the path 1901..1999 and the odometry along it, so exactly nodes 1901..1999 can move and
  // only the constraints at them change.
  TreeOptimizer opt;
  constexpr std::size_t kNodes = 2000, kTop = 1900;
  const Pose3 step = Pose3::fromRollPitchYaw(0.1, 0, 0, 0, 0, 0.01);
  for (std::size_t v = 0; v < kNodes; ++v) {
    opt.addNode(static_cast<NodeId>(v), v == 0 ? Pose3() : opt.graph().node(v - 1).pose * step);
    if (v > 0) {
      Constraint c{static_cast<NodeId>(v - 1), static_cast<NodeId>(v), step, Matrix6::Identity(),
                   ConstraintKind::kOdometry};
      opt.addConstraint(c);
    }
  }
  opt.iterate();  // the record is now computed in full once
  expectChi2Agrees(opt, "the chain");
  opt.takeChanges();
  Pose3 wrong = opt.graph().node(kTop).pose.inverse() * opt.graph().node(kNodes - 1).pose;
  wrong = wrong * Pose3::fromRollPitchYaw(0.3, -0.2, 0.1, 0.05, 0, 0.1);
  const std::size_t lc = opt.addConstraint(Constraint{static_cast<NodeId>(kTop), static_cast<NodeId>(kNodes - 1),
                                                      wrong, 10 * Matrix6::Identity(), ConstraintKind::kLoopClosure});
  const PoseGraph before = opt.graph();
  opt.iterateAffected(1);
  const OptimizerChanges changes = opt.takeChanges();
  ASSERT_FALSE(changes.all);
  const std::set<std::size_t> listed = expectJournalCovers(before, opt, changes);
  EXPECT_EQ(listed.size(), kNodes - 1 - kTop);
  EXPECT_EQ(*listed.begin(), kTop + 1);
  EXPECT_EQ(*listed.rbegin(), kNodes - 1);
  for (std::size_t c : changes.constraints) EXPECT_TRUE(c == lc || (c >= kTop && c < kNodes - 1)) << c;
  EXPECT_TRUE(std::find(changes.constraints.begin(), changes.constraints.end(), lc) != changes.constraints.end());
  expectChi2Agrees(opt, "the loop closure's pass");
  // Nothing happened since: an empty journal.
  const OptimizerChanges none = opt.takeChanges();
  EXPECT_FALSE(none.all);
  EXPECT_TRUE(none.nodes.empty() && none.constraints.empty());
}

TEST(TreeOptimizerIncremental, Chi2AfterSetGraphWeightChangesAndRandomPasses) {
  NoiseOptions noise;
  noise.seed = 7;
  const SyntheticGraph s = makeCube(5, 1.0, 1.1, noise);
  TreeOptimizerOptions o;
  o.robust.kernel = RobustKernel::kCauchy;
  TreeOptimizer opt(o);
  opt.setGraph(s.graph);
  expectChi2Agrees(opt, "setGraph");
  std::mt19937 random(3);
  std::uniform_int_distribution<std::size_t> pick(0, s.graph.numConstraints() - 1);
  for (int round = 0; round < 30; ++round) {
    switch (round % 5) {
      case 0:
        opt.iterate();
        break;
      case 1:
        opt.applyUpdate(pick(random), 0.5);
        break;
      case 2:
        opt.setRobustWidth(0.5 + round);
        opt.refreshWeights();  // weights change, poses do not
        break;
      default: {
        // A new loop closure between two random nodes and its affected passes.
        const Constraint& k = s.graph.constraints()[pick(random)];
        Constraint extra{k.to, k.from, k.measurement.inverse(), k.information, ConstraintKind::kLoopClosure};
        opt.addConstraint(extra);
        expectChi2Agrees(opt, "addConstraint");
        for (std::size_t i = 1; i <= 2; ++i) opt.iterateAffected(i);
        opt.clearAffected();
      }
    }
    expectChi2Agrees(opt, "a random step");
  }
  opt.setGraph(s.graph, InitialGuess::kFromGraph);
  expectChi2Agrees(opt, "a second setGraph");
}

TEST(TreeOptimizerIncremental, CopiesReportEverything) {
  // A copy (the gate's "before" state) is not the history its consumer followed.
  TreeOptimizer opt;
  opt.addNode(0, Pose3());
  opt.addNode(1, Pose3::fromRollPitchYaw(1, 0, 0, 0, 0, 0));
  opt.addConstraint(Constraint{0, 1, Pose3::fromRollPitchYaw(1, 0, 0, 0, 0, 0), Matrix6::Identity(),
                               ConstraintKind::kOdometry});
  EXPECT_TRUE(opt.takeChanges().all);  // a new optimiser: nothing was read
  EXPECT_FALSE(opt.takeChanges().all);
  TreeOptimizer copy = opt;
  EXPECT_TRUE(copy.takeChanges().all);
  EXPECT_FALSE(opt.takeChanges().all);  // the original's history goes on
  opt = copy;
  EXPECT_TRUE(opt.takeChanges().all);
}

TEST(TreeOptimizerIncremental, Chi2AndJournalFollowHeldLoopClosuresWeightCapsAndSetPoses) {
  // What the pipeline's support logic does: loop closures held at weight 0 outside the tree's
  // shape, released later (cap 1, admitted to the tree, marked affected), and a finished solution
  // taken over by setPoses.  The record and the journal must follow each.
  TreeOptimizerOptions o;
  o.robust.kernel = RobustKernel::kDcs;
  TreeOptimizer opt(o);
  constexpr std::size_t kNodes = 600;
  const Pose3 step = Pose3::fromRollPitchYaw(0.1, 0, 0, 0, 0, 0.012);
  for (std::size_t v = 0; v < kNodes; ++v) {
    opt.addNode(static_cast<NodeId>(v), v == 0 ? Pose3() : opt.graph().node(v - 1).pose * step);
    if (v > 0)
      opt.addConstraint(Constraint{static_cast<NodeId>(v - 1), static_cast<NodeId>(v), step, Matrix6::Identity(),
                                   ConstraintKind::kOdometry});
  }
  expectChi2Agrees(opt, "the chain");
  opt.clearAffected();
  std::vector<std::size_t> held;
  for (std::size_t top = 100; top < kNodes - 50; top += 100) {
    Pose3 m = opt.graph().node(top).pose.inverse() * opt.graph().node(top + 40).pose;
    m = m * Pose3::fromRollPitchYaw(0.2, 0.1, 0, 0, 0, 0.05);
    const std::size_t c = opt.addConstraint(Constraint{static_cast<NodeId>(top), static_cast<NodeId>(top + 40), m,
                                                       10 * Matrix6::Identity(), ConstraintKind::kLoopClosure},
                                            false);
    opt.setWeightCap(c, 0.0);
    held.push_back(c);
    expectChi2Agrees(opt, "a held loop closure");
  }
  opt.takeChanges();
  for (std::size_t c : held) {
    opt.setWeightCap(c, 1.0);
    const OptimizerChanges released = opt.takeChanges();
    // Its weight changed, no pose moved: the edge is listed, no node.
    ASSERT_FALSE(released.all);
    EXPECT_TRUE(released.nodes.empty());
    EXPECT_EQ(released.constraints, std::vector<std::size_t>{c});
    expectChi2Agrees(opt, "a release");
    opt.admitToTree(c);
    opt.markAffected(c);
    const PoseGraph before = opt.graph();
    opt.iterateAffected(1);
    const OptimizerChanges changes = opt.takeChanges();
    expectJournalCovers(before, opt, changes);
    expectChi2Agrees(opt, "the released loop closure's pass");
    TreeOptimizer full = opt;
    full.applyUpdate(0, 0.0);
    ASSERT_LT(largestPoseDifference(opt.graph(), full.graph()), 1e-9) << "after releasing " << c;
  }
  opt.setWeightCap(held.front(), 0.5);
  expectChi2Agrees(opt, "a cap of 0.5");
  std::vector<Pose3> poses;
  for (const Node& n : opt.graph().nodes()) poses.push_back(n.pose * Pose3::fromRollPitchYaw(0.01, 0, 0, 0, 0, 0.001));
  opt.setPoses(poses);
  EXPECT_TRUE(opt.takeChanges().all);
  expectChi2Agrees(opt, "setPoses");
  opt.refreshWeights();
  expectChi2Agrees(opt, "a weight refresh after setPoses");
}

// A map at the optimum of its first `settled` constraints (a merged finish): the pass after a new
// loop closure updates the new one and the newer constraints its path touches, not the settled
// ones there, whose residuals are the optimum's balance.
TEST(TreeOptimizerIncremental, SettledConstraintsTouchingANewPathAreLeftAloneUnlessNew) {
  constexpr std::size_t kNodes = 40, kTop = 5;
  const Pose3 step = Pose3::fromRollPitchYaw(1.0, 0.0, 0.0, 0.0, 0.0, 2 * M_PI / 30);
  TreeOptimizer opt;
  for (std::size_t v = 0; v < kNodes; ++v) {
    // Perturbed odometry, so every settled constraint has a residual a pass would act on.
    const Pose3 noise =
        Pose3::fromRollPitchYaw(0.02 * std::sin(3.0 * v), 0.01 * std::cos(v), 0, 0, 0, 0.01 * std::sin(v));
    opt.addNode(static_cast<NodeId>(v), v == 0 ? Pose3() : opt.graph().node(v - 1).pose * step * noise);
    if (v > 0)
      opt.addConstraint(Constraint{static_cast<NodeId>(v - 1), static_cast<NodeId>(v), step,
                                   Matrix6::Identity(), ConstraintKind::kOdometry});
  }
  opt.addConstraint(Constraint{0, 30, Pose3(), Matrix6::Identity(), ConstraintKind::kLoopClosure});
  for (int i = 0; i < 3; ++i) opt.iterate();
  const std::size_t settled = opt.graph().numConstraints();
  // One newer keyframe, then a loop closure from it back to kTop.
  opt.addNode(static_cast<NodeId>(kNodes), opt.graph().node(kNodes - 1).pose * step);
  opt.addConstraint(Constraint{static_cast<NodeId>(kNodes - 1), static_cast<NodeId>(kNodes), step,
                               Matrix6::Identity(), ConstraintKind::kOdometry});
  const Pose3 measured = opt.graph().node(kTop).pose.inverse() * opt.graph().node(kNodes).pose *
                         Pose3::fromRollPitchYaw(0.2, -0.1, 0.05, 0.02, 0, 0.05);
  const std::size_t lc =
      opt.addConstraint(Constraint{static_cast<NodeId>(kTop), static_cast<NodeId>(kNodes), measured,
                                   10 * Matrix6::Identity(), ConstraintKind::kLoopClosure});
  const PoseGraph before = opt.graph();

  // The same pass by hand: the newer constraints alone (the odometry first, as the pass orders
  // them by their top node's level, then the loop closure), each once at learning rate 1.
  TreeOptimizer by_hand = opt;
  by_hand.applyUpdate(settled, 1.0);
  by_hand.applyUpdate(lc, 1.0);
  TreeOptimizer all = opt;
  all.iterateAffected(1);

  opt.iterateAffected(1, settled);
  EXPECT_LT(largestPoseDifference(opt.graph(), by_hand.graph()), 1e-9);
  // With every constraint at the path (the default), the settled ones move the map differently.
  EXPECT_GT(largestPoseDifference(all.graph(), opt.graph()), 1e-3);
  expectChi2Agrees(opt, "the pass with settled constraints");
  // The loop closure was applied: its residual shrank.
  EXPECT_LT(constraintChi2(opt.graph(), lc), 0.5 * constraintChi2(before, lc));
}

// takeSolution (a background finish merged): the solution's nodes take its poses and the nodes added
// since keep their parameter, to the bit what setPoses gives for the poses built by hand (the
// merge's former construction), in SE(3) and in SE(2).  Newer nodes include one whose tree parent
// is older than the node before it (through a loop closure) and one whose parent is newer itself.
TEST(TreeOptimizerIncremental, ATakenSolutionIsSetPosesWithNewerNodesMovedWithTheirParents) {
  for (const Parameterization group : {Parameterization::kSpatial, Parameterization::kPlanar}) {
    SCOPED_TRACE(parameterizationName(group));
    TreeOptimizerOptions options;
    options.parameterization = group;
    TreeOptimizer opt(options);
    const Pose3 step = Pose3::fromRollPitchYaw(1.0, 0.0, 0.0, 0.0, 0.0, 2 * M_PI / 20);
    constexpr std::size_t kSolved = 30;
    const auto addStep = [&](std::size_t v) {
      const Pose3 noise =
          Pose3::fromRollPitchYaw(0.02 * std::sin(3.0 * v), 0.01 * std::cos(v), 0, 0.01 * std::sin(v),
                                  0.005 * std::cos(2.0 * v), 0.01 * std::sin(v));
      opt.addNode(static_cast<NodeId>(v), v == 0 ? Pose3() : opt.graph().node(v - 1).pose * step * noise);
      if (v > 0)
        opt.addConstraint(Constraint{static_cast<NodeId>(v - 1), static_cast<NodeId>(v), step,
                                     Matrix6::Identity(), ConstraintKind::kOdometry});
    };
    for (std::size_t v = 0; v < kSolved; ++v) addStep(v);
    opt.addConstraint(Constraint{0, 20, Pose3(), Matrix6::Identity(), ConstraintKind::kLoopClosure});
    opt.iterate();
    // The finish's solution of the graph so far (in the plane for a planar map): every pose moved.
    const bool planar = group == Parameterization::kPlanar;
    PoseGraph solution = opt.graph();
    for (std::size_t v = 0; v < kSolved; ++v)
      solution.setPoseAt(v, solution.node(v).pose *
                                Pose3::fromRollPitchYaw(0.003 * v, -0.002, planar ? 0.0 : 0.001,
                                                        planar ? 0.0 : 0.01, planar ? 0.0 : 0.002, 0.004));
    // Meanwhile: kSolved by odometry, kSolved + 1 by odometry and a loop closure to node 3 (its tree
    // parent: the smallest id it shares a constraint with), kSolved + 2 after it.
    addStep(kSolved);
    opt.addNode(static_cast<NodeId>(kSolved + 1), opt.graph().node(kSolved).pose * step);
    opt.addConstraint(Constraint{3, static_cast<NodeId>(kSolved + 1),
                                 relativePose(opt.graph().node(3).pose, opt.graph().node(kSolved + 1).pose),
                                 Matrix6::Identity(), ConstraintKind::kLoopClosure});
    opt.addConstraint(Constraint{static_cast<NodeId>(kSolved), static_cast<NodeId>(kSolved + 1), step,
                                 Matrix6::Identity(), ConstraintKind::kOdometry});
    addStep(kSolved + 2);
    ASSERT_EQ(opt.tree().parent(kSolved + 1), 3u);
    ASSERT_EQ(opt.tree().parent(kSolved + 2), kSolved + 1);

    std::vector<Pose3> poses(opt.graph().numNodes());
    for (std::size_t v = 0; v < kSolved; ++v) poses[v] = solution.node(v).pose;
    for (std::size_t v : opt.tree().topologicalOrder()) {
      if (v < kSolved) continue;
      const std::size_t p = opt.tree().parent(v);
      poses[v] = poses[p] * relativePose(opt.graph().node(p).pose, opt.graph().node(v).pose);
    }
    TreeOptimizer by_hand = opt;
    by_hand.setPoses(poses);
    const PoseGraph before = opt.graph();
    opt.takeSolution(solution);
    for (std::size_t v = 0; v < opt.graph().numNodes(); ++v)
      ASSERT_TRUE(samePose(opt.graph().node(v).pose, by_hand.graph().node(v).pose)) << "node " << v;
    EXPECT_EQ(opt.chi2(), by_hand.chi2());
    EXPECT_TRUE(opt.takeChanges().all);
    expectChi2Agrees(opt, "takeSolution");
    // The newer nodes moved with their parents; the solved ones are the solution's (normalised).
    for (std::size_t v = kSolved; v < kSolved + 3; ++v) {
      const std::size_t p = opt.tree().parent(v);
      const Pose3 now = relativePose(opt.graph().node(p).pose, opt.graph().node(v).pose);
      const Pose3 then = relativePose(before.node(p).pose, before.node(v).pose);
      EXPECT_LT((now.translation() - then.translation()).norm(), 1e-12) << "node " << v;
      EXPECT_LT(now.rotation().angularDistance(then.rotation()), 1e-12) << "node " << v;
    }
    EXPECT_GT((opt.graph().node(kSolved + 2).pose.translation() - before.node(kSolved + 2).pose.translation())
                  .norm(),
              0.01);
    PoseGraph too_large = by_hand.graph();
    too_large.addNode(999, Pose3());
    EXPECT_THROW(by_hand.takeSolution(too_large), std::invalid_argument);
  }
}
