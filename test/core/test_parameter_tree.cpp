#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "toro_ros/core/parameter_tree.h"

using namespace toro;

namespace {

Constraint edge(NodeId a, NodeId b) {
  Constraint c;
  c.from = a;
  c.to = b;
  return c;
}

PoseGraph graphOf(const std::vector<NodeId>& ids, const std::vector<std::pair<NodeId, NodeId>>& edges) {
  PoseGraph g;
  for (NodeId id : ids) g.addNode(id, Pose3());
  for (const auto& e : edges) g.addConstraint(edge(e.first, e.second));
  return g;
}

NodeId parentId(const PoseGraph& g, const ParameterTree& t, NodeId id) {
  const std::size_t p = t.parent(g.indexOf(id));
  return p == ParameterTree::kNone ? -1 : g.node(p).id;
}

std::vector<NodeId> ids(const PoseGraph& g, const std::vector<std::size_t>& indices) {
  std::vector<NodeId> out;
  for (std::size_t i : indices) out.push_back(g.node(i).id);
  return out;
}

}  // namespace

TEST(ParameterTree, SmallestNeighbourIsParentAndLevelsFollow) {
  // 0-1-2-3-4 chain with loop closures 4-1 and 3-0.
  const PoseGraph g = graphOf({0, 1, 2, 3, 4}, {{0, 1}, {1, 2}, {2, 3}, {3, 4}, {4, 1}, {3, 0}});
  ParameterTree t;
  t.build(g);
  EXPECT_TRUE(t.followsSmallestNeighbourRule());
  EXPECT_EQ(parentId(g, t, 0), -1);
  EXPECT_EQ(parentId(g, t, 1), 0);
  EXPECT_EQ(parentId(g, t, 2), 1);
  EXPECT_EQ(parentId(g, t, 3), 0);
  EXPECT_EQ(parentId(g, t, 4), 1);
  EXPECT_EQ(t.level(g.indexOf(0)), 0);
  EXPECT_EQ(t.level(g.indexOf(1)), 1);
  EXPECT_EQ(t.level(g.indexOf(2)), 2);
  EXPECT_EQ(t.level(g.indexOf(3)), 1);
  EXPECT_EQ(t.level(g.indexOf(4)), 2);
}

TEST(ParameterTree, TopNodeAndPath) {
  const PoseGraph g = graphOf({0, 1, 2, 3, 4}, {{0, 1}, {1, 2}, {2, 3}, {3, 4}, {4, 1}, {3, 0}});
  ParameterTree t;
  t.build(g);
  std::vector<std::size_t> up, down;
  // 2 -> 3: 2's branch goes 2,1 up to 0; 3 hangs directly below 0.
  std::size_t top = t.path(g.indexOf(2), g.indexOf(3), up, down);
  EXPECT_EQ(g.node(top).id, 0);
  EXPECT_EQ(ids(g, up), (std::vector<NodeId>{2, 1}));
  EXPECT_EQ(ids(g, down), (std::vector<NodeId>{3}));
  EXPECT_EQ(t.topNode(g.indexOf(2), g.indexOf(3)), top);
  // 4 -> 2: siblings below 1.
  top = t.path(g.indexOf(4), g.indexOf(2), up, down);
  EXPECT_EQ(g.node(top).id, 1);
  EXPECT_EQ(ids(g, up), (std::vector<NodeId>{4}));
  EXPECT_EQ(ids(g, down), (std::vector<NodeId>{2}));
  // Constraint to an ancestor: the ancestor is the top, one branch is empty.
  top = t.path(g.indexOf(1), g.indexOf(4), up, down);
  EXPECT_EQ(g.node(top).id, 1);
  EXPECT_TRUE(up.empty());
  EXPECT_EQ(ids(g, down), (std::vector<NodeId>{4}));
}

TEST(ParameterTree, TopologicalOrderPutsParentsFirst) {
  const PoseGraph g = graphOf({5, 3, 9, 1, 7}, {{1, 3}, {3, 5}, {5, 7}, {7, 9}, {9, 3}});
  ParameterTree t;
  t.build(g);
  const auto order = t.topologicalOrder();
  ASSERT_EQ(order.size(), g.numNodes());
  std::vector<int> position(g.numNodes());
  for (std::size_t i = 0; i < order.size(); ++i) position[order[i]] = static_cast<int>(i);
  for (std::size_t v = 0; v < g.numNodes(); ++v) {
    if (!t.isRoot(v)) {
      EXPECT_LT(position[t.parent(v)], position[v]);
    }
  }
  EXPECT_EQ(parentId(g, t, 9), 3);  // smallest neighbour of 9 is 3, not 7
}

TEST(ParameterTree, GraphsOutOfTimeOrderStillGetASpanningTree) {
  // Node 5 has no smaller neighbour, though it is not the smallest id of its component.
  const PoseGraph g = graphOf({0, 7, 5, 8}, {{0, 7}, {7, 5}, {5, 8}});
  ParameterTree t;
  t.build(g);
  EXPECT_FALSE(t.followsSmallestNeighbourRule());
  EXPECT_EQ(parentId(g, t, 0), -1);
  EXPECT_EQ(parentId(g, t, 7), 0);
  EXPECT_EQ(parentId(g, t, 5), 7);
  EXPECT_EQ(parentId(g, t, 8), 5);
  EXPECT_EQ(t.level(g.indexOf(8)), 3);
}

TEST(ParameterTree, DisconnectedComponentsHaveOneRootEach) {
  const PoseGraph g = graphOf({0, 1, 2, 10, 11}, {{0, 1}, {1, 2}, {10, 11}});
  ParameterTree t;
  t.build(g);
  EXPECT_EQ(parentId(g, t, 10), -1);
  EXPECT_EQ(parentId(g, t, 11), 10);
  EXPECT_EQ(t.topNode(g.indexOf(2), g.indexOf(11)), ParameterTree::kNone);
}

namespace {

// Grows a graph one piece at a time (a node, or a constraint between existing nodes) and checks
// after every step that the incremental tree equals a batch build of the same graph.
void checkIncrementalEqualsBatch(std::vector<NodeId> node_ids, std::uint32_t seed, bool time_ordered) {
  std::mt19937 rng(seed);
  if (!time_ordered) std::shuffle(node_ids.begin(), node_ids.end(), rng);
  PoseGraph g;
  ParameterTree incremental;
  incremental.build(g);
  std::size_t next = 0;
  for (int step = 0; step < 400; ++step) {
    const bool add_node = next < node_ids.size() && (g.numNodes() < 2 || rng() % 3 == 0);
    if (add_node) {
      g.addNode(node_ids[next++], Pose3());
      incremental.addNode(g, g.numNodes() - 1);
      if (g.numNodes() >= 2 && rng() % 4 != 0) {
        // Usually link the new node to an earlier one, as odometry does.
        const std::size_t other = rng() % (g.numNodes() - 1);
        const std::size_t c = g.addConstraint(edge(g.node(other).id, g.node(g.numNodes() - 1).id));
        incremental.addConstraint(g, c);
      }
    } else if (g.numNodes() >= 2) {
      const std::size_t a = rng() % g.numNodes(), b = rng() % g.numNodes();
      if (a == b) continue;
      const std::size_t c = g.addConstraint(edge(g.node(a).id, g.node(b).id));
      std::vector<std::size_t> reparented;
      const auto before = incremental.parents();
      incremental.addConstraint(g, c, &reparented);
      for (std::size_t v = 0; v < before.size(); ++v) {
        const bool changed = before[v] != incremental.parent(v);
        EXPECT_EQ(changed, std::count(reparented.begin(), reparented.end(), v) == 1) << "node " << v;
      }
    }
    ParameterTree batch;
    batch.build(g);
    ASSERT_EQ(batch.parents(), incremental.parents()) << "step " << step;
    ASSERT_EQ(batch.levels(), incremental.levels()) << "step " << step;
  }
}

}  // namespace

TEST(ParameterTree, IncrementalEqualsBatchForTimeOrderedIds) {
  std::vector<NodeId> node_ids;
  for (NodeId i = 0; i < 120; ++i) node_ids.push_back(i * 3 + 7);
  for (std::uint32_t seed = 1; seed <= 5; ++seed) checkIncrementalEqualsBatch(node_ids, seed, true);
}

TEST(ParameterTree, IncrementalEqualsBatchForShuffledIds) {
  std::vector<NodeId> node_ids;
  for (NodeId i = 0; i < 120; ++i) node_ids.push_back(i);
  for (std::uint32_t seed = 1; seed <= 5; ++seed) checkIncrementalEqualsBatch(node_ids, seed, false);
}

TEST(ParameterTree, TimeOrderedGrowthNeverRebuilds) {
  PoseGraph g;
  ParameterTree t;
  t.build(g);
  for (NodeId i = 0; i < 200; ++i) {
    g.addNode(i, Pose3());
    t.addNode(g, g.numNodes() - 1);
    if (i > 0) t.addConstraint(g, g.addConstraint(edge(i - 1, i)));
    if (i > 10 && i % 7 == 0) t.addConstraint(g, g.addConstraint(edge(i - 10, i)));
  }
  EXPECT_EQ(t.rebuilds(), 0u);
  EXPECT_TRUE(t.followsSmallestNeighbourRule());
}
