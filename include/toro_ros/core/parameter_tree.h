// The parameterisation tree of TORO (Grisetti et al., IROS 2007 / RSS 2007).
//
// Root: the smallest id of each connected component.  Parent: the node with the smallest id that
// shares a constraint with the node.  Whenever every non-root node has a neighbour with a smaller id
// (always so when ids are timestamps and each keyframe is linked to the previous one), that is
// literally the rule; for other graphs the tree is grown from the root, attaching the smallest
// unattached id next to its smallest attached neighbour, which coincides with the rule above
// whenever the rule yields a tree.
//
// All indices are PoseGraph dense indices (insertion order), not ids.
#pragma once

#include <cstdint>
#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

class ParameterTree {
 public:
  static constexpr std::size_t kNone = static_cast<std::size_t>(-1);

  // Builds the whole tree from the graph (discarding any previous state).
  void build(const PoseGraph& graph);

  // Incremental growth: call after the graph gained node `node_index` (with no constraints yet)
  // or constraint `constraint_index`.  The result equals build() on the grown graph.  Nodes whose
  // parent changed are appended to `reparented` (if given) so their parameters can be re-derived.
  void addNode(const PoseGraph& graph, std::size_t node_index);
  // With may_be_tree_edge false the constraint does not shape the tree (it becomes nobody's parent
  // link) unless it joins two components; then the result equals build() on the graph without it.
  // Returns false when it was kept out that way (it may be added again later, shaping the tree;
  // a full rebuild, which only graphs out of time order or joined components need, counts it).
  bool addConstraint(const PoseGraph& graph, std::size_t constraint_index,
                     std::vector<std::size_t>* reparented = nullptr, bool may_be_tree_edge = true);

  std::size_t size() const { return parent_.size(); }
  std::size_t parent(std::size_t node) const { return parent_[node]; }
  bool isRoot(std::size_t node) const { return parent_[node] == kNone; }
  int level(std::size_t node) const { return level_[node]; }
  const std::vector<std::size_t>& children(std::size_t node) const { return children_[node]; }
  const std::vector<std::size_t>& parents() const { return parent_; }
  const std::vector<int>& levels() const { return level_; }

  // The node nearest the root on the tree path between a and b (kNone if they lie in different
  // components).
  std::size_t topNode(std::size_t a, std::size_t b) const;

  // The tree path of a constraint a -> b: `up` holds a, parent(a), ... up to (excluding) the top
  // node; `down` holds b, parent(b), ... up to (excluding) the top node.  Returns the top node.
  std::size_t path(std::size_t a, std::size_t b, std::vector<std::size_t>& up,
                   std::vector<std::size_t>& down) const;

  // Nodes ordered so that every parent precedes its children (roots first).
  std::vector<std::size_t> topologicalOrder() const;

  // Number of times the incremental update fell back to a full rebuild (graphs whose ids are not
  // in time order); exposed for tests and diagnostics.
  std::size_t rebuilds() const { return rebuilds_; }
  // Whether the smallest-neighbour rule spans the graph (see the class comment).
  bool followsSmallestNeighbourRule() const { return normal_; }

 private:
  void setLevelsBelow(std::size_t node);
  void detach(std::size_t node);
  std::size_t rootOf(std::size_t node) const;
  void buildByGrowing(const PoseGraph& graph, const std::vector<std::size_t>& by_id);
  void rebuildKeepingNeighbours(const PoseGraph& graph, std::vector<std::size_t>* reparented);
  // Smallest-id neighbour of `node` among all its neighbours (kNone if isolated).
  std::size_t smallestNeighbour(const PoseGraph& graph, std::size_t node) const;

  std::vector<std::size_t> parent_;
  std::vector<int> level_;
  std::vector<std::vector<std::size_t>> children_;
  // Neighbour lists (dense indices, parallel constraints repeated) kept for incremental updates.
  std::vector<std::vector<std::size_t>> neighbours_;
  std::size_t rebuilds_ = 0;
  // True when the smallest-neighbour rule spans every component (the usual case); then additions
  // are O(subtree) updates, otherwise each addition rebuilds.
  bool normal_ = true;
};

}  // namespace toro
