#include "toro_ros/core/metrics.h"

#include "toro_ros/core/finish_residuals.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace toro {

namespace {

using Matrix2 = Eigen::Matrix2d;
using Vector2 = Eigen::Vector2d;

double yawOf(const Pose3& p) { return p.rollPitchYaw().z(); }

Matrix2 planarRotation(double theta) {
  Matrix2 r;
  r << std::cos(theta), -std::sin(theta), std::sin(theta), std::cos(theta);
  return r;
}

double chi2Of3D(const Pose3& xi, const Pose3& xj, const Constraint& c) {
  const Pose3 delta = c.measurement.inverse() * (xi.inverse() * xj);
  const Quaternion& q = delta.rotation();
  const double sign = q.w() < 0.0 ? -1.0 : 1.0;  // the representative with w >= 0
  Vector6 e;
  e.head<3>() = delta.translation();
  e.tail<3>() = sign * q.vec();
  return e.dot(c.information * e);
}

double chi2Of2D(const Pose3& xi, const Pose3& xj, const Constraint& c) {
  const double ti = yawOf(xi), tj = yawOf(xj), tz = yawOf(c.measurement);
  const Vector2 dt = (xj.translation() - xi.translation()).head<2>();
  const Vector2 local = planarRotation(ti).transpose() * dt - c.measurement.translation().head<2>();
  Eigen::Vector3d e;
  e.head<2>() = planarRotation(tz).transpose() * local;
  e.z() = wrapAngle(tj - ti - tz);
  return e.dot(planarInformation(c.information) * e);
}

double constraintChi2Of(const PoseGraph& graph, const Constraint& c) {
  const Pose3& xi = graph.pose(c.from);
  const Pose3& xj = graph.pose(c.to);
  return graph.dimension() == GraphDimension::k2D ? chi2Of2D(xi, xj, c) : chi2Of3D(xi, xj, c);
}

// tr(M^-1) of a symmetric positive-definite block, via its Cholesky factor.
template <int N>
double traceOfInverse(const Eigen::Matrix<double, N, N>& m) {
  const Eigen::LLT<Eigen::Matrix<double, N, N>> llt(m);
  return llt.solve(Eigen::Matrix<double, N, N>::Identity()).trace();
}

double seSyncTerm3D(const Pose3& xi, const Pose3& xj, const Constraint& c) {
  const double tau = 3.0 / traceOfInverse<3>(c.information.topLeftCorner<3, 3>());
  const double kappa = 3.0 / (2.0 * traceOfInverse<3>(c.information.bottomRightCorner<3, 3>()));
  const Matrix3 ri = xi.rotationMatrix();
  const Matrix3 rot_residual = xj.rotationMatrix() - ri * c.measurement.rotationMatrix();
  const Vector3 t_residual = xj.translation() - xi.translation() - ri * c.measurement.translation();
  return kappa * rot_residual.squaredNorm() + tau * t_residual.squaredNorm();
}

double seSyncTerm2D(const Pose3& xi, const Pose3& xj, const Constraint& c) {
  const Eigen::Matrix3d planar = planarInformation(c.information);
  const double tau = 2.0 / traceOfInverse<2>(Matrix2(planar.topLeftCorner<2, 2>()));
  const double kappa = planar(2, 2);
  const Matrix2 ri = planarRotation(yawOf(xi));
  const Matrix2 rot_residual = planarRotation(yawOf(xj)) - ri * planarRotation(yawOf(c.measurement));
  const Vector2 t_residual =
      (xj.translation() - xi.translation()).head<2>() - ri * c.measurement.translation().head<2>();
  return kappa * rot_residual.squaredNorm() + tau * t_residual.squaredNorm();
}

}  // namespace

Eigen::Matrix3d planarInformation(const Matrix6& info) {
  // Inverse of the readers' lifting (see graph_io.h): exact power-of-two scalings.
  Eigen::Matrix3d out;
  out << info(0, 0), info(0, 1), info(0, 5) / 2.0,  //
      info(1, 0), info(1, 1), info(1, 5) / 2.0,     //
      info(5, 0) / 2.0, info(5, 1) / 2.0, info(5, 5) / 4.0;
  return out;
}

double g2oChi2(const PoseGraph& graph) {
  double sum = 0.0;
  for (const Constraint& c : graph.constraints()) sum += constraintChi2Of(graph, c);
  return sum;
}

double robustObjective(const PoseGraph& graph, const RobustOptions& robust) {
  if (!robust.enabled()) return g2oChi2(graph);
  double sum = 0.0;
  for (const Constraint& c : graph.constraints()) {
    const double chi2 = constraintChi2Of(graph, c);
    sum += isLoopClosure(c) ? robustCost(robust, chi2) : chi2;
  }
  return sum;
}

std::vector<double> robustWeights(const PoseGraph& graph, const RobustOptions& robust) {
  std::vector<double> out(graph.numConstraints(), 1.0);
  if (!robust.enabled()) return out;
  for (std::size_t k = 0; k < out.size(); ++k) {
    const Constraint& c = graph.constraints()[k];
    if (isLoopClosure(c)) out[k] = robustWeight(robust, constraintChi2Of(graph, c));
  }
  return out;
}

double adaptedRobustWidth(const PoseGraph& graph, const RobustOptions& robust) {
  if (!robust.enabled() || !(robust.adaptive_width_factor > 0.0)) return robust.width;
  std::vector<double> accepted;  // weight >= kRejectedWeight
  for (const Constraint& c : graph.constraints()) {
    if (!isLoopClosure(c)) continue;
    const double chi2 = constraintChi2Of(graph, c);
    if (robustWeight(robust, chi2) >= kRejectedWeight) accepted.push_back(chi2);
  }
  if (accepted.empty()) return robust.width;
  const auto top = accepted.begin() + static_cast<std::ptrdiff_t>(0.99 * static_cast<double>(accepted.size() - 1));
  std::nth_element(accepted.begin(), top, accepted.end());
  const double width = robust.adaptive_width_factor * *top;
  return width > 0.0 && width < robust.width ? width : robust.width;
}

double alignedPositionRmse(const PoseGraph& estimate, const PoseGraph& reference) {
  std::vector<Vector3> from, to;
  for (const Node& n : estimate.nodes()) {
    if (!reference.hasNode(n.id)) continue;
    from.push_back(n.pose.translation());
    to.push_back(reference.pose(n.id).translation());
  }
  if (from.empty()) return 0.0;
  const std::size_t n = from.size();
  Eigen::Matrix3Xd a(3, n), b(3, n);
  for (std::size_t i = 0; i < n; ++i) {
    a.col(static_cast<Eigen::Index>(i)) = from[i];
    b.col(static_cast<Eigen::Index>(i)) = to[i];
  }
  const Eigen::Matrix4d t = n >= 3 ? Eigen::umeyama(a, b, false) : Eigen::Matrix4d::Identity();
  const Eigen::Matrix3Xd aligned = (t.topLeftCorner<3, 3>() * a).colwise() + t.topRightCorner<3, 1>();
  return std::sqrt((aligned - b).colwise().squaredNorm().sum() / static_cast<double>(n));
}

double constraintChi2(const PoseGraph& graph, std::size_t constraint_index) {
  if (constraint_index >= graph.numConstraints()) {
    throw std::out_of_range("constraintChi2: index " + std::to_string(constraint_index) +
                            " out of range (graph has " + std::to_string(graph.numConstraints()) +
                            " constraints)");
  }
  return constraintChi2Of(graph, graph.constraints()[constraint_index]);
}

double seSyncObjective(const PoseGraph& graph) {
  const bool planar = graph.dimension() == GraphDimension::k2D;
  double sum = 0.0;
  for (const Constraint& c : graph.constraints()) {
    const Pose3& xi = graph.pose(c.from);
    const Pose3& xj = graph.pose(c.to);
    sum += planar ? seSyncTerm2D(xi, xj, c) : seSyncTerm3D(xi, xj, c);
  }
  return sum;
}

ToroError toroError(const PoseGraph& graph) {
  ToroError out;
  for (const Constraint& c : graph.constraints()) {
    // TORO's residual X_j^-1 X_i Z (identity when the constraint is met).
    const Pose3 residual = graph.pose(c.to).inverse() * graph.pose(c.from) * c.measurement;
    const double rotation = residual.angle();
    const double translation = residual.translation().norm();
    out.sum += rotation * rotation + translation * translation;
    out.max_rotation = std::max(out.max_rotation, rotation);
    out.max_translation = std::max(out.max_translation, translation);
    out.mean_rotation += rotation;
    out.mean_translation += translation;
  }
  if (graph.numConstraints() > 0) {
    out.mean_rotation /= static_cast<double>(graph.numConstraints());
    out.mean_translation /= static_cast<double>(graph.numConstraints());
  }
  return out;
}

}  // namespace toro
