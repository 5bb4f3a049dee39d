// The loop-closure gate.  A place recogniser is sometimes wrong, and one wrong loop closure pulls
// the whole map out of shape.  Each new loop closure is therefore applied tentatively: the
// optimiser is copied first (O(graph), measured in test_loop_closure_gate), the loop closure's
// affected pass runs as scheduled, and then its own g2o chi2 is compared with the chi-square
// quantile with 6 degrees of freedom at the configured confidence.  Above it, the copy is
// restored (plus the keyframes that arrived in between) and the loop closure kept as rejected.
//
// Order of events: only one loop closure is on trial at a time.  When another one is applied
// before the trial ended (several arriving together, or while paused), the pending one's pass and
// test run first, so each is judged against a graph that holds only loop closures that passed.
// A wrong loop closure arriving before the right ones is judged against odometry alone, which
// is what a gate can do without hindsight: its residual after one pass is large when the
// odometry chain between its poses disagrees with it.
#include <algorithm>
#include <cmath>

#include "toro_ros/core/finish_residuals.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

namespace {

// The innovation chi2 of a new constraint, e_before^T Omega e_after, from its g2o error before
// and after its pass.  Why: in a linear-Gaussian update with S = Sigma_z + Sigma_path (the
// uncertainty of the measurement plus that of the path between its poses),
// e_after = Sigma_z S^-1 e_before, so e_before^T Omega e_after = e_before^T S^-1 e_before, the
// textbook innovation test, without computing any covariance.  Its own chi2 after the pass,
// e_after^T Omega e_after, is smaller by the factor Sigma_z / S and cannot tell a wrong loop
// closure that the pass absorbed into a long uncertain path from a right one.
double innovationChi2(const toro::PoseGraph& before, const toro::PoseGraph& after, std::size_t c) {
  const toro::Constraint& k = after.constraints()[c];
  const toro::Vector6 e0 = toro::errorSE3(before.pose(k.from), before.pose(k.to), k.measurement);
  const toro::Vector6 e1 = toro::errorSE3(after.pose(k.from), after.pose(k.to), k.measurement);
  return e0.dot(k.information * e1);
}

constexpr const char* kArrivalReason = "loop closure: failed the chi-square gate";
constexpr const char* kRecheckReason = "loop closure: failed the chi-square gate on re-check";

}  // namespace

void Pipeline::beginGate(const LoopClosure& msg) {
  settleGate();
  before_gate_ = optimizer_;
  gate_constraint_ = optimizer_.graph().numConstraints();
  gate_stamp_ = msg.header.stamp;
}

void Pipeline::settleGate() {
  if (!before_gate_) return;
  if (affected_pending_) runAffectedPass();
  const double own = toro::constraintChi2(optimizer_.graph(), gate_constraint_);
  // TORO's pass is not the exact linear update: it may overshoot (a negative product) or leave
  // more than the linear share, so the larger of both measures is tested.
  const double chi2 =
      std::max(own, std::abs(innovationChi2(before_gate_->graph(), optimizer_.graph(), gate_constraint_)));
  if (!(chi2 <= gate_threshold_)) rejectCandidate(chi2);
  before_gate_.reset();
}

void Pipeline::rejectCandidate(double chi2) {
  const toro::PoseGraph now = optimizer_.graph();
  const toro::Constraint candidate = now.constraints()[gate_constraint_];
  optimizer_ = std::move(*before_gate_);
  before_gate_.reset();
  // Keyframes made while the candidate was on trial: each keeps its pose relative to the one
  // before it, and the odometry constraints (every constraint after the candidate) are re-added.
  for (std::size_t i = optimizer_.graph().numNodes(); i < now.numNodes(); ++i) {
    const toro::Pose3 step = toro::relativePose(now.node(i - 1).pose, now.node(i).pose);
    optimizer_.addNode(now.node(i).id, optimizer_.graph().node(i - 1).pose * step);
  }
  for (std::size_t c = gate_constraint_ + 1; c < now.numConstraints(); ++c)
    optimizer_.addConstraint(now.constraints()[c]);
  is_loop_closure_.erase(is_loop_closure_.begin() + static_cast<std::ptrdiff_t>(gate_constraint_));
  last_chi2_ = optimizer_.chi2();
  if (loop_closures_since_full_ > 0) --loop_closures_since_full_;
  --counters_.loop_closures_applied;
  ++counters_.loop_closures_rejected;
  ++counters_.loop_closures_refused;
  rejected_.push_back(RejectedLoopClosure{candidate, gate_stamp_, chi2});
  refuse(kArrivalReason,
         "loop closure " + std::to_string(candidate.from) + " -> " + std::to_string(candidate.to) +
             " (message stamp " + stampString(gate_stamp_) + ") rejected: chi2 " + std::to_string(chi2) +
             " after its pass exceeds " + std::to_string(gate_threshold_) + "; the graph is restored without it");
}

// A right loop closure can fail the gate because a wrong one that passed (the gate cannot know
// better at the time) bends the map near it; the re-check removes the wrong one later, one per
// round.  So when a round ends with no loop closure failing, each rejected one is tested again
// against the map as it is now: if its chi2 at the current poses, before any pass (stricter than
// the innovation test it failed), is within the threshold, the map agrees with it and it is
// applied.  A wrong one never agrees with a right map.
bool Pipeline::readmitRejected() {
  const toro::PoseGraph& g = optimizer_.graph();
  std::size_t readmitted = 0;
  for (auto it = rejected_.begin(); it != rejected_.end();) {
    const toro::Constraint& c = it->constraint;
    if (!g.hasNode(c.from) || !g.hasNode(c.to)) {
      ++it;
      continue;
    }
    const toro::Vector6 e = toro::errorSE3(g.pose(c.from), g.pose(c.to), c.measurement);
    if (!(e.dot(c.information * e) <= gate_threshold_)) {
      ++it;
      continue;
    }
    toro::Constraint loop_closure = c;
    loop_closure.kind = toro::ConstraintKind::kLoopClosure;  // sidecar-loaded ones come as kAuto
    optimizer_.addConstraint(loop_closure);
    is_loop_closure_.push_back(true);
    ++counters_.loop_closures_applied;
    ++counters_.loop_closures_readmitted;
    --counters_.loop_closures_rejected;
    --counters_.loop_closures_refused;
    // The counts by reason say how many are refused now, like loop_closures_rejected.
    std::uint64_t& by_reason = counters_.refused_by_reason[it->stamp.isZero() ? kRecheckReason : kArrivalReason];
    if (by_reason > 0) --by_reason;
    it = rejected_.erase(it);
    ++readmitted;
  }
  if (readmitted == 0) return false;
  if (warn_) warn_(std::to_string(readmitted) + " rejected loop closure(s) re-admitted: the map agrees with them now");
  affected_pending_ = true;
  loop_closures_since_full_ += readmitted;
  last_chi2_ = optimizer_.chi2();
  ++revision_;
  return true;
}

bool Pipeline::recheckLoopClosures() {
  if (!gateEnabled() || before_gate_) return false;
  const toro::PoseGraph& g = optimizer_.graph();
  std::size_t worst = g.numConstraints();
  double worst_chi2 = gate_threshold_;
  for (std::size_t c = 0; c < g.numConstraints(); ++c) {
    if (!is_loop_closure_[c]) continue;
    const double chi2 = toro::constraintChi2(g, c);
    if (chi2 > worst_chi2) {
      worst_chi2 = chi2;
      worst = c;
    }
  }
  if (worst == g.numConstraints()) return readmitRejected();
  // Only the worst: one wrong loop closure inflates the residuals of right ones near it.
  toro::PoseGraph without;
  for (const toro::Node& n : g.nodes()) without.addNode(n.id, n.pose);
  for (std::size_t c = 0; c < g.numConstraints(); ++c)
    if (c != worst) without.addConstraint(g.constraints()[c]);
  const toro::Constraint removed = g.constraints()[worst];
  is_loop_closure_.erase(is_loop_closure_.begin() + static_cast<std::ptrdiff_t>(worst));
  replaceGraph(without);
  last_chi2_ = optimizer_.chi2();
  --counters_.loop_closures_applied;
  ++counters_.loop_closures_rejected;
  ++counters_.loop_closures_refused;
  rejected_.push_back(RejectedLoopClosure{removed, ros::Time(), worst_chi2});
  refuse(kRecheckReason,
         "loop closure " + std::to_string(removed.from) + " -> " + std::to_string(removed.to) + " removed: chi2 " +
             std::to_string(worst_chi2) + " after a full round exceeds " + std::to_string(gate_threshold_));
  return true;
}

}  // namespace toro_ros
