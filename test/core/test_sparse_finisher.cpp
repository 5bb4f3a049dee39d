// The sparse Levenberg-Marquardt finish: convergence to the minimum on small graphs (3D and
// planar), the gauge, options, repaired information, and the best known minima of
// ../shared/datasets/REFERENCE.md (B) on the benchmark files.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <random>
#include <sstream>

#include "shared_datasets.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/finish_residuals.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/random_draws.h"
#include "toro_ros/core/sparse_finisher.h"

using namespace toro;

namespace {

Pose3 randomPose(std::mt19937& rng, double rotation_scale, double translation_scale) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Vector3 t = drawVector3(n, rng);
  return Pose3::fromAngleAxis(rotation_scale * drawVector3(n, rng), translation_scale * t);
}

Matrix6 randomInformation(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Matrix6 a;
  for (int i = 0; i < 36; ++i) a(i) = u(rng);
  return 10.0 * (a * a.transpose() + Matrix6::Identity());
}

// A noisy 3D loop: a chain around a circle plus chords, poses perturbed from the truth.
PoseGraph noisyGraph3D(unsigned seed, int n = 30) {
  std::mt19937 rng(seed);
  std::vector<Pose3> truth;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    truth.push_back(
        Pose3::fromRollPitchYaw(5 * std::cos(a), 5 * std::sin(a), 0.3 * std::sin(3 * a), 0.1, -0.2, a));
  }
  PoseGraph g;
  for (int i = 0; i < n; ++i) g.addNode(i, truth[i] * randomPose(rng, 0.1, 0.3));
  auto add = [&](int a, int b) {
    g.addConstraint(Constraint{a, b, relativePose(truth[a], truth[b]) * randomPose(rng, 0.05, 0.1),
                               randomInformation(rng)});
  };
  for (int i = 0; i < n; ++i) add(i, (i + 1) % n);
  for (int i = 0; i + 5 < n; i += 3) add(i, i + 5);
  return g;
}

PoseGraph noisyGraph2D(unsigned seed, int n = 30) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  auto planar = [](double x, double y, double t) { return Pose3::fromRollPitchYaw(x, y, 0, 0, 0, t); };
  std::vector<Pose3> truth;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    truth.push_back(planar(5 * std::cos(a), 5 * std::sin(a), a + M_PI / 2));
  }
  Matrix6 info = Matrix6::Zero();  // lifted like the readers: planar (20, 30, 50) with an x-theta cross of 1
  info.diagonal() << 20, 30, 25, 200, 200, 200;
  info(0, 5) = info(5, 0) = 2.0;
  PoseGraph g;
  g.setDimension(GraphDimension::k2D);
  for (int i = 0; i < n; ++i) {
    const auto d = drawLastFirst<3>(noise, rng);
    g.addNode(i, truth[i] * planar(0.3 * d[0], 0.3 * d[1], 0.2 * d[2]));
  }
  auto add = [&](int a, int b) {
    const auto d = drawLastFirst<3>(noise, rng);
    const Pose3 z = relativePose(truth[a], truth[b]) * planar(0.1 * d[0], 0.1 * d[1], 0.05 * d[2]);
    g.addConstraint(Constraint{a, b, z, info});
  };
  for (int i = 0; i < n; ++i) add(i, (i + 1) % n);
  for (int i = 0; i + 7 < n; i += 4) add(i, i + 7);
  return g;
}

FinishOptions tightOptions() {
  FinishOptions o;
  o.relative_decrease_tolerance = 1e-15;
  o.gradient_tolerance = 1e-12;
  o.step_tolerance = 1e-14;
  return o;
}

// Largest |d chi2 / d delta| over all free nodes by central differences (the optimum's gradient).
double numericGradient3D(PoseGraph g, NodeId held) {
  double largest = 0.0;
  const double h = 1e-6;
  for (const Node& node : std::vector<Node>(g.nodes())) {
    if (node.id == held) continue;
    for (int k = 0; k < 6; ++k) {
      const Vector6 d = h * Vector6::Unit(k);
      g.setPose(node.id, retractSE3(node.pose, d));
      const double plus = g2oChi2(g);
      g.setPose(node.id, retractSE3(node.pose, -d));
      const double minus = g2oChi2(g);
      g.setPose(node.id, node.pose);
      largest = std::max(largest, std::abs(plus - minus) / (2 * h));
    }
  }
  return largest;
}

}  // namespace

TEST(SparseFinisher, ReachesTheMinimumOfASmall3DGraph) {
  PoseGraph g = noisyGraph3D(31);
  const Pose3 root_before = g.pose(0);
  const double before = g2oChi2(g);
  const FinishReport r = LevenbergMarquardt(tightOptions()).optimize(g);
  EXPECT_LT(r.final_chi2, 0.01 * before);
  EXPECT_NEAR(r.final_chi2, g2oChi2(g), 1e-12 * r.final_chi2);  // the cost is exactly g2o chi2
  EXPECT_EQ(r.held_nodes, 1u);
  EXPECT_LT((root_before.inverse() * g.pose(0)).angle() +
                (root_before.translation() - g.pose(0).translation()).norm(),
            1e-15);
  EXPECT_LT(numericGradient3D(g, 0), 1e-6);

  // A second run from a strongly perturbed start ends at the same chi2 (to 1e-9 relative).
  PoseGraph other = noisyGraph3D(31);
  std::mt19937 rng(99);
  for (const Node& n : std::vector<Node>(other.nodes())) {
    if (n.id != 0) other.setPose(n.id, g.pose(n.id) * randomPose(rng, 0.2, 0.5));
  }
  const FinishReport r2 = LevenbergMarquardt(tightOptions()).optimize(other);
  EXPECT_NEAR(r2.final_chi2, r.final_chi2, 1e-9 * r.final_chi2);
  for (const Node& n : g.nodes())
    EXPECT_LT((n.pose.translation() - other.pose(n.id).translation()).norm(), 1e-5);
}

// The innovation of a constraint left out of the graph is what adding it costs the optimum (to
// first order; here the noise is small enough for the linear model to hold within a few %).
TEST(SparseFinisher, InnovationOfALeftOutConstraintIsTheRiseOfTheOptimumWhenItIsAdded) {
  for (const bool planar : {false, true}) {
    for (unsigned seed : {41u, 42u, 43u}) {
      SCOPED_TRACE((planar ? "2D seed " : "3D seed ") + std::to_string(seed));
      const PoseGraph full = planar ? noisyGraph2D(seed) : noisyGraph3D(seed);
      const std::size_t left_out = full.numConstraints() - 1;  // a chord
      PoseGraph without = keepConstraints(full, [&](std::size_t c) { return c != left_out; });
      const Constraint candidate = full.constraints()[left_out];
      Constraint wrong = candidate;
      wrong.measurement =
          candidate.measurement * Pose3::fromRollPitchYaw(6.0, -5.0, 0, 0, 0, 0.8);  // 8 m off
      Constraint elsewhere = candidate;
      elsewhere.to = 1000;  // not a node
      const FinishReport r =
          LevenbergMarquardt(tightOptions()).optimize(without, {}, {candidate, wrong, elsewhere});
      ASSERT_EQ(r.innovation_chi2.size(), 3u);
      PoseGraph with = without;
      with.addConstraint(candidate);
      const double rise = LevenbergMarquardt(tightOptions()).optimize(with).final_chi2 - r.final_chi2;
      ASSERT_GT(rise, 0.0);
      EXPECT_NEAR(r.innovation_chi2[0], rise, 0.05 * rise);
      // Its own chi2 at the optimum without it is larger: the map's uncertainty is not in that.
      PoseGraph at_optimum_without = without;
      at_optimum_without.addConstraint(candidate);
      EXPECT_GT(constraintChi2(at_optimum_without, left_out), r.innovation_chi2[0]);
      EXPECT_GT(r.innovation_chi2[1], chiSquareQuantile(0.999, planar ? 3 : 6));  // refused at 0.999
      EXPECT_GT(r.innovation_chi2[1], 10.0 * r.innovation_chi2[0]);
      EXPECT_EQ(r.innovation_chi2[2], -1.0);
    }
  }
}

// The innovations are the same whichever factorisation gives them: CHOLMOD's supernodal L L^T reads
// only the part of its factor the two ends' rows reach (SparseCholesky::forwardGram), its
// simplicial L D L^T and Eigen's solve dense columns.  A graph large enough for many supernodes,
// candidates and included constraints spread over it (ends far apart, and near the root).
TEST(SparseFinisher, InnovationsAgreeAcrossTheLinearSolvers) {
  if (!cholmodAvailable()) GTEST_SKIP() << "CHOLMOD not built in";
  for (const bool planar : {false, true}) {
    SCOPED_TRACE(planar ? "2D" : "3D");
    const PoseGraph full = planar ? noisyGraph2D(7, 400) : noisyGraph3D(7, 400);
    std::vector<std::size_t> chords;
    for (std::size_t c = 0; c < full.numConstraints(); ++c)
      if (full.constraints()[c].to != full.constraints()[c].from + 1) chords.push_back(c);
    ASSERT_GT(chords.size(), 40u);
    std::vector<Constraint> left_out;
    for (std::size_t k = 0; k < chords.size(); k += 9) left_out.push_back(full.constraints()[chords[k]]);
    Constraint across = full.constraints()[chords[0]];  // a claim between far places
    across.to = 250;
    left_out.push_back(across);
    PoseGraph without = keepConstraints(full, [&](std::size_t c) {
      return std::none_of(left_out.begin(), left_out.end(), [&](const Constraint& l) {
        return l.from == full.constraints()[c].from && l.to == full.constraints()[c].to;
      });
    });
    const std::vector<IncludedConstraint> included{{0}, {5, 0.5}, {without.numConstraints() - 1}, {200}};
    std::vector<std::vector<double>> innovations;
    for (const LinearSolverType solver :
         {LinearSolverType::kCholmodSupernodal, LinearSolverType::kCholmodSimplicial,
          LinearSolverType::kSimplicialLDLT}) {
      FinishOptions o = tightOptions();
      o.linear_solver = solver;
      PoseGraph g = without;
      const FinishReport r = LevenbergMarquardt(o).optimize(g, {}, left_out, included);
      std::vector<double> all = r.innovation_chi2;
      all.insert(all.end(), r.included_innovation_chi2.begin(), r.included_innovation_chi2.end());
      innovations.push_back(all);
    }
    ASSERT_EQ(innovations[0].size(), left_out.size() + included.size());
    for (std::size_t k = 0; k < innovations[0].size(); ++k) {
      SCOPED_TRACE("innovation " + std::to_string(k));
      ASSERT_GT(innovations[0][k], 0.0);
      EXPECT_NEAR(innovations[0][k], innovations[1][k], 1e-6 * innovations[0][k]);
      EXPECT_NEAR(innovations[0][k], innovations[2][k], 1e-6 * innovations[0][k]);
    }
  }
}

// The leave-one-out innovation of a constraint in the graph (FinishReport::included_innovation_chi2)
// is the innovation it would have were it left out: here against the finish of the graph without
// it, within the linear model's few %.  What nothing else constrains has none to tell (-1); a wrong
// one in the graph shows it as plainly as when left out.
TEST(SparseFinisher, LeaveOneOutInnovationOfAnIncludedConstraintIsItsInnovationWhenLeftOut) {
  for (const bool planar : {false, true}) {
    for (unsigned seed : {41u, 42u, 43u}) {
      SCOPED_TRACE((planar ? "2D seed " : "3D seed ") + std::to_string(seed));
      const PoseGraph full = planar ? noisyGraph2D(seed) : noisyGraph3D(seed);
      const std::size_t chord = full.numConstraints() - 1;
      PoseGraph without = keepConstraints(full, [&](std::size_t c) { return c != chord; });
      const FinishReport left_out =
          LevenbergMarquardt(tightOptions()).optimize(without, {}, {full.constraints()[chord]});
      ASSERT_EQ(left_out.innovation_chi2.size(), 1u);
      ASSERT_GT(left_out.innovation_chi2[0], 0.0);
      PoseGraph with = full;
      const FinishReport included =
          LevenbergMarquardt(tightOptions())
              .optimize(with, {}, {}, {IncludedConstraint{chord}, IncludedConstraint{0}});
      ASSERT_EQ(included.included_innovation_chi2.size(), 2u);
      EXPECT_TRUE(included.innovation_chi2.empty());
      EXPECT_NEAR(included.included_innovation_chi2[0], left_out.innovation_chi2[0],
                  0.05 * left_out.innovation_chi2[0]);
      // The first odometry step (node 0 -> 1) is a chain link some chord bypasses: told.
      EXPECT_GE(included.included_innovation_chi2[1], 0.0);
      // In the graph at a quarter of its information (a robust weight the caller applied): still
      // against its own information, so the same value.
      PoseGraph weighted = full;
      weighted.scaleInformation(chord, 0.25);
      const double at_a_quarter = LevenbergMarquardt(tightOptions())
                                      .optimize(weighted, {}, {}, {IncludedConstraint{chord, 0.25}})
                                      .included_innovation_chi2[0];
      EXPECT_NEAR(at_a_quarter, left_out.innovation_chi2[0], 0.05 * left_out.innovation_chi2[0]);

      // Odometry only: every step is all that holds its `to` node.
      PoseGraph chain =
          keepConstraints(full, [&](std::size_t c) { return !isLoopClosure(full.constraints()[c]); });
      const FinishReport bridges =
          LevenbergMarquardt(tightOptions())
              .optimize(chain, {}, {}, {IncludedConstraint{0}, IncludedConstraint{1}});
      ASSERT_EQ(bridges.included_innovation_chi2.size(), 2u);
      EXPECT_EQ(bridges.included_innovation_chi2[0], -1.0);
      EXPECT_EQ(bridges.included_innovation_chi2[1], -1.0);

      // 8 m off, in the graph: its leave-one-out innovation refuses it as the left-out test does.
      PoseGraph wrong_in = without;
      Constraint wrong = full.constraints()[chord];
      wrong.measurement = wrong.measurement * Pose3::fromRollPitchYaw(6.0, -5.0, 0, 0, 0, 0.8);
      const std::size_t w = wrong_in.addConstraint(wrong);
      PoseGraph wrong_out = without;
      const double expected =
          LevenbergMarquardt(tightOptions()).optimize(wrong_out, {}, {wrong}).innovation_chi2[0];
      const double told = LevenbergMarquardt(tightOptions())
                              .optimize(wrong_in, {}, {}, {IncludedConstraint{w}})
                              .included_innovation_chi2[0];
      EXPECT_GT(told, chiSquareQuantile(0.999, planar ? 3 : 6));
      EXPECT_GT(told, 0.5 * expected);  // the linear model is poor this far off; the verdict is the same
    }
  }
}

// The supernodal factorisation computes the innovations with half a solve (J H^-1 J^T = Y^T Y,
// Y = L^-1 P J^T); the LDL^T solvers (Eigen's, CHOLMOD's simplicial) with the whole solve.  The
// same numbers, whichever ran.
TEST(SparseFinisher, InnovationsAreTheSameWithEveryLinearSolver) {
  for (const bool planar : {false, true}) {
    const PoseGraph full = planar ? noisyGraph2D(44) : noisyGraph3D(44);
    PoseGraph without;
    without.setDimension(full.dimension());
    for (const Node& n : full.nodes()) without.addNode(n.id, n.pose);
    std::vector<Constraint> candidates;
    for (std::size_t c = 0; c < full.numConstraints(); ++c) {
      const Constraint& k = full.constraints()[c];
      if (isLoopClosure(k) && candidates.size() < 3) {
        candidates.push_back(k);
      } else {
        without.addConstraint(k);
      }
    }
    ASSERT_EQ(candidates.size(), 3u);
    candidates[1].measurement =
        candidates[1].measurement * Pose3::fromRollPitchYaw(6.0, -5.0, 0, 0, 0, 0.8);  // 8 m off
    std::vector<double> reference;
    for (const LinearSolverType solver :
         {LinearSolverType::kSimplicialLDLT, LinearSolverType::kCholmodSimplicial,
          LinearSolverType::kCholmodSupernodal}) {
      SCOPED_TRACE(std::string(planar ? "2D " : "3D ") + linearSolverName(solver));
      FinishOptions options = tightOptions();
      options.linear_solver = solver;
      PoseGraph g = without;
      const FinishReport r = LevenbergMarquardt(options).optimize(g, {}, candidates);
      ASSERT_EQ(r.innovation_chi2.size(), 3u);
      if (reference.empty()) {
        reference = r.innovation_chi2;
        for (double chi2 : reference) EXPECT_GT(chi2, 0.0);
        EXPECT_GT(reference[1], 10.0 * reference[0]);
        continue;
      }
      for (std::size_t k = 0; k < 3; ++k)
        EXPECT_NEAR(r.innovation_chi2[k], reference[k], 1e-6 * reference[k]);
    }
  }
}

TEST(SparseFinisher, ReportsEveryIterationAndChi2DecreasesMonotonically) {
  PoseGraph g = noisyGraph3D(32);
  std::vector<FinishIteration> seen;
  const FinishReport r =
      LevenbergMarquardt().optimize(g, [&](const FinishIteration& it) { seen.push_back(it); });
  ASSERT_EQ(seen.size(), r.history.size());
  ASSERT_EQ(seen.size(), r.iterations);
  ASSERT_FALSE(seen.empty());
  double previous = r.initial_chi2;
  for (std::size_t k = 0; k < seen.size(); ++k) {
    EXPECT_EQ(seen[k].iteration, k + 1);
    EXPECT_LE(seen[k].chi2, previous);
    EXPECT_GT(seen[k].lambda, 0.0);
    if (seen[k].accepted) {
      EXPECT_LT(seen[k].chi2, previous);
    }
    previous = seen[k].chi2;
  }
  EXPECT_EQ(previous, r.final_chi2);
  EXPECT_TRUE(r.stop == FinishStop::kRelativeDecrease || r.stop == FinishStop::kPredictedDecrease ||
              r.stop == FinishStop::kGradient || r.stop == FinishStop::kStep)
      << finishStopName(r.stop);
}

TEST(SparseFinisher, PlanarGraphMinimisesThe2DChi2AndStaysInThePlane) {
  PoseGraph g = noisyGraph2D(33);
  const FinishReport r = LevenbergMarquardt(tightOptions()).optimize(g);
  EXPECT_NEAR(r.final_chi2, g2oChi2(g), 1e-12 * r.final_chi2);
  EXPECT_LT(r.final_chi2, 0.01 * r.initial_chi2);
  for (const Node& n : g.nodes()) {
    EXPECT_EQ(n.pose.translation().z(), 0.0);
    EXPECT_LT(n.pose.rotation().vec().head<2>().norm(), 1e-15);  // no roll or pitch
  }
  // Same minimum from another start (angles shifted by whole turns and noise).
  PoseGraph other = noisyGraph2D(33);
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 0.1);
  for (const Node& node : std::vector<Node>(other.nodes())) {
    if (node.id == 0) continue;
    const Vector3 rpy = g.pose(node.id).rollPitchYaw();
    const Vector3 t = g.pose(node.id).translation();
    const auto d = drawLastFirst<3>(n, rng);
    other.setPose(node.id,
                  Pose3::fromRollPitchYaw(t.x() + d[0], t.y() + d[1], 0, 0, 0, rpy.z() + 2 * M_PI + d[2]));
  }
  const FinishReport r2 = LevenbergMarquardt(tightOptions()).optimize(other);
  EXPECT_NEAR(r2.final_chi2, r.final_chi2, 1e-9 * r.final_chi2);
}

TEST(SparseFinisher, GaugeHoldsFixNodesAndOneNodePerUnconnectedComponent) {
  PoseGraph g = noisyGraph3D(34, 12);
  // A second, unconnected component (ids 100..104) and a FIX node in the first.
  std::mt19937 rng(7);
  for (int i = 100; i < 105; ++i) g.addNode(i, randomPose(rng, 0.5, 2.0));
  for (int i = 100; i + 1 < 105; ++i) {
    g.addConstraint(Constraint{i, i + 1, randomPose(rng, 0.3, 1.0), Matrix6::Identity()});
  }
  g.addFixed(5);
  const Pose3 fixed_before = g.pose(5), other_root_before = g.pose(100), node0_before = g.pose(0);
  const FinishReport r = LevenbergMarquardt(tightOptions()).optimize(g);
  EXPECT_EQ(r.held_nodes, 2u);
  EXPECT_EQ((fixed_before.translation() - g.pose(5).translation()).norm(), 0.0);
  EXPECT_EQ((other_root_before.translation() - g.pose(100).translation()).norm(), 0.0);
  EXPECT_GT((node0_before.translation() - g.pose(0).translation()).norm(), 1e-6);  // not held: FIX wins
  // The second component is a tree, so it is met exactly.
  double tree_chi2 = 0.0;
  for (std::size_t c = 0; c < g.numConstraints(); ++c) {
    if (g.constraints()[c].from >= 100) tree_chi2 += constraintChi2(g, c);
  }
  EXPECT_LT(tree_chi2, 1e-18);
}

TEST(SparseFinisher, OptionsAreValidated) {
  FinishOptions o;
  EXPECT_EQ(o.validate(), "");
  o.max_iterations = 0;
  o.initial_lambda_factor = -1.0;
  const std::string why = o.validate();
  EXPECT_NE(why.find("max_iterations"), std::string::npos);
  EXPECT_NE(why.find("initial_lambda_factor"), std::string::npos);
  EXPECT_THROW(LevenbergMarquardt{o}, std::invalid_argument);
  FinishOptions ldlt;
  ldlt.linear_solver = LinearSolverType::kSimplicialLDLT;
  EXPECT_NO_THROW(LevenbergMarquardt{ldlt});
}

TEST(SparseFinisher, LinearSolversAgree) {
  PoseGraph a = noisyGraph3D(35), b = a;
  FinishOptions o = tightOptions();
  o.linear_solver = LinearSolverType::kSimplicialLDLT;
  const double ldlt = LevenbergMarquardt(o).optimize(a).final_chi2;
  if (!cholmodAvailable()) GTEST_SKIP() << "CHOLMOD not built in";
  o.linear_solver = LinearSolverType::kCholmodSupernodal;
  const double cholmod = LevenbergMarquardt(o).optimize(b).final_chi2;
  EXPECT_NEAR(ldlt, cholmod, 1e-10 * ldlt);
}

TEST(SparseFinisher, RepairedIndefiniteInformationDoesNotDiverge) {
  // Cubicle-like information: both 3x3 blocks positive definite, the whole indefinite (strong
  // translation-rotation coupling).  The reader repairs it (counted); the finish converges.
  std::ostringstream text;
  text << "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"
       << "VERTEX_SE3:QUAT 1 1.1 0.1 0 0 0 0.05 0.9987492\n"
       << "VERTEX_SE3:QUAT 2 2.0 0.3 0.1 0 0 0.1 0.9949874\n";
  const std::string identity_upper = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1";
  text << "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 " << identity_upper << "\n";
  text << "EDGE_SE3:QUAT 1 2 1 0 0 0 0 0 1 " << identity_upper << "\n";
  // Upper triangle with an x-qx coupling of 3 (> sqrt(1 * 1)): indefinite.
  text << "EDGE_SE3:QUAT 0 2 2 0 0 0 0 0 1 1 0 0 3 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n";
  std::istringstream in(text.str());
  ReadReport report;
  PoseGraph g = readGraph(in, "indefinite.g2o", ReadOptions{}, &report);
  ASSERT_EQ(report.repaired_information, 1u);
  const Matrix6& repaired = g.constraints()[2].information;
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Matrix6>(repaired).eigenvalues().minCoeff(), 0.0);
  const FinishReport r = LevenbergMarquardt(tightOptions()).optimize(g);
  EXPECT_TRUE(std::isfinite(r.final_chi2));
  EXPECT_LE(r.final_chi2, r.initial_chi2);
  EXPECT_LT(numericGradient3D(g, 0), 1e-6);
}

// The benchmark files, from the file's own initial guess, against REFERENCE.md (B).
class FinishOnDatasets : public ::testing::TestWithParam<std::pair<const char*, double>> {};

TEST_P(FinishOnDatasets, ReachesTheBestKnownChi2FromTheFileGuess) {
  TORO_REQUIRE_DATASETS();
  const std::string path = std::string(TORO_DATASETS_DIR) + "/" + GetParam().first;
  PoseGraph g = readGraph(path);
  const double at_file = g2oChi2(g);
  EXPECT_TRUE(std::isfinite(at_file));
  EXPECT_GT(at_file, GetParam().second);
  EXPECT_TRUE(std::isfinite(seSyncObjective(g)));
  EXPECT_GT(seSyncObjective(g), 0.0);
  const FinishReport r = LevenbergMarquardt().optimize(g);
  EXPECT_NEAR(g2oChi2(g), GetParam().second, 1e-4 * GetParam().second) << finishStopName(r.stop);
}

INSTANTIATE_TEST_SUITE_P(Reference, FinishOnDatasets,
                         ::testing::Values(std::make_pair("sphere2500.g2o", 727.150),
                                           std::make_pair("parking-garage.g2o", 1.23869),
                                           std::make_pair("small/tinyGrid3D.g2o", 6.72788),
                                           std::make_pair("2d/intel.g2o", 45.0047),
                                           std::make_pair("2d/manhattanOlson3500.g2o", 146.077)));
