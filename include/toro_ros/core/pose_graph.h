// The pose graph: nodes (poses keyed by integer id, ids increasing with time) and relative-pose
// constraints with 6x6 information matrices.
#pragma once

#include <cstddef>
#include <functional>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

#include "toro_ros/core/pose3.h"

namespace toro {

using NodeId = long long;

// Thrown when a node or constraint is refused; the message names it and says why.
class GraphError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Node {
  NodeId id = 0;
  Pose3 pose;  // world_T_node (the current estimate)
};

// What a constraint is to the robust estimators: loop closures may be wrong and get a weight from
// their residual (robust_kernel.h); odometry is trusted and stays Gaussian.  kAuto decides by the
// ids: consecutive ids (|to - from| == 1) are odometry, anything else a loop closure, which is right
// for datasets and for the pipeline's keyframes (ids by time); callers that know better say so.
enum class ConstraintKind : unsigned char { kAuto, kOdometry, kLoopClosure };

// Constraint from -> to: `measurement` is from_T_to, i.e. the pose of `to` in the frame of `from`.
// The information matrix is ordered as in g2o: translation (x y z) first, then rotation, and the
// rotational block is in units of the quaternion's vector part (about half the rotation angle), so
// an information of 4*w on the q-vector is w per rad^2 on the angle.
struct Constraint {
  NodeId from = 0;
  NodeId to = 0;
  Pose3 measurement;
  Matrix6 information = Matrix6::Identity();
  ConstraintKind kind = ConstraintKind::kAuto;
};

// Whether the robust estimators treat `c` as a loop closure (see ConstraintKind).
inline bool isLoopClosure(const Constraint& c) {
  if (c.kind != ConstraintKind::kAuto) return c.kind == ConstraintKind::kLoopClosure;
  return c.to - c.from != 1 && c.from - c.to != 1;
}

// How big 2D graphs map onto the 3D graph: they are lifted into the plane z = 0, and remember
// that they are 2D so writers and metrics can use the 2D definitions.
enum class GraphDimension { k3D, k2D };

class PoseGraph {
 public:
  // Adds a node; throws GraphError if the id exists or the pose is not finite.
  void addNode(NodeId id, const Pose3& pose);
  // Adds a constraint after validation (see validateConstraint); returns its index.
  std::size_t addConstraint(const Constraint& constraint);

  // Multiplies constraint c's information by `factor` (> 0 and finite, else GraphError): a
  // positive multiple of a valid information is valid, so no re-validation is needed.
  void scaleInformation(std::size_t c, double factor);
  // Sets constraint c's kind (GraphError if there is no constraint c); nothing else changes, so no
  // re-validation is needed.
  void setKind(std::size_t c, ConstraintKind kind);

  // Empty string if the constraint is acceptable for this graph, otherwise the reason.
  // Checks: finite measurement and information, symmetric positive-definite information,
  // both endpoints known, no self-loop.
  std::string validateConstraint(const Constraint& constraint) const;

  bool hasNode(NodeId id) const { return index_.count(id) != 0; }
  // Dense index of a node (insertion order); throws GraphError for an unknown id.
  std::size_t indexOf(NodeId id) const;

  std::size_t numNodes() const { return nodes_.size(); }
  std::size_t numConstraints() const { return constraints_.size(); }
  bool empty() const { return nodes_.empty(); }

  const std::vector<Node>& nodes() const { return nodes_; }
  const std::vector<Constraint>& constraints() const { return constraints_; }
  const Node& node(std::size_t index) const { return nodes_[index]; }
  const Pose3& pose(NodeId id) const { return nodes_[indexOf(id)].pose; }
  void setPose(NodeId id, const Pose3& pose) { nodes_[indexOf(id)].pose = pose; }
  void setPoseAt(std::size_t index, const Pose3& pose) { nodes_[index].pose = pose; }

  // Ids held fixed by the file (g2o FIX); informational for the optimisers' gauge choice.
  const std::vector<NodeId>& fixedNodes() const { return fixed_; }
  void addFixed(NodeId id) { fixed_.push_back(id); }

  GraphDimension dimension() const { return dimension_; }
  void setDimension(GraphDimension d) { dimension_ = d; }

  void clear();

 private:
  std::vector<Node> nodes_;
  std::vector<Constraint> constraints_;
  std::unordered_map<NodeId, std::size_t> index_;
  std::vector<NodeId> fixed_;
  GraphDimension dimension_ = GraphDimension::k3D;
};

// The graph with only the constraints c for which keep(c) is true, in their order; the nodes, their
// poses, the fixed nodes and the dimension as in `graph`.  What a finish without held or set-aside
// loop closures, or a leave-one-out solve, runs on.
PoseGraph keepConstraints(const PoseGraph& graph, const std::function<bool(std::size_t)>& keep);

// Conversions of a translation-first 6x6 information matrix between angle units (per rad^2 on the
// rotation vector or Euler angles: TORO files, geometry_msgs covariances) and the core's units
// (per unit^2 on the quaternion's vector part, about half the angle): rotation block x4, cross
// blocks x2, and back.  Exact powers of two, so a round trip is exact.
Matrix6 angleToQuaternionUnits(const Matrix6& information);
Matrix6 quaternionToAngleUnits(const Matrix6& information);

// An axis of a 3x3 block (translation or rotation) of an information matrix whose information is
// below this fraction of the block's largest counts as unmeasured: a sender that marks z, roll and
// pitch unknown with variance 1e6 gives ~1e-8 of its measured axes' information.  The optimisers'
// scalar weights and step directions ignore such axes (TreeOptimizer), rather than weighing the
// whole constraint by them.
constexpr double kUnmeasuredInformationRatio = 1e-6;

// Reason string for an information matrix that is unusable (non-finite, asymmetric beyond a
// relative tolerance, or not positive definite); empty if fine.
std::string checkInformation(const Matrix6& information);

// Fraction of the largest eigenvalue that repairInformation gives to the eigenvalues it raises.
constexpr double kRepairEigenvalueFraction = 1e-6;

// Projects a symmetric information matrix that is not positive definite (real data has 6x6
// matrices whose 3x3 blocks are positive definite while the whole is indefinite) onto the nearest
// positive-definite matrix: eigenvalues below kRepairEigenvalueFraction * (largest eigenvalue)
// are raised to that value, the eigenvectors kept.  Returns true if it changed the matrix; false
// (matrix untouched) if it was already positive definite or cannot be repaired: a non-finite
// entry, asymmetry (as checkInformation judges it), or no positive eigenvalue.
bool repairInformation(Matrix6& information);

}  // namespace toro
