#include "toro_ros/core/planar.h"

#include "graph_io_detail.h"

namespace toro {

bool isExactlyPlanar(const Pose3& pose) {
  return pose.translation().z() == 0.0 && pose.rotation().x() == 0.0 && pose.rotation().y() == 0.0;
}

Pose3 projectToPlane(const Pose3& pose) {
  if (isExactlyPlanar(pose)) return pose;
  return liftToPose3(planarPart(pose));
}

Matrix6 projectInformationToPlane(const Matrix6& information) {
  // Both conversions are exact power-of-two scalings (graph_io.h), so a lifted 2D matrix comes
  // back bit for bit.
  return detail::liftPlanarInformation(detail::planarInformation(information));
}

Constraint projectToPlane(const Constraint& constraint) {
  Constraint out = constraint;
  out.measurement = projectToPlane(constraint.measurement);
  out.information = projectInformationToPlane(constraint.information);
  return out;
}

PoseGraph projectToPlane(const PoseGraph& graph) {
  PoseGraph out;
  out.setDimension(GraphDimension::k2D);
  for (const Node& n : graph.nodes()) out.addNode(n.id, projectToPlane(n.pose));
  for (const Constraint& c : graph.constraints()) out.addConstraint(projectToPlane(c));
  for (NodeId id : graph.fixedNodes()) out.addFixed(id);
  return out;
}

}  // namespace toro
