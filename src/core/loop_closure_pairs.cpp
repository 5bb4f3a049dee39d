#include "toro_ros/core/loop_closure_pairs.h"

#include "toro_ros/core/odometry_consistency.h"

#include <Eigen/Cholesky>
#include <cstdlib>

namespace toro {

namespace {

// A relative pose with the covariance of its right perturbation (A exp(e), e ordered translation,
// rotation; angle units), first order.
struct UncertainPose {
  Pose3 pose;
  Matrix6 covariance;
};

// (A exp(ea)) (B exp(eb)) = A B exp(Ad(B^-1) ea + eb).
UncertainPose compose(const UncertainPose& a, const UncertainPose& b) {
  const Matrix6 ad = adjoint(b.pose.inverse());
  return {a.pose * b.pose, ad * a.covariance * ad.transpose() + b.covariance};
}

// (A exp(e))^-1 = exp(-e) A^-1 = A^-1 exp(-Ad(A) e).
UncertainPose inverse(const UncertainPose& a) {
  const Matrix6 ad = adjoint(a.pose);
  return {a.pose.inverse(), ad * a.covariance * ad.transpose()};
}

// A constraint's measurement and covariance.  In the plane only the x, y, yaw block is read (the
// others may be zero in a planar graph); the other axes get unit variance, which the x, y, yaw
// block of every composition never sees (planar adjoints keep that block to itself).
UncertainPose measurementOf(const Constraint& k, bool planar) {
  const Matrix6 info = quaternionToAngleUnits(k.information);
  Matrix6 cov = Matrix6::Zero();
  if (planar) {
    const int axes[3] = {0, 1, 5};
    Matrix3 block;
    for (int r = 0; r < 3; ++r)
      for (int s = 0; s < 3; ++s) block(r, s) = info(axes[r], axes[s]);
    const Eigen::LDLT<Matrix3> ldlt(block);
    const Matrix3 inv = ldlt.solve(Matrix3::Identity());
    cov.setIdentity();
    for (int r = 0; r < 3; ++r)
      for (int s = 0; s < 3; ++s) cov(axes[r], axes[s]) = inv(r, s);
  } else {
    const Eigen::LDLT<Matrix6> ldlt(info);
    cov = ldlt.solve(Matrix6::Identity());
  }
  return {k.measurement, cov};
}

// The odometry from dense node u to dense node w (x_u^-1 x_w), false when a step is missing.
bool odometryBetween(const PoseGraph& graph, const OdometryChain& odometry, std::size_t u, std::size_t w,
                     UncertainPose* out) {
  const std::size_t lo = std::min(u, w), hi = std::max(u, w);
  UncertainPose chain{Pose3(), Matrix6::Zero()};
  for (std::size_t v = lo + 1; v <= hi; ++v) {
    const std::size_t step = odometry.step(v);
    if (step == kNoOdometry) return false;
    const Pose3& z = graph.constraints()[step].measurement;
    chain = compose(chain, {odometry.reversed(v) ? z.inverse() : z, odometry.covariance(v)});
  }
  *out = u <= w ? chain : inverse(chain);
  return true;
}

// The chi2 of a cycle that should compose to the identity.
double cycleChi2(const UncertainPose& cycle, bool planar);

}  // namespace

std::vector<std::size_t> odometrySteps(const PoseGraph& graph, const std::vector<bool>& is_loop_closure) {
  std::vector<std::size_t> steps(graph.numNodes(), kNoOdometry);
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    const Constraint& k = graph.constraints()[c];
    if (c < is_loop_closure.size() ? is_loop_closure[c] : isLoopClosure(k)) continue;
    const std::size_t a = graph.indexOf(k.from), b = graph.indexOf(k.to);
    const std::size_t later = std::max(a, b);
    if (later == std::min(a, b) + 1 && steps[later] == kNoOdometry) steps[later] = c;
  }
  return steps;
}

OdometryChain::OdometryChain(const PoseGraph& graph, const std::vector<bool>& is_loop_closure, bool planar)
    : planar_(planar) {
  for (std::size_t step : odometrySteps(graph, is_loop_closure)) append(graph, step);
}

void OdometryChain::append(const PoseGraph& graph, std::size_t step) {
  const std::size_t v = steps_.size();
  steps_.push_back(step);
  reversed_.push_back(false);
  covariances_.emplace_back(Matrix6::Zero());
  if (step == kNoOdometry) return;
  const Constraint& k = graph.constraints()[step];
  UncertainPose forward = measurementOf(k, planar_);
  if (graph.indexOf(k.from) != v - 1) {  // stored from v to v - 1
    forward = inverse(forward);
    reversed_.back() = true;
  }
  covariances_.back() = forward.covariance;
}

void OdometryChain::clear() {
  steps_.clear();
  reversed_.clear();
  covariances_.clear();
}

double loopClosurePairChi2(const PoseGraph& graph, const OdometryChain& odometry, std::size_t c1,
                           std::size_t c2) {
  const bool planar = odometry.planar();
  const Constraint& k1 = graph.constraints()[c1];
  const Constraint& k2 = graph.constraints()[c2];
  const std::size_t a = graph.indexOf(k1.from), b = graph.indexOf(k1.to);
  std::size_t c = graph.indexOf(k2.from), d = graph.indexOf(k2.to);
  UncertainPose z2 = measurementOf(k2, planar);
  const auto gap = [](std::size_t x, std::size_t y) { return x > y ? x - y : y - x; };
  if (gap(a, d) + gap(b, c) < gap(a, c) + gap(b, d)) {  // c2 runs the other way: take it backwards
    std::swap(c, d);
    z2 = inverse(z2);
  }
  UncertainPose o_ac, o_db;
  if (!odometryBetween(graph, odometry, a, c, &o_ac) || !odometryBetween(graph, odometry, d, b, &o_db))
    return -1.0;
  return cycleChi2(compose(compose(compose(inverse(measurementOf(k1, planar)), o_ac), z2), o_db), planar);
}

double loopClosureOdometryChi2(const PoseGraph& graph, const OdometryChain& odometry, std::size_t c) {
  const Constraint& k = graph.constraints()[c];
  UncertainPose o_ab;
  if (!odometryBetween(graph, odometry, graph.indexOf(k.from), graph.indexOf(k.to), &o_ab)) return -1.0;
  return cycleChi2(compose(inverse(measurementOf(k, odometry.planar())), o_ab), odometry.planar());
}

double loopClosureChainChi2(const PoseGraph& graph, std::size_t c, const std::vector<ChainLink>& chain, bool planar) {
  const Constraint& k = graph.constraints()[c];
  std::size_t at = graph.indexOf(k.from);
  UncertainPose walked{Pose3(), Matrix6::Zero()};
  for (const ChainLink& link : chain) {
    if (!(link.weight > 0.0) || link.constraint >= graph.numConstraints()) return -1.0;
    const Constraint& l = graph.constraints()[link.constraint];
    UncertainPose step = measurementOf(l, planar);
    step.covariance /= link.weight;
    const std::size_t from = graph.indexOf(l.from), to = graph.indexOf(l.to);
    if (from == at) {
      at = to;
    } else if (to == at) {
      step = inverse(step);
      at = from;
    } else {
      return -1.0;
    }
    walked = compose(walked, step);
  }
  if (at != graph.indexOf(k.to)) return -1.0;
  return cycleChi2(compose(inverse(measurementOf(k, planar)), walked), planar);
}

namespace {

double cycleChi2(const UncertainPose& cycle, bool planar) {
  return poseErrorChi2(cycle.pose, cycle.covariance, planar);
}

}  // namespace

}  // namespace toro
