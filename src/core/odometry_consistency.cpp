#include "toro_ros/core/odometry_consistency.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <deque>

namespace toro {

namespace {

// Covariance (angle units) of a constraint's measurement; zero if its information is singular.
Matrix6 covarianceOf(const Matrix6& information) {
  const Eigen::LDLT<Matrix6> ldlt(quaternionToAngleUnits(information));
  if (ldlt.info() != Eigen::Success) return Matrix6::Zero();
  return ldlt.solve(Matrix6::Identity());
}

// The odometry forest: each node reached from its component's smallest id over odometry, with
// the world-frame covariance of its pose accumulated along the way (first order: the step
// i_T_j = Z exp(eps) perturbs world_T_j by Ad(world_T_j) eps, and the steps are independent).
struct OdometryForest {
  std::vector<std::size_t> parent;  // kNone at a root or for nodes odometry does not reach
  std::vector<std::size_t> depth;
  std::vector<std::size_t> root;
  std::vector<Matrix6> world_covariance;
};

constexpr std::size_t kNone = static_cast<std::size_t>(-1);

OdometryForest buildForest(const PoseGraph& graph) {
  const std::size_t n = graph.numNodes();
  OdometryForest f{std::vector<std::size_t>(n, kNone), std::vector<std::size_t>(n, 0),
                   std::vector<std::size_t>(n, kNone), std::vector<Matrix6>(n, Matrix6::Zero())};
  std::vector<std::vector<std::size_t>> incident(n);
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    const Constraint& k = graph.constraints()[c];
    if (isLoopClosure(k)) continue;
    incident[graph.indexOf(k.from)].push_back(c);
    incident[graph.indexOf(k.to)].push_back(c);
  }
  std::vector<std::size_t> by_id(n);
  for (std::size_t v = 0; v < n; ++v) by_id[v] = v;
  std::sort(by_id.begin(), by_id.end(),
            [&](std::size_t a, std::size_t b) { return graph.node(a).id < graph.node(b).id; });
  std::deque<std::size_t> queue;
  for (std::size_t r : by_id) {
    if (f.root[r] != kNone) continue;
    f.root[r] = r;
    queue.push_back(r);
    while (!queue.empty()) {
      const std::size_t v = queue.front();
      queue.pop_front();
      for (std::size_t c : incident[v]) {
        const Constraint& k = graph.constraints()[c];
        const std::size_t from = graph.indexOf(k.from), to = graph.indexOf(k.to);
        const std::size_t u = from == v ? to : from;
        if (f.root[u] != kNone) continue;
        f.root[u] = r;
        f.parent[u] = v;
        f.depth[u] = f.depth[v] + 1;
        // The step's covariance is in the frame of its `to` end; carried to the world through it.
        const Matrix6 a = adjoint(graph.node(to).pose);
        f.world_covariance[u] = f.world_covariance[v] + a * covarianceOf(k.information) * a.transpose();
        queue.push_back(u);
      }
    }
  }
  return f;
}

std::size_t commonAncestor(const OdometryForest& f, std::size_t a, std::size_t b) {
  while (f.depth[a] > f.depth[b]) a = f.parent[a];
  while (f.depth[b] > f.depth[a]) b = f.parent[b];
  while (a != b) {
    a = f.parent[a];
    b = f.parent[b];
  }
  return a;
}

}  // namespace

double poseErrorChi2(const Pose3& error, const Matrix6& covariance, bool planar) {
  Vector6 e;
  e << error.translation(), error.angleAxis();
  if (!planar) return e.dot(covariance.ldlt().solve(e));
  const int axes[3] = {0, 1, 5};
  Eigen::Vector3d ep;
  Matrix3 sp;
  for (int r = 0; r < 3; ++r) {
    ep(r) = e(axes[r]);
    for (int s = 0; s < 3; ++s) sp(r, s) = covariance(axes[r], axes[s]);
  }
  return ep.dot(sp.ldlt().solve(ep));
}

std::vector<double> odometryInnovationChi2(const PoseGraph& graph) {
  std::vector<double> out(graph.numConstraints(), -1.0);
  const OdometryForest forest = buildForest(graph);
  const bool planar = graph.dimension() == GraphDimension::k2D;
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    const Constraint& k = graph.constraints()[c];
    if (!isLoopClosure(k)) continue;
    const std::size_t i = graph.indexOf(k.from), j = graph.indexOf(k.to);
    if (forest.root[i] != forest.root[j]) continue;
    const std::size_t top = commonAncestor(forest, i, j);
    const Matrix6 world =
        forest.world_covariance[i] + forest.world_covariance[j] - 2.0 * forest.world_covariance[top];
    const Pose3& xi = graph.node(i).pose;
    const Pose3& xj = graph.node(j).pose;
    const Matrix6 a = adjoint(xj.inverse());
    const Matrix6 total = a * world * a.transpose() + covarianceOf(k.information);
    const Pose3 d = k.measurement.inverse() * (xi.inverse() * xj);
    out[c] = poseErrorChi2(d, total, planar);
  }
  return out;
}

}  // namespace toro
