#include "toro_ros/core/parameter_tree.h"

#include <algorithm>
#include <functional>
#include <numeric>
#include <queue>

namespace toro {

namespace {
using Index = std::size_t;
constexpr Index kNoNode = ParameterTree::kNone;
}  // namespace

void ParameterTree::build(const PoseGraph& graph) {
  const Index n = graph.numNodes();
  parent_.assign(n, kNoNode);
  level_.assign(n, 0);
  children_.assign(n, {});
  neighbours_.assign(n, {});
  for (const Constraint& c : graph.constraints()) {
    const Index a = graph.indexOf(c.from), b = graph.indexOf(c.to);
    neighbours_[a].push_back(b);
    neighbours_[b].push_back(a);
  }
  const auto id = [&](Index i) { return graph.node(i).id; };

  // Fast path, the paper's rule: parent = smallest-id neighbour when it is smaller than the node.
  normal_ = true;
  for (Index v = 0; v < n; ++v) {
    const Index s = smallestNeighbour(graph, v);
    if (s != kNoNode && id(s) < id(v)) parent_[v] = s;
  }
  // The rule gives a forest (parents have smaller ids).  It spans each connected component with one
  // tree only if no constraint joins two of its trees; otherwise fall back to growing the tree.
  std::vector<Index> by_id(n);
  std::iota(by_id.begin(), by_id.end(), Index{0});
  std::sort(by_id.begin(), by_id.end(), [&](Index a, Index b) { return id(a) < id(b); });
  std::vector<Index> root(n);
  for (Index v : by_id) root[v] = parent_[v] == kNoNode ? v : root[parent_[v]];
  for (const Constraint& c : graph.constraints()) {
    if (root[graph.indexOf(c.from)] != root[graph.indexOf(c.to)]) {
      normal_ = false;
      break;
    }
  }
  if (!normal_) buildByGrowing(graph, by_id);

  for (Index v = 0; v < n; ++v) {
    if (parent_[v] != kNoNode) children_[parent_[v]].push_back(v);
  }
  for (Index v = 0; v < n; ++v) {
    if (parent_[v] == kNoNode) setLevelsBelow(v);
  }
}

void ParameterTree::buildByGrowing(const PoseGraph& graph, const std::vector<std::size_t>& by_id) {
  // Prim-like growth from each component's smallest id: always attach the smallest unattached id
  // adjacent to the tree, below its smallest attached neighbour.  Deterministic, and equal to the
  // smallest-neighbour rule whenever that rule yields a spanning tree.
  const Index n = graph.numNodes();
  const auto id = [&](Index i) { return graph.node(i).id; };
  std::fill(parent_.begin(), parent_.end(), kNoNode);
  std::vector<char> attached(n, 0);
  using Entry = std::pair<NodeId, Index>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> frontier;
  for (Index start : by_id) {
    if (attached[start]) continue;
    frontier.push({id(start), start});
    while (!frontier.empty()) {
      const Index v = frontier.top().second;
      frontier.pop();
      if (attached[v]) continue;
      attached[v] = 1;
      Index best = kNoNode;
      for (Index u : neighbours_[v]) {
        if (attached[u] && u != v && (best == kNoNode || id(u) < id(best))) best = u;
        if (!attached[u]) frontier.push({id(u), u});
      }
      parent_[v] = best;
    }
  }
}

std::size_t ParameterTree::smallestNeighbour(const PoseGraph& graph, std::size_t node) const {
  Index best = kNoNode;
  for (Index u : neighbours_[node]) {
    if (best == kNoNode || graph.node(u).id < graph.node(best).id) best = u;
  }
  return best;
}

void ParameterTree::setLevelsBelow(std::size_t node) {
  // Iterative DFS: trees can be thousands of levels deep.
  std::vector<Index> stack{node};
  level_[node] = parent_[node] == kNoNode ? 0 : level_[parent_[node]] + 1;
  while (!stack.empty()) {
    const Index v = stack.back();
    stack.pop_back();
    for (Index c : children_[v]) {
      level_[c] = level_[v] + 1;
      stack.push_back(c);
    }
  }
}

void ParameterTree::addNode(const PoseGraph& graph, std::size_t node_index) {
  (void)graph;
  if (node_index != parent_.size()) {
    throw GraphError("ParameterTree::addNode: nodes must be added in the graph's order");
  }
  parent_.push_back(kNoNode);
  level_.push_back(0);
  children_.emplace_back();
  neighbours_.emplace_back();
}

bool ParameterTree::addConstraint(const PoseGraph& graph, std::size_t constraint_index,
                                  std::vector<std::size_t>* reparented, bool may_be_tree_edge) {
  const Constraint& c = graph.constraints()[constraint_index];
  Index u = graph.indexOf(c.from), v = graph.indexOf(c.to);
  // A constraint kept out of the tree's shape still needs a tree path between its ends.
  if (!may_be_tree_edge && rootOf(u) == rootOf(v)) return false;
  neighbours_[u].push_back(v);
  neighbours_[v].push_back(u);
  if (!normal_) {
    rebuildKeepingNeighbours(graph, reparented);
    return true;
  }
  // While the smallest-neighbour rule spans every component, a new constraint can only change the
  // parent of its larger-id end.  The rule stops spanning when the constraint joins two components
  // and the larger-id end is not the root of its own: that root then keeps no smaller neighbour
  // although it is no longer its component's smallest id; only a rebuild handles that.
  if (graph.node(u).id > graph.node(v).id) std::swap(u, v);
  const Index root_u = rootOf(u), root_v = rootOf(v);
  if (root_u != root_v && root_v != v) {
    rebuildKeepingNeighbours(graph, reparented);
    return true;
  }
  const Index old_parent = parent_[v];
  if (old_parent != kNoNode && graph.node(old_parent).id <= graph.node(u).id) return true;
  if (old_parent != kNoNode) detach(v);
  parent_[v] = u;
  children_[u].push_back(v);
  setLevelsBelow(v);
  if (reparented) reparented->push_back(v);
  return true;
}

std::size_t ParameterTree::rootOf(std::size_t node) const {
  while (parent_[node] != kNoNode) node = parent_[node];
  return node;
}

void ParameterTree::rebuildKeepingNeighbours(const PoseGraph& graph, std::vector<std::size_t>* reparented) {
  ++rebuilds_;
  const std::vector<Index> old_parent = parent_;
  build(graph);
  if (reparented) {
    for (Index v = 0; v < parent_.size(); ++v) {
      if (parent_[v] != old_parent[v]) reparented->push_back(v);
    }
  }
}

void ParameterTree::detach(std::size_t node) {
  auto& siblings = children_[parent_[node]];
  siblings.erase(std::find(siblings.begin(), siblings.end(), node));
  parent_[node] = kNoNode;
}

std::size_t ParameterTree::topNode(std::size_t a, std::size_t b) const {
  while (level_[a] > level_[b]) a = parent_[a];
  while (level_[b] > level_[a]) b = parent_[b];
  while (a != b) {
    a = parent_[a];
    b = parent_[b];
    if (a == kNoNode || b == kNoNode) return kNoNode;
  }
  return a;
}

std::size_t ParameterTree::path(std::size_t a, std::size_t b, std::vector<std::size_t>& up,
                                std::vector<std::size_t>& down) const {
  up.clear();
  down.clear();
  // The usual constraint (odometry) joins a node and its parent: a one-node path.
  if (parent_[a] == b) {
    up.push_back(a);
    return b;
  }
  if (parent_[b] == a) {
    down.push_back(b);
    return a;
  }
  while (level_[a] > level_[b]) {
    up.push_back(a);
    a = parent_[a];
  }
  while (level_[b] > level_[a]) {
    down.push_back(b);
    b = parent_[b];
  }
  while (a != b) {
    up.push_back(a);
    down.push_back(b);
    a = parent_[a];
    b = parent_[b];
    if (a == kNoNode || b == kNoNode) return kNoNode;
  }
  return a;
}

std::vector<std::size_t> ParameterTree::topologicalOrder() const {
  std::vector<Index> order;
  order.reserve(parent_.size());
  for (Index v = 0; v < parent_.size(); ++v) {
    if (parent_[v] == kNoNode) order.push_back(v);
  }
  for (Index i = 0; i < order.size(); ++i) {
    for (Index c : children_[order[i]]) order.push_back(c);
  }
  return order;
}

}  // namespace toro
