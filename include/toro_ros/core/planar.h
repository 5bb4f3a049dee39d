// Planar mode: the projection of 3D poses, constraints and graphs onto the plane (x, y, yaw),
// for robots that drive on a floor.  The planar optimisers (TreeOptimizer with
// Parameterization::kPlanar, the finish's SE(2) model) work on the result, which is a lifted 2D
// graph exactly like one read from a 2D file (graph_io.h): GraphDimension::k2D, poses with z = 0
// and roll = pitch = 0, and information whose x, y, yaw block carries the planar information.
//
// What is dropped: z, roll and pitch of every pose and measurement (the heading kept is the yaw
// of R = Rz(yaw) Ry(pitch) Rx(roll), the direction of the body x axis in the plane), and every
// information entry that involves z, roll or pitch.  The planar information is the (x, y, yaw)
// block of the 6x6 information as it stands: for the usual ROS planar convention (z, roll and
// pitch uncorrelated with the planar axes, with any variance) that equals the inverse of the
// (x, y, yaw) block of the covariance.  The out-of-plane entries of the result are filled as the
// 2D readers fill them (they only hold a 3D optimiser in the plane) and mean nothing.
#pragma once

#include "toro_ros/core/pose2.h"
#include "toro_ros/core/pose_graph.h"

namespace toro {

// True if the pose lies in the plane exactly: z = 0 and a rotation about the z axis only
// (quaternion x = y = 0), so roll and pitch are exactly 0.
bool isExactlyPlanar(const Pose3& pose);

// (x, y, 0) and the yaw alone; a pose that is exactly planar is returned unchanged (bit for bit).
Pose3 projectToPlane(const Pose3& pose);

// The (x, y, yaw) block of an information matrix (internal units, pose_graph.h) with the
// out-of-plane entries of a lifted 2D graph.  Idempotent, and the identity on the information of
// a 2D file as graph_io reads it.
Matrix6 projectInformationToPlane(const Matrix6& information);

Constraint projectToPlane(const Constraint& constraint);

// Every node and constraint projected (fixed nodes kept), dimension k2D.  Projecting a lifted 2D
// graph changes nothing.
PoseGraph projectToPlane(const PoseGraph& graph);

}  // namespace toro
