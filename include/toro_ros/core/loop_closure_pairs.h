// Whether two loop closures agree with each other, whatever the map: the pairwise consistency test
// of Mangelson, Dominic, Eustice and Vasudevan ("Pairwise Consistent Measurement Set Maximization
// for Robust Multi-robot Map Merging", ICRA 2018), on one robot's odometry.  Two loop closures
// a -> b and c -> d whose ends lie near each other (c near a, d near b) and the odometry between
// the near ends form a cycle
//   x_a^-1 x_b  =  (x_a^-1 x_c) (x_c^-1 x_d) (x_d^-1 x_b)  =  O_ac Z_cd O_db,
// so Z_ab^-1 O_ac Z_cd O_db is the identity up to the noise of its four parts when both are right.
// Why this test and not the map's residual: it reads only measurements, so it is as good on a map
// that has not converged, or that a wrong loop closure bent, as on a settled one; and a wrong loop
// closure between two places has a right partner only by chance (a second wrong one saying the
// same thing), where a right one of a revisit has its neighbours.
#pragma once

#include <cstddef>
#include <limits>
#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

constexpr std::size_t kNoOdometry = std::numeric_limits<std::size_t>::max();

// The odometry steps of a graph whose nodes are in driving order (dense index v follows v - 1):
// for each node, the index of an odometry constraint (not isLoopClosure, or as `is_loop_closure`
// says) between it and the node before, or kNoOdometry (the first node, or a gap).
std::vector<std::size_t> odometrySteps(const PoseGraph& graph, const std::vector<bool>& is_loop_closure);

// The odometry steps (odometrySteps) with each step's covariance ready for the tests below: the
// first-order covariance of the right perturbation of x_{v-1}^-1 x_v (translation, rotation; angle
// units; in the plane x, y, yaw and unit variance on the other axes).  Why kept: the tests compose
// runs of steps, the same steps many times, and inverting a step's information at every walk
// across it was most of their cost (4 % of the sphere2500 replay, node by node).  `planar` fixes
// which axes count.  Grows by append() as a live graph does; 36 doubles a node.
class OdometryChain {
 public:
  explicit OdometryChain(bool planar = false) : planar_(planar) {}
  OdometryChain(const PoseGraph& graph, const std::vector<bool>& is_loop_closure, bool planar);

  // The step of node size(): `step` is the index of an odometry constraint between that node and
  // the one before it, or kNoOdometry.
  void append(const PoseGraph& graph, std::size_t step);
  void clear();
  std::size_t size() const { return steps_.size(); }
  bool planar() const { return planar_; }
  std::size_t step(std::size_t v) const { return steps_[v]; }
  // Whether node v's step constraint is stored from v to v - 1 (its measurement is x_v^-1 x_{v-1}).
  bool reversed(std::size_t v) const { return reversed_[v]; }
  const Matrix6& covariance(std::size_t v) const { return covariances_[v]; }

 private:
  bool planar_;
  std::vector<std::size_t> steps_;
  std::vector<bool> reversed_;
  std::vector<Matrix6> covariances_;
};

// The chi2 of the cycle of loop closures `c1` and `c2` over the odometry between their near ends
// (first-order covariance of the four parts carried into one frame; g2o chi2 units, x, y and yaw
// only when the chain is planar), or -1 when the odometry does not connect the near ends.  Which
// ends are near is taken from the dense indices (the orientation with the shorter odometry).
// Cost: linear in the number of odometry steps between the near ends.
double loopClosurePairChi2(const PoseGraph& graph, const OdometryChain& odometry, std::size_t c1,
                           std::size_t c2);

// The chi2 of loop closure `c` against the odometry between its two ends (the cycle Z^-1 O_ab):
// a strong test where the two ends are a few steps apart (a place recogniser confusing nearby,
// similar-looking places), a weak one over a long stretch of drift.  -1 when the odometry does
// not connect them.  Cost: linear in the odometry steps between the ends.
double loopClosureOdometryChi2(const PoseGraph& graph, const OdometryChain& odometry, std::size_t c);

// One link of a chain of constraints: the constraint and the factor its information counts with
// (a robust weight: its covariance is divided by it).
struct ChainLink {
  std::size_t constraint = 0;
  double weight = 1.0;
};

// The chi2 of loop closure `c` against a chain of other constraints that walks from its `from`
// node to its `to` node (each link entered at either end): the cycle Z^-1 L_1 ... L_n, the links'
// covariances carried into one frame.  With the tree path of the constraints that count in the map
// as the chain, this asks the map's evidence rather than the odometry's: where accepted loop
// closures made the path between two places short and stiff, a claim far from it contradicts
// them, however many neighbours repeat it (a place recogniser's repeated confusion).  An upper
// bound of the map's uncertainty (one path, not every path), so it errs towards agreeing.  -1 when
// the links do not walk from `from` to `to`, or a weight is not positive.  Cost: linear in the links.
double loopClosureChainChi2(const PoseGraph& graph, std::size_t c, const std::vector<ChainLink>& chain, bool planar);

}  // namespace toro
