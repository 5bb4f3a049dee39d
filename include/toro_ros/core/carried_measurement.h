// A relative-pose measurement carried along odometry to other nodes: a place recogniser measures
// between two scans' stamps, the graph has keyframes near them, and the odometry between each
// stamp and its keyframe carries the measurement there.  That odometry is uncertain too: left out,
// a loop closure declared to the millimetre and carried over a few decimetres of wheel odometry
// keeps its millimetre, and the map, which cannot bend to it, judges it an outlier.
#pragma once

#include <limits>

#include "toro_ros/core/pose3.h"

namespace toro {

// The covariance of an information matrix, on the axes it measures: directions whose information is
// below kUnmeasuredInformationRatio (pose_graph.h) of the largest, or whose variance would reach
// `unmeasured_variance`, count as unmeasured and get no variance (a pseudo-inverse).  An odometry
// step that says nothing of z, roll and pitch (a planar robot's "1e6 to ignore an axis") adds
// nothing there: that variance is a flag, not a size, and carried through a lever arm a roll of
// 1000 rad^2 would drown the measured x and y.  Angle units in, angle units out.
Matrix6 measuredCovariance(const Matrix6& information,
                           double unmeasured_variance = std::numeric_limits<double>::infinity());

// The information of Z' = A Z B^-1, the measurement Z (from stamp a to stamp b, information
// `z_information`) carried to the nodes A and B are measured from (A = node_a_T_stamp_a,
// B = node_b_T_stamp_b), each offset with the covariance of its right perturbation (A exp(e)).
// First order: e' = Ad(B Z^-1) e_A + Ad(B) (e_Z - e_B) (A itself does not enter), so the covariance is
// Ad(B) Sigma_Z Ad(B)^T + Ad(B Z^-1) Sigma_A Ad(B Z^-1)^T + Ad(B) Sigma_B Ad(B)^T, returned as
// Lambda' (I + S Lambda')^-1 with Lambda' the carried Z information and S the offsets' part, which
// holds for a singular Z information (axes it does not measure stay unmeasured).  Everything in
// angle units, twists ordered translation, rotation.
Matrix6 carriedInformation(const Matrix6& a_covariance, const Pose3& z, const Matrix6& z_information,
                           const Pose3& b, const Matrix6& b_covariance);

}  // namespace toro
