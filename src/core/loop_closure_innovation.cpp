#include "toro_ros/core/loop_closure_innovation.h"

#include <Eigen/Cholesky>

#include "toro_ros/core/tree_optimizer.h"

namespace toro {

namespace {

// The path's covariance is taken this many times larger than the declared one: odometry
// covariances leave out the systematic errors (wheel radius, slip, a yaw bias) that dominate real
// drift, so a right loop closure after a long lap sits at 3 to 4 declared standard deviations
// (test_pipeline_robust: 3 % scale and 0.02 rad/m against the default 0.05 m / 0.02 rad per
// keyframe).  4 (twice the standard deviation) brings it back inside the kernel's width.
constexpr double kPathCovarianceLenience = 4.0;

// A tree edge with no weighted information: as good as unconstrained, without infinities.
constexpr double kUnconstrainedVariance = 1e12;

// Covariance (angle units, frame of v) of v relative to its tree parent p, from the constraints
// between them other than `skip`, each weighted by its robust weight.
Matrix6 edgeCovariance(const TreeOptimizer& opt, std::size_t v, std::size_t p, std::size_t skip) {
  const PoseGraph& g = opt.graph();
  Matrix6 information = Matrix6::Zero();
  for (std::size_t k : opt.incident(v)) {
    if (k == skip) continue;
    const std::size_t from = opt.fromIndex(k), to = opt.toIndex(k);
    if (!((from == p && to == v) || (from == v && to == p))) continue;
    const Matrix6 omega = opt.weights()[k] * quaternionToAngleUnits(g.constraints()[k].information);
    if (to == v) {
      information += omega;  // its error lives in the frame of its `to` end, v
    } else {
      // p measured from v: its error lives in p's frame; carried into v's by Ad(v^-1 p).
      const Matrix6 a = adjoint(relativePose(g.node(v).pose, g.node(p).pose));
      const Eigen::LDLT<Matrix6> ldlt(omega);
      if (ldlt.info() != Eigen::Success) continue;
      const Matrix6 cov = a * ldlt.solve(Matrix6::Identity()) * a.transpose();
      const Eigen::LDLT<Matrix6> back(cov);
      if (back.info() == Eigen::Success) information += back.solve(Matrix6::Identity());
    }
  }
  const Eigen::LDLT<Matrix6> ldlt(information);
  if (!(information.diagonal().minCoeff() > 0.0) || ldlt.info() != Eigen::Success)
    return kUnconstrainedVariance * Matrix6::Identity();
  return ldlt.solve(Matrix6::Identity());
}

// The other constraint at v (not `skip`, not to `avoid`) with the largest weighted information: the
// way round a loop closure that is v's tree edge.  kNone if there is none.
std::size_t strongestOther(const TreeOptimizer& opt, std::size_t v, std::size_t avoid, std::size_t skip) {
  std::size_t best = ParameterTree::kNone;
  double best_trace = 0.0;
  for (std::size_t k : opt.incident(v)) {
    if (k == skip) continue;
    const std::size_t u = opt.fromIndex(k) == v ? opt.toIndex(k) : opt.fromIndex(k);
    if (u == avoid) continue;
    const double trace = opt.weights()[k] * opt.graph().constraints()[k].information.trace();
    if (trace > best_trace) {
      best_trace = trace;
      best = k;
    }
  }
  return best;
}

// When c is itself the tree edge of `end` (its other end being end's parent), the tree path
// between its ends is c alone; the path then starts at end's strongest other neighbour instead,
// and `extra` (frame of `end`) gets end's covariance relative to that neighbour.  Returns the node
// the path starts from.
std::size_t aroundLoopClosure(const TreeOptimizer& opt, std::size_t end, std::size_t other, std::size_t c,
                              Matrix6* extra) {
  if (opt.tree().parent(end) != other) return end;
  if (edgeCovariance(opt, end, other, c)(0, 0) < kUnconstrainedVariance) return end;  // other links exist
  const std::size_t k = strongestOther(opt, end, other, c);
  if (k == ParameterTree::kNone) return end;
  const std::size_t u = opt.fromIndex(k) == end ? opt.toIndex(k) : opt.fromIndex(k);
  *extra = edgeCovariance(opt, end, u, ParameterTree::kNone);
  return u;
}

// edgeCovariance(v, parent p, leaving out c), from the batch's cache when c is not between them.
Matrix6 treeEdgeCovariance(const TreeOptimizer& opt, std::size_t v, std::size_t p, std::size_t c,
                           InnovationScratch& scratch) {
  const std::size_t from = opt.fromIndex(c), to = opt.toIndex(c);
  const bool c_on_edge = (from == v && to == p) || (from == p && to == v);
  if (!scratch.caching || c_on_edge || v >= scratch.valid.size()) return edgeCovariance(opt, v, p, c);
  if (!scratch.valid[v]) {
    scratch.edge_covariance[v] = edgeCovariance(opt, v, p, ParameterTree::kNone);
    scratch.valid[v] = 1;
  }
  return scratch.edge_covariance[v];
}

}  // namespace

void InnovationScratch::beginBatch(std::size_t nodes) {
  caching = true;
  valid.assign(nodes, 0);
  if (edge_covariance.size() < nodes) edge_covariance.resize(nodes);
}

double loopClosureInnovationChi2(const TreeOptimizer& opt, std::size_t c, InnovationScratch& scratch) {
  const PoseGraph& g = opt.graph();
  const Constraint& k = g.constraints()[c];
  const std::size_t a = opt.fromIndex(c), b = opt.toIndex(c);
  const Pose3& world_T_b = g.node(b).pose;
  const Pose3 b_T_world = world_T_b.inverse();
  Matrix6 around_a = Matrix6::Zero(), around_b = Matrix6::Zero();
  const std::size_t start_a = aroundLoopClosure(opt, a, b, c, &around_a);
  const std::size_t start_b = aroundLoopClosure(opt, b, a, c, &around_b);
  if (opt.tree().path(start_a, start_b, scratch.up, scratch.down) == ParameterTree::kNone) return 0.0;
  const Matrix6 ad_a = adjoint(b_T_world * g.node(a).pose);
  Matrix6 total = around_b + ad_a * around_a * ad_a.transpose();
  for (const auto* branch : {&scratch.up, &scratch.down}) {
    for (std::size_t v : *branch) {
      const Matrix6 edge = treeEdgeCovariance(opt, v, opt.tree().parent(v), c, scratch);
      // Only down-weighted (or held) loop closures hold this edge: the path says nothing, and a
      // ~0 chi2 would pass for a measured agreement (it narrowed the adaptive width to nothing).
      if (!(edge(0, 0) < kUnconstrainedVariance)) return -1.0;
      const Matrix6 ad = adjoint(b_T_world * g.node(v).pose);
      total += ad * edge * ad.transpose();
    }
  }
  total *= kPathCovarianceLenience;
  const Eigen::LDLT<Matrix6> own(quaternionToAngleUnits(k.information));
  if (own.info() != Eigen::Success) return 0.0;
  total += own.solve(Matrix6::Identity());
  const Pose3 d = k.measurement.inverse() * (g.node(a).pose.inverse() * world_T_b);
  Vector6 e;
  e << d.translation(), d.angleAxis();
  const Eigen::LDLT<Matrix6> ldlt(total);
  if (ldlt.info() != Eigen::Success) return 0.0;
  return e.dot(ldlt.solve(e));
}

}  // namespace toro
