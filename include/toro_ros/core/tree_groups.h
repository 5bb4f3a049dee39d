// The two groups TreeOptimizer's update runs in: SE(3) (TORO 3D, IROS 2007) and SE(2) (TORO 2D,
// Grisetti, Stachniss, Grzonka, Burgard, RSS 2007).  The update (tree_optimizer_update.cpp) is one
// template over these traits: what differs is the pose type, the rotation error and its
// exponential (3D: rotation vector and quaternion; 2D: the angle and a unit complex number, so the
// shares of a rotation error simply add), and how the information becomes scalar stiffness.
// Internal to the core (namespace detail); TreeOptimizer's interface speaks Pose3 only.
#pragma once

#include <vector>

#include "toro_ros/core/block_stiffness.h"
#include "toro_ros/core/pose2.h"
#include "toro_ros/core/pose3.h"

namespace toro {
namespace detail {

// Scalar stiffness of a constraint (block_stiffness.h) and, when some axis is unmeasured, the
// projectors onto its measured axes in the constraint's frame (the "to" end).
template <class Translation, class Rotation>
struct GroupStiffness {
  double translation = 0.0;
  double rotation = 0.0;
  bool all_axes_measured = true;
  Translation translation_projection;
  Rotation rotation_projection;
  bool translation_partial = false;
  bool rotation_partial = false;
};

struct SpatialGroup {
  static constexpr bool kPlanar = false;
  using Pose = Pose3;
  using Rotation = Quaternion;
  using Translation = Vector3;
  using Tangent = Vector3;  // a rotation error: the rotation vector (axis * angle)
  using Stiffness = GroupStiffness<Matrix3, Matrix3>;

  static const Pose& fromPose3(const Pose3& pose) { return pose; }
  static const Pose3& toPose3(const Pose& pose) { return pose; }
  // The rotation vector of a rotation (angle in [0, pi]) and back.
  static Tangent log(const Rotation& q) { return rotationVectorFromQuaternion(q); }
  static Rotation exp(const Tangent& v) { return quaternionFromRotationVector(v); }
  static Stiffness stiffness(const Matrix6& information) {
    const BlockStiffness t = blockStiffness(information.topLeftCorner<3, 3>());
    const BlockStiffness r = blockStiffness(information.bottomRightCorner<3, 3>());
    return Stiffness{t.weight,
                     r.weight,
                     t.all_axes_measured && r.all_axes_measured,
                     t.measured_projection,
                     r.measured_projection,
                     !t.all_axes_measured,
                     !r.all_axes_measured};
  }
};

struct PlanarGroup {
  static constexpr bool kPlanar = true;
  using Pose = Pose2;
  using Rotation = Rotation2;
  using Translation = Vector2;
  using Tangent = double;  // a rotation error: the angle
  // The rotation block is the one yaw entry: measured or not, never partly.
  using Stiffness = GroupStiffness<Matrix2, double>;

  static Pose fromPose3(const Pose3& pose) { return planarPart(pose); }
  static Pose3 toPose3(const Pose& pose) { return liftToPose3(pose); }
  static Tangent log(const Rotation& r) { return r.angle(); }
  static Rotation exp(Tangent angle) { return rotation2FromAngle(angle); }
  // From the (x, y, yaw) entries of the internal information (yaw in the quaternion-vector units
  // of pose_graph.h, as SpatialGroup uses them, so a lifted 2D graph gets the same step fractions
  // in both groups).
  static Stiffness stiffness(const Matrix6& information) {
    const PlanarBlockStiffness t = planarBlockStiffness(information.topLeftCorner<2, 2>());
    const double yaw = information(5, 5) > 0.0 ? information(5, 5) : 0.0;
    return Stiffness{t.weight, yaw, t.all_axes_measured, t.measured_projection, 1.0, !t.all_axes_measured,
                     false};
  }
};

// What TreeOptimizer keeps per group: the parameters, the measurements in the group, the
// projectors of constraints with unmeasured axes, and scratch for one update.
template <class G>
struct TreeGroupState {
  using Pose = typename G::Pose;
  std::vector<Pose> parameters;    // parent_T_node per dense node index (root: world_T_root)
  std::vector<Pose> measurements;  // from_T_to per constraint
  std::vector<typename G::Stiffness> measured_axes;  // constraints with unmeasured axes only
  std::vector<Pose> world;                 // world_T_node per dense node index (planar only: the graph
                                           // holds the Pose3 of each, so SE(3) reads it from there)
  std::vector<Pose> up_poses, down_poses;  // top_T_node of the path nodes of one update

  void clear() {
    parameters.clear();
    measurements.clear();
    measured_axes.clear();
    world.clear();
  }
};

}  // namespace detail
}  // namespace toro
