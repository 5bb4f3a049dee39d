// Seeded synthetic pose graphs with known ground truth, for tests and benchmarks.
#pragma once

#include <cstdint>
#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

struct SyntheticGraph {
  PoseGraph graph;                 // noisy measurements; node poses = ground truth (use the chain guess)
  std::vector<Pose3> ground_truth;  // by dense node index
};

struct NoiseOptions {
  double translation_sigma_m = 0.05;   // per axis
  double rotation_sigma_rad = 0.01;    // per axis of the rotation vector
  std::uint32_t seed = 42;
};

// A robot driving rings of constant latitude on a sphere (like the TORO paper's sphere): odometry
// between consecutive poses, loop closures to the nearest pose of the previous ring.
SyntheticGraph makeSphere(int rings, int poses_per_ring, double radius_m, const NoiseOptions& noise);

// A robot driving a 3D grid (a "cube") in lanes, visiting every layer: odometry plus loop closures
// to every earlier pose within `closure_distance_m`.
SyntheticGraph makeCube(int side, double spacing_m, double closure_distance_m, const NoiseOptions& noise);

// Any ground-truth trajectory: odometry between consecutive poses plus the given loop closures
// (pairs of dense indices, earlier first), with noise; information = inverse noise covariance
// (g2o units: rotation block in quaternion-vector units).
SyntheticGraph makeFromTrajectory(const std::vector<Pose3>& ground_truth,
                                  const std::vector<std::pair<std::size_t, std::size_t>>& loop_closures,
                                  const NoiseOptions& noise);

// Mean position error of `graph`'s poses against ground truth (same dense indices).
double meanPositionError(const PoseGraph& graph, const std::vector<Pose3>& ground_truth);
// Mean rotation error (rad).
double meanRotationError(const PoseGraph& graph, const std::vector<Pose3>& ground_truth);

}  // namespace toro
