#include "toro_ros/core/pose_graph.h"

#include <cmath>
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <sstream>

namespace toro {

namespace {
std::string describe(const Constraint& c) {
  std::ostringstream s;
  s << "constraint " << c.from << " -> " << c.to;
  return s.str();
}
}  // namespace

std::string checkInformation(const Matrix6& information) {
  if (!information.allFinite()) return "information matrix has a non-finite entry";
  const double scale = information.cwiseAbs().maxCoeff();
  if (scale == 0.0) return "information matrix is zero";
  const double asymmetry = (information - information.transpose()).cwiseAbs().maxCoeff();
  if (asymmetry > 1e-9 * scale) {
    std::ostringstream s;
    s << "information matrix is not symmetric (largest |I - I^T| entry " << asymmetry << ")";
    return s.str();
  }
  Eigen::LLT<Matrix6> llt(0.5 * (information + information.transpose()));
  if (llt.info() != Eigen::Success) return "information matrix is not positive definite";
  return {};
}

bool repairInformation(Matrix6& information) {
  if (!information.allFinite()) return false;
  const double scale = information.cwiseAbs().maxCoeff();
  if (scale == 0.0) return false;
  if ((information - information.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) return false;
  const Matrix6 symmetric = 0.5 * (information + information.transpose());
  if (Eigen::LLT<Matrix6>(symmetric).info() == Eigen::Success) return false;
  const Eigen::SelfAdjointEigenSolver<Matrix6> eigen(symmetric);
  if (eigen.info() != Eigen::Success) return false;
  const double largest = eigen.eigenvalues().maxCoeff();
  if (!(largest > 0.0)) return false;
  const Vector6 clamped = eigen.eigenvalues().cwiseMax(kRepairEigenvalueFraction * largest);
  Matrix6 repaired = eigen.eigenvectors() * clamped.asDiagonal() * eigen.eigenvectors().transpose();
  // Rounding in the product leaves tiny asymmetries; mirror so the result is exactly symmetric.
  repaired = (0.5 * (repaired + repaired.transpose())).eval();
  // Extreme magnitudes can overflow in the reconstruction; then there is nothing sound to return.
  if (!repaired.allFinite() || Eigen::LLT<Matrix6>(repaired).info() != Eigen::Success) return false;
  information = repaired;
  return true;
}

Matrix6 angleToQuaternionUnits(const Matrix6& information) {
  Matrix6 m = information;
  m.block<3, 3>(3, 3) *= 4.0;
  m.block<3, 3>(0, 3) *= 2.0;
  m.block<3, 3>(3, 0) *= 2.0;
  return m;
}

Matrix6 quaternionToAngleUnits(const Matrix6& information) {
  Matrix6 m = information;
  m.block<3, 3>(3, 3) *= 0.25;
  m.block<3, 3>(0, 3) *= 0.5;
  m.block<3, 3>(3, 0) *= 0.5;
  return m;
}

void PoseGraph::addNode(NodeId id, const Pose3& pose) {
  if (index_.count(id)) {
    throw GraphError("node " + std::to_string(id) + " already exists");
  }
  if (!pose.isFinite()) {
    throw GraphError("node " + std::to_string(id) + " has a non-finite pose");
  }
  index_.emplace(id, nodes_.size());
  nodes_.push_back(Node{id, pose});
}

std::string PoseGraph::validateConstraint(const Constraint& c) const {
  if (c.from == c.to) return describe(c) + ": self-loop (both ends are node " + std::to_string(c.from) + ")";
  if (!hasNode(c.from)) return describe(c) + ": unknown node " + std::to_string(c.from);
  if (!hasNode(c.to)) return describe(c) + ": unknown node " + std::to_string(c.to);
  if (!c.measurement.isFinite()) return describe(c) + ": measurement has a non-finite value";
  const std::string info = checkInformation(c.information);
  if (!info.empty()) return describe(c) + ": " + info;
  return {};
}

std::size_t PoseGraph::addConstraint(const Constraint& constraint) {
  const std::string reason = validateConstraint(constraint);
  if (!reason.empty()) throw GraphError(reason);
  constraints_.push_back(constraint);
  return constraints_.size() - 1;
}

void PoseGraph::scaleInformation(std::size_t c, double factor) {
  if (c >= constraints_.size()) throw GraphError("no constraint " + std::to_string(c));
  if (!(std::isfinite(factor) && factor > 0.0))
    throw GraphError("information scale factor must be finite and > 0, not " + std::to_string(factor));
  constraints_[c].information *= factor;
}

void PoseGraph::setKind(std::size_t c, ConstraintKind kind) {
  if (c >= constraints_.size()) throw GraphError("no constraint " + std::to_string(c));
  constraints_[c].kind = kind;
}

std::size_t PoseGraph::indexOf(NodeId id) const {
  const auto it = index_.find(id);
  if (it == index_.end()) throw GraphError("unknown node " + std::to_string(id));
  return it->second;
}

void PoseGraph::clear() {
  nodes_.clear();
  constraints_.clear();
  index_.clear();
  fixed_.clear();
  dimension_ = GraphDimension::k3D;
}

PoseGraph keepConstraints(const PoseGraph& graph, const std::function<bool(std::size_t)>& keep) {
  PoseGraph kept;
  kept.setDimension(graph.dimension());
  for (const Node& n : graph.nodes()) kept.addNode(n.id, n.pose);
  for (NodeId id : graph.fixedNodes()) kept.addFixed(id);
  for (std::size_t c = 0; c < graph.numConstraints(); ++c)
    if (keep(c)) kept.addConstraint(graph.constraints()[c]);
  return kept;
}

}  // namespace toro
