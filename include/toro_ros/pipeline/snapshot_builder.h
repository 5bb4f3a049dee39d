// The pipeline's working copy of what its snapshots show (keyframes and edges), brought up to
// date from the optimiser's change journal (toro::TreeOptimizer::takeChanges): only the keyframes
// that moved and the edges whose chi2 or weight changed are rewritten, new ones appended, and a
// snapshot takes a copy that shares every unchanged chunk.  So a snapshot after one new keyframe
// or one affected pass costs what changed (plus a pointer per 1024 elements), not the map's size.
#pragma once

#include <cstddef>
#include <vector>

#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/pipeline/loop_closure_matcher.h"
#include "toro_ros/pipeline/snapshot.h"

namespace toro_ros {

class SnapshotBuilder {
 public:
  // `records[i]` is graph node i (the pipeline's keyframes); `is_loop_closure` per constraint.
  // Rebuilds everything when the journal says so (a full pass, a new or restored optimiser) or
  // when the graph shrank.
  void update(toro::TreeOptimizer& optimizer, const std::vector<KeyframeRecord>& records,
              const std::vector<bool>& is_loop_closure);
  // Copies for a Snapshot that share every chunk (chunked_vector.h).
  ChunkedVector<SnapshotKeyframe> shareKeyframes() { return keyframes_.share(); }
  ChunkedVector<SnapshotEdge> shareEdges() { return edges_.share(); }
  // Edges with loop_closure and weight < toro::kRejectedWeight.
  std::size_t downWeighted() const { return down_weighted_; }
  // How many keyframes and edges the last update wrote (appended or changed): for tests of the
  // work per update.
  std::size_t lastWritten() const { return last_written_; }

 private:
  ChunkedVector<SnapshotKeyframe> keyframes_;
  ChunkedVector<SnapshotEdge> edges_;
  std::size_t down_weighted_ = 0;
  std::size_t last_written_ = 0;
};

}  // namespace toro_ros
