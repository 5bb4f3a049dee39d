#include "toro_ros/pipeline/snapshot_builder.h"

#include "toro_ros/core/robust_kernel.h"

namespace toro_ros {

namespace {

SnapshotKeyframe keyframeAt(const toro::PoseGraph& g, const std::vector<KeyframeRecord>& records, std::size_t i) {
  return SnapshotKeyframe{records[i].id, records[i].stamp, g.node(i).pose};
}

SnapshotEdge edgeAt(toro::TreeOptimizer& optimizer, const std::vector<bool>& is_loop_closure, std::size_t c) {
  const bool lc = c < is_loop_closure.size() && is_loop_closure[c];
  // Only loop closures carry their chi2 (the markers colour them by it); odometry shows 0.
  return SnapshotEdge{optimizer.fromIndex(c), optimizer.toIndex(c), lc, lc ? optimizer.constraintChi2(c) : 0.0,
                      optimizer.weights()[c]};
}

bool downWeightedEdge(const SnapshotEdge& e) { return e.loop_closure && e.weight < toro::kRejectedWeight; }

bool sameEdge(const SnapshotEdge& a, const SnapshotEdge& b) {
  return a.from_index == b.from_index && a.to_index == b.to_index && a.loop_closure == b.loop_closure &&
         a.chi2 == b.chi2 && a.weight == b.weight;
}

}  // namespace

void SnapshotBuilder::update(toro::TreeOptimizer& optimizer, const std::vector<KeyframeRecord>& records,
                             const std::vector<bool>& is_loop_closure) {
  const toro::OptimizerChanges changes = optimizer.takeChanges();
  const toro::PoseGraph& g = optimizer.graph();
  last_written_ = 0;
  if (changes.all || keyframes_.size() > records.size() || edges_.size() > g.numConstraints()) {
    keyframes_.clear();
    edges_.clear();
    down_weighted_ = 0;
  } else {
    for (std::size_t v : changes.nodes) {
      if (v >= keyframes_.size()) continue;  // appended below
      keyframes_.set(v, keyframeAt(g, records, v));
      ++last_written_;
    }
    for (std::size_t c : changes.constraints) {
      if (c >= edges_.size()) continue;
      const SnapshotEdge e = edgeAt(optimizer, is_loop_closure, c);
      // Odometry edges at moved nodes are listed too, but what they show does not change: their
      // chunks stay shared.
      if (sameEdge(e, edges_[c])) continue;
      down_weighted_ += downWeightedEdge(e);
      down_weighted_ -= downWeightedEdge(edges_[c]);
      edges_.set(c, e);
      ++last_written_;
    }
  }
  // records[i] is node i; the pipeline keeps the two the same length.
  const std::size_t nodes = std::min(records.size(), g.numNodes());
  for (std::size_t i = keyframes_.size(); i < nodes; ++i, ++last_written_) keyframes_.push_back(keyframeAt(g, records, i));
  for (std::size_t c = edges_.size(); c < g.numConstraints(); ++c, ++last_written_) {
    const SnapshotEdge e = edgeAt(optimizer, is_loop_closure, c);
    down_weighted_ += downWeightedEdge(e);
    edges_.push_back(e);
  }
}

}  // namespace toro_ros
