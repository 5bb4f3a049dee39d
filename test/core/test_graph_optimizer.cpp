// The combined driver: TORO phase, switch-over rule, finish, and the per-iteration report.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "shared_datasets.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/graph_optimizer.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/random_draws.h"

using namespace toro;

namespace {

// A noisy 3D loop with chords; node poses are the truth perturbed, measurements noisy.
PoseGraph noisyLoop(unsigned seed, int n = 40) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  auto jitter = [&](double r, double t) {
    const Vector3 translation = t * drawVector3(noise, rng);
    return Pose3::fromAngleAxis(r * drawVector3(noise, rng), translation);
  };
  std::vector<Pose3> truth;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    truth.push_back(
        Pose3::fromRollPitchYaw(8 * std::cos(a), 8 * std::sin(a), 0.5 * std::sin(2 * a), 0, 0.1, a));
  }
  PoseGraph g;
  for (int i = 0; i < n; ++i) g.addNode(i, truth[i] * jitter(0.2, 0.5));
  Matrix6 info = Matrix6::Identity();
  info.bottomRightCorner<3, 3>() *= 400.0;
  for (int i = 0; i < n; ++i) {
    g.addConstraint(
        Constraint{i, (i + 1) % n, relativePose(truth[i], truth[(i + 1) % n]) * jitter(0.01, 0.05), info});
  }
  for (int i = 0; i + 10 < n; i += 5) {
    g.addConstraint(Constraint{i, i + 10, relativePose(truth[i], truth[i + 10]) * jitter(0.01, 0.05), info});
  }
  return g;
}

}  // namespace

TEST(GraphOptimizer, ModeNamesRoundTrip) {
  for (OptimizeMode m : {OptimizeMode::kToro, OptimizeMode::kFinish, OptimizeMode::kToroThenFinish}) {
    OptimizeMode parsed = OptimizeMode::kToro;
    ASSERT_TRUE(parseOptimizeMode(optimizeModeName(m), &parsed));
    EXPECT_EQ(parsed, m);
  }
  OptimizeMode unchanged = OptimizeMode::kFinish;
  EXPECT_FALSE(parseOptimizeMode("gauss-newton", &unchanged));
  EXPECT_EQ(unchanged, OptimizeMode::kFinish);
}

TEST(GraphOptimizer, OptionsAreValidated) {
  OptimizeOptions o;
  EXPECT_EQ(o.validate(), "");
  o.toro_min_iterations = o.toro_max_iterations + 1;
  o.switch_relative_decrease = -0.1;
  o.finish.max_iterations = 0;
  const std::string why = o.validate();
  EXPECT_NE(why.find("toro_min_iterations"), std::string::npos);
  EXPECT_NE(why.find("switch_relative_decrease"), std::string::npos);
  EXPECT_NE(why.find("finish: max_iterations"), std::string::npos);
  PoseGraph g = noisyLoop(1);
  EXPECT_THROW(optimizeGraph(g, o), std::invalid_argument);
}

TEST(GraphOptimizer, ToroOnlyRunsTheBudgetWithoutSwitchThreshold) {
  PoseGraph g = noisyLoop(2);
  OptimizeOptions o;
  o.mode = OptimizeMode::kToro;
  o.toro_max_iterations = 7;
  o.toro_min_iterations = 1;
  o.switch_relative_decrease = 0.0;
  const OptimizeReport r = optimizeGraph(g, o);
  EXPECT_EQ(r.toro_iterations, 7u);
  EXPECT_EQ(r.finish.stop, FinishStop::kNotRun);
  ASSERT_EQ(r.history.size(), 8u);
  EXPECT_EQ(r.history.front().phase, OptimizePhase::kStart);
  for (std::size_t k = 1; k < r.history.size(); ++k) {
    EXPECT_EQ(r.history[k].phase, OptimizePhase::kToro);
    EXPECT_EQ(r.history[k].iteration, k);
  }
  EXPECT_NEAR(r.final_chi2, g2oChi2(g), 1e-12 * r.final_chi2);
  EXPECT_NEAR(r.history.back().chi2, r.final_chi2, 1e-12 * r.final_chi2);
  EXPECT_LT(r.final_chi2, r.initial_chi2);
}

TEST(GraphOptimizer, SwitchesWhenToroStopsMakingProgressThenFinishes) {
  PoseGraph g = noisyLoop(3);
  OptimizeOptions o;
  o.toro_max_iterations = 200;
  o.toro_min_iterations = 2;
  o.switch_relative_decrease = 0.05;
  std::vector<OptimizeIteration> seen;
  const OptimizeReport r = optimizeGraph(g, o, [&](const OptimizeIteration& it) { seen.push_back(it); });
  ASSERT_EQ(seen.size(), r.history.size());
  ASSERT_GE(r.toro_iterations, 2u);
  ASSERT_LT(r.toro_iterations, 200u);  // the threshold fired, not the budget
  // The rule: every TORO iteration from the minimum on decreased chi2 by >= 5% except the last.
  for (std::size_t k = 2; k <= r.toro_iterations; ++k) {
    const double decrease = (seen[k - 1].chi2 - seen[k].chi2) / seen[k - 1].chi2;
    if (k < r.toro_iterations) {
      EXPECT_GE(decrease, 0.05) << k;
    } else {
      EXPECT_LT(decrease, 0.05);
    }
  }
  ASSERT_GT(r.finish.iterations, 0u);
  EXPECT_EQ(seen[r.toro_iterations + 1].phase, OptimizePhase::kFinish);
  EXPECT_EQ(seen.back().phase, OptimizePhase::kFinish);
  EXPECT_NEAR(r.final_chi2, g2oChi2(g), 1e-12 * r.final_chi2);
  // Same minimum as the finish alone from the file poses (this graph has no other basin).
  PoseGraph direct = noisyLoop(3);
  OptimizeOptions finish_only;
  finish_only.mode = OptimizeMode::kFinish;
  finish_only.initial_guess = InitialGuess::kFromGraph;
  finish_only.finish.relative_decrease_tolerance = 1e-14;
  o.finish.relative_decrease_tolerance = 1e-14;
  PoseGraph again = noisyLoop(3);
  const double combined = optimizeGraph(again, o).final_chi2;
  const OptimizeReport fr = optimizeGraph(direct, finish_only);
  EXPECT_EQ(fr.toro_iterations, 0u);
  EXPECT_NEAR(fr.initial_chi2, g2oChi2(noisyLoop(3)), 1e-12 * fr.initial_chi2);
  EXPECT_NEAR(combined, fr.final_chi2, 1e-9 * fr.final_chi2);
}

// TORO then finish from the chained initial guess, against REFERENCE.md (B).
class ToroThenFinishOnDatasets : public ::testing::TestWithParam<std::pair<const char*, double>> {};

TEST_P(ToroThenFinishOnDatasets, ReachesTheBestKnownChi2FromTheChainedGuess) {
  TORO_REQUIRE_DATASETS();
  PoseGraph g = readGraph(std::string(TORO_DATASETS_DIR) + "/" + GetParam().first);
  OptimizeOptions o;  // defaults: toro+finish from the chained guess
  const OptimizeReport r = optimizeGraph(g, o);
  EXPECT_GT(r.toro_iterations, 0u);
  EXPECT_NEAR(g2oChi2(g), GetParam().second, 1e-4 * GetParam().second) << r.switch_reason;
}

INSTANTIATE_TEST_SUITE_P(Reference, ToroThenFinishOnDatasets,
                         ::testing::Values(std::make_pair("sphere2500.g2o", 727.150),
                                           std::make_pair("parking-garage.g2o", 1.23869),
                                           std::make_pair("2d/MIT.g2o", 41.1633),
                                           // very poor start: reached only with the larger TORO
                                           // steps before the finish (kToroGammaBeforeFinish)
                                           std::make_pair("sphere_bignoise_vertex3.g2o", 743862.7)));

TEST(GraphOptimizer, ToroGammaOneBeforeTheFinishMissesTheBestBasinOnBigNoise) {
  // The reason for kToroGammaBeforeFinish: with TORO's own gamma the finish ends in a worse minimum.
  TORO_REQUIRE_DATASETS();
  PoseGraph g = readGraph(std::string(TORO_DATASETS_DIR) + "/sphere_bignoise_vertex3.g2o");
  OptimizeOptions o;
  o.toro.gamma = TreeOptimizerOptions{}.gamma;
  optimizeGraph(g, o);
  EXPECT_GT(g2oChi2(g), 1.1 * 743862.7);
}

TEST(GraphOptimizer, ToroPhaseEscapesTheLocalMinimumOfTheFileGuessOnMIT) {
  // REFERENCE.md (B): from MIT.g2o's own poses LM stops in a local minimum (770.664 there);
  // TORO first reaches the best known 41.1633 (previous test).
  TORO_REQUIRE_DATASETS();
  PoseGraph g = readGraph(std::string(TORO_DATASETS_DIR) + "/2d/MIT.g2o");
  OptimizeOptions o;
  o.mode = OptimizeMode::kFinish;
  o.initial_guess = InitialGuess::kFromGraph;
  optimizeGraph(g, o);
  EXPECT_GT(g2oChi2(g), 10 * 41.1633);
}
