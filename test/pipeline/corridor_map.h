// A small map shared by the tests of the support rules and the evidence they read
// (test_loop_closure_evidence, test_loop_closure_support): a corridor driven there and back.
#pragma once

#include <cmath>
#include <vector>

#include "toro_ros/core/tree_optimizer.h"

namespace toro_ros {
namespace testing {

// Information of a 6-dof measurement with these standard deviations (rotation in g2o's quaternion
// units).
inline toro::Matrix6 informationOf(double stddev_m, double stddev_rad) {
  toro::Matrix6 info = toro::Matrix6::Zero();
  for (int k = 0; k < 3; ++k) {
    info(k, k) = 1.0 / (stddev_m * stddev_m);
    info(k + 3, k + 3) = 4.0 / (stddev_rad * stddev_rad);
  }
  return info;
}

// 40 poses 1 m apart with a half turn at pose 20, odometry exact (0.05 m, 0.01 rad declared), so
// poses 20 + k and 20 - k are one place; the map and its loop-closure flags as MapOptimizer keeps
// them.
struct Corridor {
  toro::TreeOptimizer map;
  std::vector<bool> is_loop_closure;
  std::vector<toro::Pose3> truth;

  explicit Corridor(const toro::TreeOptimizerOptions& options = {}) : map(options) {
    toro::Pose3 pose;
    for (int i = 0; i < 40; ++i) {
      truth.push_back(pose);
      map.addNode(i, pose);
      if (i > 0)
        add({i - 1, i, toro::relativePose(truth[i - 1], truth[i]), informationOf(0.05, 0.01),
             toro::ConstraintKind::kOdometry});
      pose = pose * (i == 19 ? toro::Pose3::fromRollPitchYaw(0, 0, 0, 0, 0, M_PI)
                             : toro::Pose3::fromRollPitchYaw(1.0, 0, 0, 0, 0, 0));
    }
  }
  std::size_t add(const toro::Constraint& c, bool tree_edge = true) {
    is_loop_closure.push_back(c.kind == toro::ConstraintKind::kLoopClosure);
    return map.addConstraint(c, tree_edge);
  }
  // A loop closure between two poses (0.1 m, 0.05 rad declared), its measurement off the truth by
  // `error`; `tree_edge` as TreeOptimizer::addConstraint's (MapOptimizer admits one to the tree
  // once it counts).
  std::size_t loopClosure(int from, int to, const toro::Pose3& error = toro::Pose3(), bool tree_edge = true) {
    return add({from, to, toro::relativePose(truth[from], truth[to]) * error, informationOf(0.1, 0.05),
                toro::ConstraintKind::kLoopClosure},
               tree_edge);
  }
};

}  // namespace testing
}  // namespace toro_ros
