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

namespace {

// Whether projecting `graph` would change nothing (a 2D file as read): then it is copied as it is,
// without validating every constraint again.
bool projectionIsIdentity(const PoseGraph& graph) {
  if (graph.dimension() != GraphDimension::k2D) return false;
  for (const Node& n : graph.nodes())
    if (!isExactlyPlanar(n.pose)) return false;
  for (const Constraint& c : graph.constraints())
    if (!isExactlyPlanar(c.measurement) || projectInformationToPlane(c.information) != c.information)
      return false;
  return true;
}

}  // namespace

PoseGraph projectToPlane(const PoseGraph& graph) {
  if (projectionIsIdentity(graph)) return graph;
  PoseGraph out;
  out.setDimension(GraphDimension::k2D);
  for (const Node& n : graph.nodes()) out.addNode(n.id, projectToPlane(n.pose));
  for (const Constraint& c : graph.constraints()) out.addConstraint(projectToPlane(c));
  for (NodeId id : graph.fixedNodes()) out.addFixed(id);
  return out;
}

}  // namespace toro
