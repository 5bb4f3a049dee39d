// Wrong loop closures that agree with each other, between places the map holds stiffly, replayed
// through the Pipeline as toro_offline replays a bag (background finishes inline).  A synthetic
// sphere like sphere2500.g2o: rings of poses, each pose tied to the previous ring by a loop closure,
// every constraint declaring sphere2500's covariances (0.32 m, and 0.1 to 0.2 rad in rotation:
// far more than the noise).  The tree path between two rings several rings apart runs down towards
// the root and up again, so its composed covariance (each link's rotation uncertainty times the
// lever arm of the sphere) is metres wide and does not contradict a claim metres off, and neither
// does the odometry over the span; the neighbours of a repeated wrong claim agree with it.  Only
// the map, which every ring's loop closures make stiff, contradicts it: a loop closure that far
// from the map (beyond 10 robust widths and the 0.99 quantile) waits for the background finish's
// innovation test, its residual against the whole map's uncertainty, instead of counting on its
// neighbours.  Before, with partners' support enough, sphere2500.g2o replayed with 100 grouped
// wrong loop closures (bench_robust seed 1) accepted 38 and ended 33.9 m from its optimum.  Not
// covered: a group that claims a place one pose beside the right one lies within reach of the map
// and still passes by its neighbours (toro::addOutliers seed 4 here: before and now).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "dataset_replay.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/outlier_generator.h"
#include "toro_ros/core/random_draws.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/core/synthetic.h"

namespace toro_ros {
namespace offline {
namespace {

using Pair = std::pair<toro::NodeId, toro::NodeId>;
Pair ends(toro::NodeId a, toro::NodeId b) { return {std::min(a, b), std::max(a, b)}; }

struct SphereRun {
  double rms = 0.0;                                // final positions against the sphere's truth, aligned
  std::size_t wrong_accepted = 0;                  // wrong loop closures weighted >= 0.5 at the end
  std::size_t right_held = 0;                      // right loop closures weighted < 0.5 at the end
  std::vector<std::vector<Eigen::Vector3d>> maps;  // every keyframe's position after each odometry message
  std::size_t from_scratch = 0;                    // finishes that also solved from scratch
  std::size_t from_scratch_kept = 0;               // ... and kept that solution
};

// The largest distance between a keyframe's positions in two runs' maps after the same odometry
// message: how far apart a tf listener would have seen the two maps.
double largestGap(const SphereRun& a, const SphereRun& b) {
  double gap = 0.0;
  for (std::size_t m = 0; m < std::min(a.maps.size(), b.maps.size()); ++m)
    for (std::size_t k = 0; k < std::min(a.maps[m].size(), b.maps[m].size()); ++k)
      gap = std::max(gap, (a.maps[m][k] - b.maps[m][k]).norm());
  return gap;
}

SphereRun replaySphere(const toro::SyntheticGraph& sphere, const toro::GraphWithOutliers& input) {
  const testing::DatasetReplay r =
      testing::graphReplay(input.graph, "synthetic sphere", sphere.graph.numConstraints());
  Pipeline p(testing::replayOptions());
  SphereRun out;
  testing::replayThrough(p, r, [&out](const Pipeline& q) {
    std::vector<Eigen::Vector3d> positions;
    for (const toro::Node& n : q.graph().nodes()) positions.push_back(n.pose.translation());
    out.maps.push_back(std::move(positions));
  });
  out.rms = toro::alignedPositionRmse(p.graph(), sphere.graph);  // the sphere's nodes are at the truth
  out.from_scratch = p.counters().finishes_from_scratch;
  out.from_scratch_kept = p.counters().finishes_from_scratch_kept;
  std::set<Pair> wrong, wrong_held;
  for (std::size_t c : input.outliers)
    wrong.insert(ends(input.graph.constraints()[c].from, input.graph.constraints()[c].to));
  for (const DownWeightedLoopClosure& d : p.status().down_weighted) {
    if (d.weight >= 0.5) continue;
    if (wrong.count(ends(d.from, d.to)) > 0)
      wrong_held.insert(ends(d.from, d.to));
    else
      ++out.right_held;
  }
  out.wrong_accepted = wrong.size() - wrong_held.size();
  std::printf("%zu wrong loop closures: %zu accepted; %zu right ones held; RMS against the truth %.4g m\n",
              wrong.size(), out.wrong_accepted, out.right_held, out.rms);
  return out;
}

// 15 rings of 40 poses on a sphere of 20 m radius; noise 5 cm and 0.01 rad per axis; every
// constraint declares sphere2500.g2o's information (g2o units: 10 on translation, 400, 400 and 100
// on the rotation's quaternion vector).
toro::SyntheticGraph sphere() {
  toro::NoiseOptions noise;
  noise.translation_sigma_m = 0.05;
  noise.rotation_sigma_rad = 0.01;
  noise.seed = 7;
  toro::SyntheticGraph s = toro::makeSphere(15, 40, 20.0, noise);
  toro::PoseGraph declared;
  for (const toro::Node& n : s.graph.nodes()) declared.addNode(n.id, n.pose);
  for (toro::Constraint c : s.graph.constraints()) {
    c.information = toro::Matrix6::Zero();
    c.information.diagonal() << 10, 10, 10, 400, 400, 100;
    declared.addConstraint(c);
  }
  s.graph = declared;
  return s;
}

// The sphere with `count` wrong loop closures of `kind` (toro::addOutliers with `seed`) replayed.
SphereRun replayWithOutliers(const toro::SyntheticGraph& s, toro::OutlierKind kind, std::size_t count,
                             unsigned seed) {
  toro::OutlierOptions o;
  o.kind = kind;
  o.count = count;
  o.seed = seed;
  return replaySphere(s, toro::addOutliers(s.graph, o, &s.graph));
}

TEST(InnovationSupport, WrongGroupsBetweenPlacesTheMapHoldsStifflyNeverBendIt) {
  const toro::SyntheticGraph s = sphere();
  const SphereRun clean = replaySphere(s, toro::GraphWithOutliers{s.graph, {}});
  // Five groups of ten (toro::addOutliers, seed 3): each ten agree with each other; three of the
  // five join rings seven or eight apart.  Before, partners' support let one of those in (the path
  // and the odometry over its span "agreeing"): the map bent 21 m, and the ten were still accepted
  // at the end, 2.8 m RMS against the truth.
  const SphereRun wrong = replayWithOutliers(s, toro::OutlierKind::kGrouped, 50, 3);
  const double gap = largestGap(clean, wrong);
  std::printf("largest gap between the two runs' maps: %.4g m\n", gap);
  EXPECT_EQ(clean.right_held, 0u);
  EXPECT_EQ(wrong.wrong_accepted, 0u);
  EXPECT_EQ(wrong.right_held, 0u);
  EXPECT_LT(wrong.rms, 1.05 * clean.rms);
  EXPECT_LT(gap, 0.1);
}

// Wrong loop closures a few poses apart (a recogniser confusing nearby scans), dense in the first
// ring: before the sender's scale is learnt the short odometry between their ends cannot refute
// them, so some are accepted and bend the first ring; once the scale is learnt they are judged
// again and held (rejudgeAccepted).  The finishes had settled the map with them, and a finish
// warm-started from that bent map stays in its basin: before, its chi2 stayed at 75 where the
// graph's optimum was 0.7, the first revisit's right loop closures, measured against it, were held
// to the end (4 here), and the map ended 2.2 m from the clean run's (0.27 m RMS against the truth,
// clean 0.087 m).  Now the next finish also solves the map from scratch and keeps the lower end.
TEST(InnovationSupport, AMapBentByLoopClosuresHeldLaterIsSolvedAgainFromScratch) {
  const toro::SyntheticGraph s = sphere();
  const SphereRun clean = replaySphere(s, toro::GraphWithOutliers{s.graph, {}});
  const SphereRun wrong = replayWithOutliers(s, toro::OutlierKind::kLocal, 150, 2);
  // The wrong ones bend the map while the first ring is driven (nothing can tell them yet); from
  // the first revisit on, the two runs must show the same map.
  SphereRun late_clean, late_wrong;
  const std::size_t n = std::min(clean.maps.size(), wrong.maps.size());
  late_clean.maps.assign(clean.maps.begin() + n / 4, clean.maps.begin() + n);
  late_wrong.maps.assign(wrong.maps.begin() + n / 4, wrong.maps.begin() + n);
  const double late_gap = largestGap(late_clean, late_wrong);
  std::printf("largest gap between the two runs' maps after the first quarter: %.4g m; finishes from scratch %zu, "
              "kept %zu\n",
              late_gap, wrong.from_scratch, wrong.from_scratch_kept);
  EXPECT_EQ(clean.from_scratch, 0u);
  EXPECT_GE(wrong.from_scratch_kept, 1u);
  EXPECT_EQ(wrong.wrong_accepted, 0u);
  EXPECT_EQ(wrong.right_held, 0u);
  EXPECT_LT(wrong.rms, 1.05 * clean.rms);
  EXPECT_LT(late_gap, 0.5);
}

// A sender whose right loop closures have heavier tails than its declared covariance says (real
// front ends: 3.6-7.8 % of them beyond the chi-square model's 0.99 quantile,
// bench/innovation_calibration.md): a track driven in laps, one loop closure per pose to the lap
// before, a tenth of them with three times the declared standard deviation.  Then two excursions,
// each closed by one loop closure that nothing else supports (a lone revisit after 120 keyframes):
// only the map can judge them, by their leave-one-out innovation.  The first lies at 1.5 times the
// model's threshold: a right one in the sender's own tail, which the threshold calibrated on the
// sender's accepted loop closures releases (held to the end before).  The second lies at 3 times,
// beyond the calibrated threshold's bound (twice the model's), where the wrong ones nearest to
// being right lie: it stays held, however heavy the sender's tail.
namespace calibration {

constexpr double kStep = 0.5;  // m between poses

// Appends `steps` poses, each kStep ahead of the last; the last one of each side of a rectangle
// turns by `turn` rad (the corners).
void drive(std::vector<toro::Pose3>* truth, const std::vector<int>& sides, double turn) {
  for (int side : sides)
    for (int i = 0; i < side; ++i)
      truth->push_back(truth->back() *
                       toro::Pose3::fromRollPitchYaw(kStep, 0, 0, 0, 0, i + 1 == side ? turn : 0.0));
}

struct LapsAndExcursions {
  toro::PoseGraph graph;         // initial poses at the truth; lap loop closures, then the two lone ones
  std::size_t within_tail = 0;   // the lone loop closure at 1.5 times the threshold (constraint index)
  std::size_t beyond_bound = 0;  // ... at 3 times
};

// The lone loop closure (a, b) with its innovation at `ratio` times `threshold`: its measurement
// is the map's own prediction (`optimum`: the graph without it, optimised) moved along a fixed direction,
// by as much as gives that innovation (first order; checked by the caller's finish).
toro::Constraint loneLoopClosure(const toro::PoseGraph& optimum, std::size_t a, std::size_t b, double ratio,
                                 double threshold, const toro::Matrix6& information) {
  toro::Constraint c;
  c.from = static_cast<toro::NodeId>(a);
  c.to = static_cast<toro::NodeId>(b);
  c.information = information;
  const toro::Pose3 predicted = toro::relativePose(optimum.node(a).pose, optimum.node(b).pose);
  const auto moved = [&](double s) {
    return predicted * toro::Pose3::fromRollPitchYaw(s, s, 0, 0, 0, 0.1 * s);
  };
  c.measurement = moved(0.1);
  toro::PoseGraph finished = optimum;
  const double at_unit = toro::LevenbergMarquardt().optimize(finished, {}, {c}).innovation_chi2.at(0);
  c.measurement = moved(0.1 * std::sqrt(ratio * threshold / at_unit));
  return c;
}

LapsAndExcursions make(std::uint32_t seed) {
  // Seven laps of a 12 m x 8 m track (80 poses a lap), a 15 m square excursion (120 poses), 10 m
  // straight on, another 15 m square, 20 m straight on (time for the finishes to test the last).
  std::vector<toro::Pose3> truth{toro::Pose3::identity()};
  for (int lap = 0; lap < 7; ++lap) drive(&truth, {24, 16, 24, 16}, M_PI / 2);
  const std::size_t first_start = truth.size() - 1;
  drive(&truth, {30, 30, 30, 30}, -M_PI / 2);
  const std::size_t first_end = truth.size() - 1;
  drive(&truth, {20}, 0.0);
  const std::size_t second_start = truth.size() - 1;
  drive(&truth, {30, 30, 30, 30}, -M_PI / 2);
  const std::size_t second_end = truth.size() - 1;
  drive(&truth, {40}, 0.0);
  std::vector<std::pair<std::size_t, std::size_t>> laps;
  for (std::size_t i = 80; i <= first_start; ++i) laps.emplace_back(i - 80, i);
  toro::NoiseOptions noise;
  noise.translation_sigma_m = 0.02;
  noise.rotation_sigma_rad = 0.005;
  noise.seed = seed;
  toro::SyntheticGraph s = toro::makeFromTrajectory(truth, laps, noise);
  // The heavy tail: a tenth of the loop closures with 3 times the declared standard deviation.
  std::mt19937 rng(seed + 1000);
  std::bernoulli_distribution in_tail(0.1);
  std::normal_distribution<double> extra_t(0.0, std::sqrt(8.0) * noise.translation_sigma_m),
      extra_r(0.0, std::sqrt(8.0) * noise.rotation_sigma_rad);
  toro::PoseGraph graph;
  for (const toro::Node& n : s.graph.nodes()) graph.addNode(n.id, n.pose);
  for (toro::Constraint c : s.graph.constraints()) {
    if (c.to != c.from + 1 && in_tail(rng))
      c.measurement = c.measurement * toro::drawPose3(extra_r, extra_t, rng);
    graph.addConstraint(c);
  }
  const toro::Matrix6 information = s.graph.constraints().back().information;
  const double threshold = toro::chiSquareQuantile(0.99, 6);  // the model's, 6 degrees of freedom
  LapsAndExcursions out;
  toro::PoseGraph optimum = graph;
  toro::LevenbergMarquardt().optimize(optimum);
  const toro::Constraint within =
      loneLoopClosure(optimum, first_start, first_end, 1.5, threshold, information);
  const toro::Constraint beyond =
      loneLoopClosure(optimum, second_start, second_end, 2.5, threshold, information);
  out.graph = graph;
  out.within_tail = out.graph.numConstraints();
  out.graph.addConstraint(within);
  out.beyond_bound = out.graph.numConstraints();
  out.graph.addConstraint(beyond);
  return out;
}

}  // namespace calibration

TEST(InnovationSupport, ALoneRightLoopClosureInTheSendersOwnTailIsReleasedWithinABound) {
  for (std::uint32_t seed : {1u, 2u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const calibration::LapsAndExcursions s = calibration::make(seed);
    // The lone ones' innovations against the map without both, as the pipeline's finishes test them.
    toro::PoseGraph without =
        toro::keepConstraints(s.graph, [&](std::size_t c) { return c < s.within_tail; });
    const std::vector<double> innovations =
        toro::LevenbergMarquardt()
            .optimize(without, {},
                      {s.graph.constraints()[s.within_tail], s.graph.constraints()[s.beyond_bound]})
            .innovation_chi2;
    const double threshold = toro::chiSquareQuantile(0.99, 6);
    std::printf("lone loop closures' innovations: %.3g and %.3g times the model's threshold\n",
                innovations.at(0) / threshold, innovations.at(1) / threshold);
    ASSERT_NEAR(innovations.at(0), 1.5 * threshold, 0.15 * threshold);
    ASSERT_NEAR(innovations.at(1), 2.5 * threshold, 0.25 * threshold);

    Pipeline p(testing::replayOptions());
    testing::replayThrough(p, testing::graphReplay(s.graph, "laps and excursions"));
    const auto weightOf = [&](std::size_t c) {
      const Pair e = ends(s.graph.constraints()[c].from, s.graph.constraints()[c].to);
      for (const DownWeightedLoopClosure& d : p.status().down_weighted)
        if (ends(d.from, d.to) == e) return d.weight;
      return 1.0;
    };
    std::size_t held = 0;
    for (const DownWeightedLoopClosure& d : p.status().down_weighted) held += d.weight < 0.5;
    std::printf(
        "weights of the lone ones: %.3g and %.3g; loop closures held in all %zu; released by their "
        "innovation %llu\n",
        weightOf(s.within_tail), weightOf(s.beyond_bound), held,
        static_cast<unsigned long long>(p.counters().loop_closures_released_predicted));
    EXPECT_GE(weightOf(s.within_tail), 0.5);
    EXPECT_LT(weightOf(s.beyond_bound), 0.5);
  }
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros
