#include "toro_ros/core/synthetic.h"
#include "toro_ros/core/random_draws.h"

#include <cmath>
#include <random>

namespace toro {

namespace {

Matrix6 informationFor(const NoiseOptions& noise) {
  Matrix6 info = Matrix6::Zero();
  const double t = 1.0 / (noise.translation_sigma_m * noise.translation_sigma_m);
  // sigma on the angle is sigma/2 on the quaternion vector part: information x4.
  const double r = 4.0 / (noise.rotation_sigma_rad * noise.rotation_sigma_rad);
  info.diagonal() << t, t, t, r, r, r;
  return info;
}

Pose3 perturb(const Pose3& pose, const NoiseOptions& noise, std::mt19937& rng) {
  std::normal_distribution<double> nt(0.0, noise.translation_sigma_m), nr(0.0, noise.rotation_sigma_rad);
  return pose * drawPose3(nr, nt, rng);
}

// Orientation whose x axis points along `forward`, with z as close to `up` as possible.
Quaternion facing(const Vector3& forward, const Vector3& up) {
  const Vector3 x = forward.normalized();
  Vector3 z = (up - up.dot(x) * x);
  if (z.norm() < 1e-9) z = x.unitOrthogonal();
  z.normalize();
  Matrix3 r;
  r.col(0) = x;
  r.col(1) = z.cross(x);
  r.col(2) = z;
  return Quaternion(r);
}

}  // namespace

SyntheticGraph makeFromTrajectory(const std::vector<Pose3>& ground_truth,
                                  const std::vector<std::pair<std::size_t, std::size_t>>& loop_closures,
                                  const NoiseOptions& noise) {
  SyntheticGraph out;
  out.ground_truth = ground_truth;
  std::mt19937 rng(noise.seed);
  const Matrix6 info = informationFor(noise);
  for (std::size_t i = 0; i < ground_truth.size(); ++i) {
    out.graph.addNode(static_cast<NodeId>(i), ground_truth[i]);
  }
  const auto add = [&](std::size_t a, std::size_t b) {
    Constraint c;
    c.from = static_cast<NodeId>(a);
    c.to = static_cast<NodeId>(b);
    c.measurement = perturb(relativePose(ground_truth[a], ground_truth[b]), noise, rng);
    c.information = info;
    out.graph.addConstraint(c);
  };
  for (std::size_t i = 1; i < ground_truth.size(); ++i) add(i - 1, i);
  for (const auto& lc : loop_closures) add(lc.first, lc.second);
  return out;
}

SyntheticGraph makeSphere(int rings, int poses_per_ring, double radius_m, const NoiseOptions& noise) {
  std::vector<Pose3> truth;
  std::vector<std::pair<std::size_t, std::size_t>> closures;
  for (int ring = 0; ring < rings; ++ring) {
    // Latitudes strictly inside (-pi/2, pi/2) so no ring degenerates to a point.
    const double lat = -M_PI / 2 + M_PI * (ring + 1) / (rings + 1);
    for (int k = 0; k < poses_per_ring; ++k) {
      const double lon = 2 * M_PI * k / poses_per_ring;
      const Vector3 p = radius_m * Vector3(std::cos(lat) * std::cos(lon), std::cos(lat) * std::sin(lon), std::sin(lat));
      const Vector3 forward(-std::sin(lon), std::cos(lon), 0.0);
      truth.emplace_back(facing(forward, p.normalized()), p);
      const std::size_t index = truth.size() - 1;
      if (ring > 0) closures.emplace_back(index - poses_per_ring, index);
    }
  }
  return makeFromTrajectory(truth, closures, noise);
}

SyntheticGraph makeCube(int side, double spacing_m, double closure_distance_m, const NoiseOptions& noise) {
  std::vector<Pose3> truth;
  // Boustrophedon over each layer; alternate direction per row and per layer so the path is continuous.
  for (int z = 0; z < side; ++z) {
    for (int yy = 0; yy < side; ++yy) {
      const int y = (z % 2 == 0) ? yy : side - 1 - yy;
      for (int xx = 0; xx < side; ++xx) {
        const int x = ((yy + z * side) % 2 == 0) ? xx : side - 1 - xx;
        truth.emplace_back(Quaternion::Identity(), spacing_m * Vector3(x, y, z));
      }
    }
  }
  // Heading along the direction of travel (up = z), so consecutive rotations differ.
  for (std::size_t i = 0; i < truth.size(); ++i) {
    const std::size_t a = i + 1 < truth.size() ? i : i - 1;
    const Vector3 dir = truth[a + 1].translation() - truth[a].translation();
    truth[i] = Pose3(facing(dir, Vector3::UnitZ()), truth[i].translation());
  }
  std::vector<std::pair<std::size_t, std::size_t>> closures;
  for (std::size_t j = 0; j < truth.size(); ++j) {
    for (std::size_t i = 0; i + 1 < j; ++i) {
      if ((truth[i].translation() - truth[j].translation()).norm() <= closure_distance_m) closures.emplace_back(i, j);
    }
  }
  return makeFromTrajectory(truth, closures, noise);
}

double meanPositionError(const PoseGraph& graph, const std::vector<Pose3>& ground_truth) {
  double sum = 0.0;
  for (std::size_t i = 0; i < ground_truth.size(); ++i) {
    sum += (graph.node(i).pose.translation() - ground_truth[i].translation()).norm();
  }
  return ground_truth.empty() ? 0.0 : sum / ground_truth.size();
}

double meanRotationError(const PoseGraph& graph, const std::vector<Pose3>& ground_truth) {
  double sum = 0.0;
  for (std::size_t i = 0; i < ground_truth.size(); ++i) {
    sum += relativePose(graph.node(i).pose, ground_truth[i]).angle();
  }
  return ground_truth.empty() ? 0.0 : sum / ground_truth.size();
}

}  // namespace toro
