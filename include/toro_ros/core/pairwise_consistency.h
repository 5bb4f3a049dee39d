// Which loop closures of a whole graph their neighbours agree with: the pairwise consistency of
// loop_closure_pairs.h (Mangelson et al., ICRA 2018) applied to every loop closure at once, for the
// batch optimiser's robust dead-reckoning and corroborated starts (robust_optimizer.cpp,
// heldFromDeadReckoning).  The live pipeline asks
// the same question one arrival at a time (LoopClosureSupport::consistentPartners, with the same window,
// partner count and scale statistic).
//
// Why the batch needs it: its starts judged each loop closure against the odometry alone, at the
// declared covariances.  A sender whose covariances are far too large (parking-garage.g2o: its
// residuals are ~1e-4 of what it declares) makes every wrong loop closure look consistent with the
// odometry, and the map bent by them ended metres from the right one (100 random wrong ones: 10.9 m
// RMSE).  Pairs of nearby loop closures read the sender's real scale from the data (their cycles'
// low quantile) and judge each loop closure by measurements only.
#pragma once

#include <cstddef>
#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

enum class PairVerdict : signed char {
  kNotALoopClosure = 0,
  kAlone,         // no other loop closure near both of its ends (and not a short span): nothing to ask
  kAgreed,        // enough neighbours agree with it, or the short odometry between its ends does
  kContradicted,  // it has neighbours and too few agree, or the short odometry disagrees
};

struct PairwiseConsistency {
  std::vector<PairVerdict> verdicts;  // one per constraint
  // The tested cycles' low quantile against the chi-square's (kPairScaleLenience times, never above
  // 1): how much smaller than declared the sender's errors are.  1 until kMinPairsForScale cycles
  // were tested.
  double scale = 1.0;
  bool scale_learnt = false;  // false: too few pairs; every loop closure is then kAlone
  std::size_t pairs_tested = 0;
};

// Neighbours: loop closures with each end within this many nodes (in id order) of the other's.
// A loop closure whose two ends are this close is judged by the odometry between them instead.
constexpr std::size_t kPairWindowNodes = 25;
// Agreement of this many neighbours makes a loop closure agreed (two wrong ones agree by chance
// now and then; a right one of a revisit has several neighbours).
constexpr std::size_t kMinAgreeingPartners = 2;
// Pairs tested per loop closure at most, nearest neighbours first (each costs a walk along the
// odometry between the near ends; the nearest give the shortest, most precise cycles).  Searched
// in node order instead, parking-garage's 4,700 loop closures took 0.55 s (42,000 pairs); nearest
// first, 0.12 s (36,000).
constexpr std::size_t kMaxPairsPerLoopClosure = 16;
// Cycles needed before the scale is read and any verdict is given.
constexpr std::size_t kMinPairsForScale = 10;
// A cycle agrees within the 0.99 chi-square quantile times the scale.  The scale is this many times
// the ratio of the cycles' 0.2 quantile to the chi-square's: real residuals are heavier-tailed and
// correlated (loop closures of one scan matcher), so the low quantile alone reads them too small.
constexpr double kPairConfidence = 0.99;
constexpr double kPairScaleQuantile = 0.2;
constexpr double kPairScaleLenience = 4.0;

// Nodes must be in driving order by id (consecutive ids joined by odometry, as isLoopClosure
// assumes); loop closures are the constraints isLoopClosure names.  Reads measurements only, not
// the poses.
PairwiseConsistency pairwiseConsistency(const PoseGraph& graph);

}  // namespace toro
