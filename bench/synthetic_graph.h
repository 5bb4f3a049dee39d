// A large synthetic 3D pose graph for the benchmark: a seeded random walk over a bounded 3D grid
// (corridors on several floors), odometry between consecutive poses and loop closures to earlier
// poses in the same grid cell, with Gaussian noise on every measurement.  Header-only because
// CMakeLists.txt builds each bench/*.cpp into its own executable.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <unordered_map>
#include <vector>

#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/random_draws.h"

namespace toro_bench {

struct SyntheticOptions {
  std::size_t nodes = 100000;
  std::size_t constraints = 200000;  // odometry (nodes - 1) + loop closures
  int cells_x = 30, cells_y = 30, cells_z = 4;
  double cell_size_m = 1.0;
  double position_jitter_m = 0.1;     // ground-truth offset from the cell centre
  double tilt_sigma_rad = 0.05;       // ground-truth roll/pitch wobble
  double translation_sigma_m = 0.05;  // measurement noise
  double rotation_sigma_rad = 0.01;
  std::uint32_t seed = 42;
};

namespace detail {

struct Cell {
  int x, y, z;
  long long key(const SyntheticOptions& o) const {
    return (static_cast<long long>(z) * o.cells_y + y) * o.cells_x + x;
  }
};

// Moves one cell: mostly straight on, sometimes a 90-degree turn, rarely a floor change; turns
// around at the boundary.  `heading` is 0..3 (multiples of 90 degrees about z).
inline Cell step(const Cell& c, int& heading, std::mt19937& rng, const SyntheticOptions& o) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double r = u(rng);
  if (r < 0.05 && o.cells_z > 1) {
    Cell up = c;
    up.z += (c.z == 0 || (c.z < o.cells_z - 1 && u(rng) < 0.5)) ? 1 : -1;
    return up;
  }
  if (r < 0.25) heading = (heading + (u(rng) < 0.5 ? 1 : 3)) % 4;
  static const int kDx[4] = {1, 0, -1, 0}, kDy[4] = {0, 1, 0, -1};
  for (int attempt = 0; attempt < 4; ++attempt) {
    const Cell next{c.x + kDx[heading], c.y + kDy[heading], c.z};
    if (next.x >= 0 && next.x < o.cells_x && next.y >= 0 && next.y < o.cells_y) return next;
    heading = (heading + (attempt == 0 ? 2 : 1)) % 4;
  }
  return c;  // unreachable for grids of at least 2x2 cells
}

inline toro::Pose3 noisy(const toro::Pose3& exact, std::mt19937& rng, const SyntheticOptions& o) {
  std::normal_distribution<double> rot(0.0, o.rotation_sigma_rad), trans(0.0, o.translation_sigma_m);
  return exact * toro::drawPose3(rot, trans, rng);
}

}  // namespace detail

// Ground-truth poses of the walk (world_T_node, node i has id i).
inline std::vector<toro::Pose3> syntheticTrajectory(const SyntheticOptions& o,
                                                    std::vector<long long>* cell_keys, std::mt19937& rng) {
  std::normal_distribution<double> jitter(0.0, o.position_jitter_m), tilt(0.0, o.tilt_sigma_rad);
  std::vector<toro::Pose3> truth;
  truth.reserve(o.nodes);
  detail::Cell cell{o.cells_x / 2, o.cells_y / 2, 0};
  int heading = 0;
  for (std::size_t i = 0; i < o.nodes; ++i) {
    if (i > 0) cell = detail::step(cell, heading, rng, o);
    const double yaw = heading * M_PI / 2.0;
    // Drawn in a fixed order (toro::drawLastFirst): the tilts, then z, y, x.
    const auto tilts = toro::drawLastFirst<2>(tilt, rng);
    const auto offset = toro::drawVector3(jitter, rng);
    truth.push_back(toro::Pose3::fromRollPitchYaw(
        cell.x * o.cell_size_m + offset.x(), cell.y * o.cell_size_m + offset.y(),
        cell.z * o.cell_size_m + offset.z(), tilts[0], tilts[1], yaw));
    cell_keys->push_back(cell.key(o));
  }
  return truth;
}

// The graph: poses are the composed noisy odometry (a realistic kFromGraph guess); constraints are
// odometry i-1 -> i, then one loop closure from each pose to a random earlier visit of its cell,
// then further random closures between earlier visits until `constraints` is reached.
inline toro::PoseGraph makeSyntheticGraph(const SyntheticOptions& o) {
  std::mt19937 rng(o.seed);
  std::vector<long long> keys;
  const std::vector<toro::Pose3> truth = syntheticTrajectory(o, &keys, rng);

  toro::Matrix6 information = toro::Matrix6::Zero();
  // g2o units: translation per m^2; rotation per (quaternion vector part)^2 = 4 per rad^2.
  information.topLeftCorner<3, 3>().diagonal().setConstant(1.0 /
                                                           (o.translation_sigma_m * o.translation_sigma_m));
  information.bottomRightCorner<3, 3>().diagonal().setConstant(4.0 /
                                                               (o.rotation_sigma_rad * o.rotation_sigma_rad));

  toro::PoseGraph graph;
  toro::Pose3 odometry_pose = truth.empty() ? toro::Pose3() : truth[0];
  std::vector<toro::Constraint> edges;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    if (i > 0) {
      const toro::Pose3 z = detail::noisy(toro::relativePose(truth[i - 1], truth[i]), rng, o);
      odometry_pose = odometry_pose * z;
      edges.push_back({static_cast<toro::NodeId>(i - 1), static_cast<toro::NodeId>(i), z, information});
    }
    graph.addNode(static_cast<toro::NodeId>(i), odometry_pose);
  }
  for (const auto& e : edges) graph.addConstraint(e);

  auto addClosure = [&](std::size_t earlier, std::size_t later) {
    const toro::Pose3 z = detail::noisy(toro::relativePose(truth[earlier], truth[later]), rng, o);
    graph.addConstraint(
        {static_cast<toro::NodeId>(earlier), static_cast<toro::NodeId>(later), z, information});
  };
  std::unordered_map<long long, std::vector<std::size_t>> visits;
  for (std::size_t i = 0; i < truth.size() && graph.numConstraints() < o.constraints; ++i) {
    auto& earlier = visits[keys[i]];
    if (!earlier.empty())
      addClosure(earlier[std::uniform_int_distribution<std::size_t>(0, earlier.size() - 1)(rng)], i);
    earlier.push_back(i);
  }
  // Fill up with closures between two visits of the same cell (parallel constraints may occur).
  std::uniform_int_distribution<std::size_t> any(1, truth.size() > 1 ? truth.size() - 1 : 1);
  for (std::size_t attempts = 0; graph.numConstraints() < o.constraints && attempts < 100 * o.constraints;
       ++attempts) {
    const std::size_t later = any(rng);
    const auto& v = visits[keys[later]];
    const std::size_t earlier = v[std::uniform_int_distribution<std::size_t>(0, v.size() - 1)(rng)];
    if (earlier < later && earlier + 1 != later) addClosure(earlier, later);
  }
  return graph;
}

}  // namespace toro_bench
