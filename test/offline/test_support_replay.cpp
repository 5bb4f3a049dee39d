// Support for loop closures (robust_hold_until_supported, on by default) on real datasets whose
// every loop closure is right: kitti_02 and kitti_05 (2D, replayed as 3D messages as a user's bag
// would carry them) and parking-garage through the Pipeline with default parameters.  Their revisits close
// long loops after shorter ones: the map's path between a long loop's ends runs through hundreds of
// keyframes, and its chi2 (kitti_02 8-17, kitti_05 6-10 over ~1,100-1,660 links) lies far above
// the short paths' scale (their low quantile 0.02-0.14, learnt from the first revisit) though
// within the declared covariances' 0.99 quantile (16.8), while the odometry over the loop's span
// agrees with it.  Such a path is in doubt, not a veto: before it was, the last revisit of kitti_02
// (5 loop closures) and two revisits of kitti_05 (27) were held to the end, the maps 0.24 m and
// 6.3 m from the optimum (final chi2 3,140 and 1.9e6, replayed as bags by toro_offline).  Replayed
// here, in memory, kitti_02 ended with none held either way (its messages' timing differs from the
// bag's); kitti_05 held 27 before (chi2 2.0e6 against the optimum 157.1).  The datasets are not part of the
// package
// (../shared/datasets beside a checkout): without them the tests skip.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <set>
#include <utility>
#include <vector>

#include "dataset_replay.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"

namespace toro_ros {
namespace offline {
namespace {

struct SupportRun {
  std::size_t loop_closures = 0;
  std::size_t held_at_end = 0;  // weighted below 0.5 at the end
  double chi2 = 0.0;            // the dataset's constraints at the final poses
  double optimum = 0.0;         // the plain finish from there: the optimum of the same graph
};

// The pipeline's state at the end; g: the graph judged.
SupportRun score(const std::string& file, Pipeline& p, toro::PoseGraph g) {
  SupportRun out;
  out.loop_closures = p.status().counters.loop_closures_applied;
  out.held_at_end = p.makeSnapshot()->down_weighted_loop_closures;
  out.chi2 = toro::g2oChi2(g);
  toro::FinishOptions o;
  o.max_iterations = 50;
  out.optimum = toro::LevenbergMarquardt(o).optimize(g).final_chi2;
  std::printf(
      "%s: %zu keyframes, %zu loop closures, %zu held at the end; chi2 %.6g, optimum of the same graph "
      "%.6g\n",
      file.c_str(), p.graph().numNodes(), out.loop_closures, out.held_at_end, out.chi2, out.optimum);
  return out;
}

// In memory, one keyframe per file node (the replay configuration).
SupportRun replay(const std::string& file) {
  const testing::DatasetReplay r = testing::loadDatasetReplay(file);
  Pipeline p(testing::replayOptions());
  testing::replayThrough(p, r);
  return score(file, p, testing::cleanGraphAtFinalPoses(p, r));
}

// As a user would first try it: graph_to_bag's defaults (20 Hz odometry), then toro_offline with
// the node's defaults (keyframes by distance and angle, so not the file's nodes: the pipeline's own
// graph is judged).  The in-memory route does not reproduce the bag's schedule of finishes.
// The bag of `file` with graph_to_bag's defaults through toro_offline's runner (`configure` may
// set more of its options); `inspect` sees the runner and its run before the files go.
void runBag(const std::string& file, const std::function<void(OfflineOptions*)>& configure,
            const std::function<void(OfflineRunner&, const OfflineRun&)>& inspect) {
  char dir_template[] = "/tmp/toro_support_XXXXXX";
  const std::string dir = mkdtemp(dir_template);
  GraphToBagOptions b;
  b.input_path = toro_test::datasetPath(file);
  b.output_bag = dir + "/replay.bag";
  graphToBag(b);
  OfflineOptions o;
  o.bag_path = b.output_bag;
  o.output_dir = dir + "/out";
  o.progress = false;
  o.iteration_curve = false;
  if (configure) configure(&o);
  OfflineRunner runner(o);
  const OfflineRun run = runner.run();
  inspect(runner, run);
  std::filesystem::remove_all(dir);
}

SupportRun replayBag(const std::string& file) {
  SupportRun out;
  runBag(file, {}, [&](OfflineRunner& runner, const OfflineRun&) {
    out = score(file, runner.pipeline(), runner.pipeline().graph());
  });
  return out;
}

// Every loop closure applied, none held at the end, the final passes within tolerance of the optimum.
void expectEveryOneCounts(const SupportRun& run, std::size_t loop_closures, double tolerance) {
  EXPECT_EQ(run.loop_closures, loop_closures);
  EXPECT_EQ(run.held_at_end, 0u);
  EXPECT_LE(run.chi2, (1.0 + tolerance) * run.optimum);
}

TEST(SupportReplay, Kitti02EveryRightLoopClosureCountsAndTheMapEndsAtTheOptimum) {
  TORO_REQUIRE_DATASETS();
  expectEveryOneCounts(replay("2d/kitti_02.g2o"), 43, 0.01);  // the final passes are TORO's (0.8 % here)
}

// With default keyframing a file node is several keyframes apart, and the last revisit's loop
// closures span ~5,300 keyframes: the odometry over so long a span was not composed, so nothing
// cleared their paths of doubt (5 held to the end, chi2 3,103 against the optimum 63.07, as a bag
// through toro_offline with defaults).
TEST(SupportReplay, Kitti02DefaultKeyframingLongSpansCount) {
  TORO_REQUIRE_DATASETS();
  expectEveryOneCounts(replayBag("2d/kitti_02.g2o"), 43, 0.01);
}

// A loop closure names the scans' stamps, between keyframes by default: the odometry from the
// keyframe to the stamp carries it, and its noise is the loop closure's too.  Before it was
// counted, CSAIL's revisit 254-716 (declared 1.7 mm, carried over ~0.1 m of odometry) stayed held
// to the end, the map 17 cm from it (chi2 15,490 against the optimum 40.4).
TEST(SupportReplay, CsailDefaultKeyframingCarriedLoopClosuresCount) {
  TORO_REQUIRE_DATASETS();
  expectEveryOneCounts(replayBag("2d/CSAIL.g2o"), 127, 1e-3);
}

// parking-garage declares covariances about 1e4 times its residuals: the short paths' scale is
// ~1e-4 of the declared one, and revisits' paths of a few links at 1 to 8 times that threshold
// (still far within the declared quantile, the odometry over their span agreeing) were vetoed.
// Before: 32 right loop closures held at the end, chi2 1.3734 against the optimum 1.2387.
TEST(SupportReplay, ParkingGarageEveryRightLoopClosureCountsAndTheMapEndsAtTheOptimum) {
  TORO_REQUIRE_DATASETS();
  expectEveryOneCounts(replay("parking-garage.g2o"), 4615, 1e-4);
}

// The first loop closure is wrong (bench_robust's seed-2 random one: nodes 0 and 17, 63 m off), and
// parking-garage declares 1 m and 1 rad per odometry step: 17 steps of that "agree" with anything,
// and it was accepted before any pair could teach the sender's scale (~1e-4 of the declared).
// Accepted, it bent the replayed map 14 m and the right loop closures of the garage's closing
// revisit ended held.  Judged again at the learnt scale it is held, the map at the clean optimum.
// The first 500 nodes (~120 loop closures; the scale is learnt within the first 60).
TEST(SupportReplay, ParkingGarageAWrongFirstLoopClosureIsJudgedAgainAtTheLearntScale) {
  TORO_REQUIRE_DATASETS();
  const toro::PoseGraph file = sortedById(toro::readGraph(toro_test::datasetPath("parking-garage.g2o")));
  constexpr toro::NodeId kLast = 499;
  testing::DatasetReplay r;
  r.file = "parking-garage.g2o";
  for (std::size_t i = 0; i < file.numNodes() && file.node(i).id <= kLast; ++i)
    r.graph.addNode(file.node(i).id, file.node(i).pose);
  for (const toro::Constraint& c : file.constraints())
    if (c.from <= kLast && c.to <= kLast) r.graph.addConstraint(c);
  r.clean_constraints = r.graph.numConstraints();
  const toro::Pose3 wrong(toro::Quaternion(0.99955958547041879, -0.0039598583577983232, 0.003605338504822041,
                                           0.029188287895260137),
                          toro::Vector3(-6.55346, 0.328641, 0.0118872));
  r.graph.addConstraint(toro::Constraint{0, 17, wrong, r.graph.constraints().front().information,
                                         toro::ConstraintKind::kLoopClosure});
  r.options.odometry_rate_hz = 4.0;
  r.options.keyframe_period_sec = 0.25;
  testing::makeMessages(&r);
  Pipeline p(testing::replayOptions());
  testing::replayThrough(p, r);
  const SupportRun run = score(r.file, p, testing::cleanGraphAtFinalPoses(p, r));
  EXPECT_GE(run.held_at_end, 1u);
  EXPECT_LE(run.held_at_end, 3u);
  EXPECT_LE(run.chi2, 1.01 * run.optimum);  // bent by the wrong one: 24 times (1.089 vs 0.0456)
}

TEST(SupportReplay, Kitti05LongLoopsCount) {
  TORO_REQUIRE_DATASETS();
  const SupportRun run = replay("2d/kitti_05.g2o");
  EXPECT_EQ(run.loop_closures, 66u);
  // One loop closure stays held: its path (21 links, chi2 46) is beyond the declared covariances'
  // quantile too, and its innovation against the finished map beyond the release threshold.
  EXPECT_LE(run.held_at_end, 1u);
  EXPECT_LE(run.chi2, 10.0 * run.optimum);
}

// MIT.g2o's front end reports a few loop closures per revisit, tens of keyframes apart.  As a bag
// with graph_to_bag's defaults (keyframes by distance: 3,480 of them), after a loop of ~1,300
// keyframes 1363->48, 1438->125, 1449->266 and 1542->198 are each alone within the support window,
// and the long loop's drift puts each 4 to 12 times above the finish's release threshold.  They
// agree with each other over a tenth of their span, so the finish releases them within
// kCorroboratedInnovationLenience (LoopClosureSupport::witnessedAcrossSpan); before, the published map
// ignored that revisit for ~510 s of message time (its chi2 12,000 to 27,000 times the optimum's)
// until later loop closures had brought it within reach (605 s with the earlier stretch below).
// Now ~50 s; the longest stretch left (247 s) is the first revisits', held until a second loop
// closure counts and the finish can read the covariances' scale (kMinLoopClosuresForScale).
TEST(SupportReplay, MitLongLoopsFewLoopClosuresAreNotHeldForMinutes) {
  TORO_REQUIRE_DATASETS();
  // The published map against the optimum of the graph so far (every loop closure at full weight),
  // 2 s of message time after a loop closure, at most every 5 s.
  std::vector<OfflineRun::Optimality> samples;
  std::size_t held_at_end = 0;
  runBag(
      "2d/MIT.g2o",
      [](OfflineOptions* o) {
        o->optimality_every_sec = 5.0;
        o->optimality_after_loop_closure_sec = 2.0;
      },
      [&](OfflineRunner& runner, const OfflineRun& run) {
        samples = run.optimality;
        held_at_end = runner.pipeline().makeSnapshot()->down_weighted_loop_closures;
      });
  // The longest stretch of message time over which the samples show the map ten times above the
  // optimum: a right loop closure not applied.
  double longest = 0.0, since = -1.0;
  for (const OfflineRun::Optimality& s : samples) {
    if (s.published_chi2 > 10.0 * s.optimum_chi2) {
      if (since < 0.0) since = s.stamp_sec;
      longest = std::max(longest, s.stamp_sec - since);
    } else {
      since = -1.0;
    }
  }
  std::printf("MIT: %zu samples, the longest stretch ten times above the optimum %.0f s\n", samples.size(),
              longest);
  ASSERT_GE(samples.size(), 10u);
  EXPECT_EQ(held_at_end, 0u);
  EXPECT_LE(longest, 400.0);
}

// A 2D robot's input in the 3D pipeline (planar: false, as a user's bag of a ground robot is read
// by default) is judged as in planar mode: its errors have three components, and the support and
// release tests count three (MapOptimizer::dof).  Counted as six, the variance factor came out half
// the planar one and the pair scale a third, every threshold narrower: CSAIL.g2o replayed so held
// 21 right loop closures at the end against planar mode's 1 (chi2 29,069 against the optimum
// 40.6), and manhattan.g2o as a bag through toro_offline 5 against 1.  The same loop closures
// held at the end both ways.
std::set<std::pair<toro::NodeId, toro::NodeId>> heldAtTheEnd(Pipeline& p) {
  std::set<std::pair<toro::NodeId, toro::NodeId>> held;
  for (const DownWeightedLoopClosure& d : p.status().down_weighted) held.emplace(d.from, d.to);
  return held;
}

TEST(SupportReplay, CsailPlanarInputInThe3DPipelineIsJudgedAsInPlanarMode) {
  TORO_REQUIRE_DATASETS();
  const std::string file = "2d/CSAIL.g2o";
  const testing::DatasetReplay r = testing::loadDatasetReplay(file);
  PipelineOptions spatial_options = testing::replayOptions();
  spatial_options.planar = false;
  PipelineOptions planar_options = spatial_options;
  planar_options.planar = true;
  Pipeline spatial(spatial_options), planar(planar_options);
  testing::replayThrough(spatial, r);
  testing::replayThrough(planar, r);
  const SupportRun s = score(file + " (3D)", spatial, testing::cleanGraphAtFinalPoses(spatial, r));
  const SupportRun p = score(file + " (planar)", planar, testing::cleanGraphAtFinalPoses(planar, r));
  EXPECT_EQ(s.loop_closures, p.loop_closures);
  EXPECT_EQ(heldAtTheEnd(spatial), heldAtTheEnd(planar));
  EXPECT_LE(s.held_at_end, 2u);
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros
