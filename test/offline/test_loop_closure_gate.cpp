// The loop-closure gate on real datasets: sphere2500 and parking-garage replayed through the
// Pipeline (messages synthesised in memory as graph_to_bag writes them, one odometry message per
// keyframe), once clean and once with 5 % extra loop closures between unrelated poses (seeded),
// gated at 0.99, and once more with them ungated.  The final error (g2o chi2 of the dataset's own
// constraints at the corrected poses, after the same final passes as toro_offline) must stay
// within 10 % of the clean run's (gated too), and the rejected set must hold the injected ones.
// The wall times printed include the gate's copy of the optimiser per loop closure.  The datasets
// are not part of the package (../shared/datasets beside a checkout): without them both tests skip.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <random>
#include <set>

#include "dataset_replay.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/random_draws.h"

namespace toro_ros {
namespace offline {
namespace {

using testing::DatasetReplay;

// Extra loop closures as a wrong place recogniser makes them: between two poses at least
// `kMinGap` keyframes and kMinDistance metres apart (in the odometry the robot reports), each
// claiming that they are at nearly the same place (up to 1 m and 0.3 rad apart), with the
// information of the dataset's first loop closure.
constexpr long kMinGap = 50;
constexpr double kMinDistance = 10.0;

DatasetReplay makeReplay(const std::string& file, double outlier_fraction, unsigned seed) {
  DatasetReplay r = testing::loadDatasetReplay(file);
  r.background_finishes = false;
  const RobotTimeline& clean = r.timeline;
  std::size_t loop_closures = 0;
  toro::Matrix6 info = toro::Matrix6::Identity();
  for (std::size_t c = 0; c < r.graph.numConstraints(); ++c)
    if (clean.is_loop_closure[c] && loop_closures++ == 0) info = r.graph.constraints()[c].information;
  std::mt19937 rng(seed);
  const long n = static_cast<long>(r.graph.numNodes());
  std::uniform_int_distribution<long> node(0, n - 1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const auto extra = static_cast<std::size_t>(std::lround(outlier_fraction * loop_closures));
  for (std::size_t k = 0; k < extra;) {
    const long a = std::min(node(rng), node(rng)), b = std::max(node(rng), node(rng));
    if (b - a < kMinGap ||
        (clean.odom_T_base[a].translation() - clean.odom_T_base[b].translation()).norm() < kMinDistance)
      continue;
    const auto d = toro::drawLastFirst<6>(u, rng);
    const toro::Pose3 z =
        toro::Pose3::fromRollPitchYaw(d[0], d[1], 0.2 * d[2], 0.1 * d[3], 0.1 * d[4], 0.3 * d[5]);
    r.graph.addConstraint(toro::Constraint{r.graph.node(a).id, r.graph.node(b).id, z, info});
    ++k;
  }
  testing::makeMessages(&r);
  return r;
}

struct GateRun {
  double chi2 = 0;                  // of the clean constraints at the final poses
  std::set<std::size_t> rejected;   // constraint indices into DatasetReplay::graph
  double seconds = 0;
  std::size_t applied = 0;
};

GateRun run(const DatasetReplay& r, double confidence, double variance_factor) {
  PipelineOptions po = testing::replayOptions();
  po.loop_closure_gate_confidence = confidence;
  po.loop_closure_gate_variance_factor = variance_factor;
  // The gate alone: robust weights (on by default) would hide what the gate does and does not do.
  po.robust.kernel = toro::RobustKernel::kNone;
  Pipeline p(po);
  const auto t0 = std::chrono::steady_clock::now();
  testing::replayThrough(p, r);
  GateRun out;
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  out.applied = p.status().counters.loop_closures_applied;
  EXPECT_EQ(p.graph().numNodes(), r.graph.numNodes());
  // Score against the dataset's constraints only.
  out.chi2 = toro::g2oChi2(testing::cleanGraphAtFinalPoses(p, r));
  for (const RejectedLoopClosure& x : p.rejectedLoopClosures()) {
    const toro::NodeId from = r.graph.node(p.graph().indexOf(x.constraint.from)).id;
    const toro::NodeId to = r.graph.node(p.graph().indexOf(x.constraint.to)).id;
    for (std::size_t c = 0; c < r.graph.numConstraints(); ++c)
      if (r.timeline.is_loop_closure[c] && r.graph.constraints()[c].from == from && r.graph.constraints()[c].to == to)
        out.rejected.insert(c);
  }
  return out;
}

struct Outcome {
  GateRun clean, dirty, ungated;
  std::size_t injected = 0, caught = 0;
};

Outcome runDataset(const std::string& file, double variance_factor) {
  const DatasetReplay clean = makeReplay(file, 0.0, 1);
  const DatasetReplay dirty = makeReplay(file, 0.05, 1);
  Outcome o;
  o.clean = run(clean, 0.99, variance_factor);
  o.dirty = run(dirty, 0.99, variance_factor);
  o.ungated = run(dirty, 0.0, variance_factor);
  o.injected = dirty.graph.numConstraints() - dirty.clean_constraints;
  for (std::size_t k : o.dirty.rejected) o.caught += k >= dirty.clean_constraints;
  std::printf("%s (variance factor %g): clean chi2 %.4g (%zu right ones rejected, %.2f s); with %zu injected: "
              "chi2 %.4g (%zu rejected, %zu of them injected, %.2f s); ungated %.4g (%.2f s)\n",
              file.c_str(), variance_factor, o.clean.chi2, o.clean.rejected.size(), o.clean.seconds, o.injected,
              o.dirty.chi2, o.dirty.rejected.size(), o.caught, o.dirty.seconds, o.ungated.chi2, o.ungated.seconds);
  return o;
}

// sphere2500 declares covariances its residuals agree with: the gate as configured by default
// (0.99, variance factor 1) meets the target.  2,500 keyframes, about 10 s.
TEST(LoopClosureGate, Sphere2500WithinTenPercentOfTheCleanRun) {
  TORO_REQUIRE_DATASETS();
  const Outcome o = runDataset("sphere2500.g2o", 1.0);
  EXPECT_LE(o.dirty.chi2, 1.10 * o.clean.chi2);
  EXPECT_GE(o.caught, o.injected * 9 / 10);
  EXPECT_GT(o.ungated.chi2, 10 * o.clean.chi2);  // the injected ones do matter
}

// parking-garage declares covariances about 1e4 times its residuals (chi2 1.6 over ~37,000
// residual components): with them as declared, 100 m of wrong loop closure is "plausible" and the
// gate cannot work.  With the variance factor 5e-4 it catches every injected one; the right ones
// it rejects while an undetected wrong one still bends the map are re-admitted once the re-check
// has removed it (11 right ones stay rejected in the clean run).  Measured at the time of
// writing: clean 1.582, with the injected ones 1.704 (+7.7 %).  The factor is a scale the user
// must know (2e-4: +6.8 %; 1e-3: one injected one survives and the error is 2000x), see
// loop_closure_gate_variance_factor in config/map_corrector.yaml.
TEST(LoopClosureGate, ParkingGarageWithAVarianceFactorWithinTenPercent) {
  TORO_REQUIRE_DATASETS();
  const Outcome o = runDataset("parking-garage.g2o", 5e-4);
  EXPECT_LE(o.dirty.chi2, 1.10 * o.clean.chi2);
  EXPECT_EQ(o.caught, o.injected);
  EXPECT_LT(o.dirty.chi2, 1e-3 * o.ungated.chi2);
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros
