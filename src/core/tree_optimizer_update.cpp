// The group-dependent half of TreeOptimizer: parameters, initial guesses, pose recomputation and
// the update of one constraint's path, each one template over the group (tree_groups.h), behind
// small dispatchers that pick SE(3) or SE(2) once per call.  The dimension-independent half (tree,
// preconditioner, robust weights, schedule) is tree_optimizer.cpp.
#include "toro_ros/core/tree_optimizer.h"

#include <algorithm>
#include <cmath>

#include "toro_ros/core/finish_residuals.h"  // wrapAngle
#include "toro_ros/core/planar.h"

namespace toro {

namespace {

constexpr std::size_t kNone = ParameterTree::kNone;

// Fraction of a constraint's error removed by one update: the learning rate times the constraint's
// information over the stiffness of its path (Olson's preconditioned step, summed over the path),
// never more than the whole error.
double stepFraction(double learning_rate, double info, double weight_sum) {
  return std::min(1.0, learning_rate * info * weight_sum);
}

// Fills the signed share of the correction that each path node takes: moving along the path from
// the constraint's first end (share -u_top) over the top (share 0) to its second end (share
// 1 - u_top), every node's share grows by its joint's weight / total weight.  A node's weight is
// the inverse of its stiffness (the preconditioner), capped by the inverse of this constraint's own
// information, which the stiffness always includes when it is up to date.
template <class Stiffness>
double computeShares(const std::vector<std::size_t>& up, const std::vector<std::size_t>& down,
                     const Stiffness* inverse, double Stiffness::*inverse_stiffness, double own_information,
                     std::vector<double>& up_share, std::vector<double>& down_share) {
  // Grow only: the entries past the path are stale and never read.
  if (up_share.size() < up.size()) up_share.resize(up.size());
  if (down_share.size() < down.size()) down_share.resize(down.size());
  const double cap = 1.0 / own_information;
  double up_total = 0.0;
  for (std::size_t i = up.size(); i-- > 0;) {
    up_total += std::min(inverse[up[i]].*inverse_stiffness, cap);
    up_share[i] = up_total;
  }
  double down_total = 0.0;
  for (std::size_t i = down.size(); i-- > 0;) {
    down_total += std::min(inverse[down[i]].*inverse_stiffness, cap);
    down_share[i] = down_total;
  }
  const double total = up_total + down_total;
  const double scale = 1.0 / total;
  for (std::size_t i = 0; i < up.size(); ++i) up_share[i] *= -scale;
  for (std::size_t i = 0; i < down.size(); ++i) down_share[i] *= scale;
  return total;
}

// Both kinds of shares in one walk over the path (the usual case: rotational and translational
// information both positive), each computed exactly as computeShares would.
template <class Stiffness>
void computeBothShares(const std::vector<std::size_t>& up, const std::vector<std::size_t>& down,
                       const Stiffness* inverse, double rotation_information, double translation_information,
                       std::vector<double>& up_rotation, std::vector<double>& down_rotation,
                       std::vector<double>& up_translation, std::vector<double>& down_translation,
                       double* rotation_total, double* translation_total) {
  const double rotation_cap = 1.0 / rotation_information;
  const double translation_cap = 1.0 / translation_information;
  if (up_rotation.size() < up.size()) up_rotation.resize(up.size());
  if (up_translation.size() < up.size()) up_translation.resize(up.size());
  if (down_rotation.size() < down.size()) down_rotation.resize(down.size());
  if (down_translation.size() < down.size()) down_translation.resize(down.size());
  // Cumulative sums from the top down each branch, then scaled to the signed shares.
  const auto accumulate = [&](const std::vector<std::size_t>& branch, double* r, double* t, double* r_total,
                              double* t_total) {
    const std::size_t* nodes = branch.data();
    double sum_r = 0.0, sum_t = 0.0;
    for (std::size_t i = branch.size(); i-- > 0;) {
      const std::size_t v = nodes[i];
      sum_r += std::min(inverse[v].rotation, rotation_cap);
      r[i] = sum_r;
      sum_t += std::min(inverse[v].translation, translation_cap);
      t[i] = sum_t;
    }
    *r_total = sum_r;
    *t_total = sum_t;
  };
  double up_r, up_t, down_r, down_t;
  accumulate(up, up_rotation.data(), up_translation.data(), &up_r, &up_t);
  accumulate(down, down_rotation.data(), down_translation.data(), &down_r, &down_t);
  *rotation_total = up_r + down_r;
  *translation_total = up_t + down_t;
  const double rotation_scale = 1.0 / *rotation_total;
  const double translation_scale = 1.0 / *translation_total;
  const auto scale = [](std::size_t n, double* r, double* t, double r_scale, double t_scale) {
    for (std::size_t i = 0; i < n; ++i) {
      r[i] *= r_scale;
      t[i] *= t_scale;
    }
  };
  scale(up.size(), up_rotation.data(), up_translation.data(), -rotation_scale, -translation_scale);
  scale(down.size(), down_rotation.data(), down_translation.data(), rotation_scale, translation_scale);
}

}  // namespace

// ---- dispatchers --------------------------------------------------------------------------------

void TreeOptimizer::clearParameters() {
  spatial_.clear();
  planar_state_.clear();
}

void TreeOptimizer::registerGroupConstraint(std::size_t c) {
  planar_ ? registerGroupConstraintIn<Planar>(c) : registerGroupConstraintIn<Spatial>(c);
}

void TreeOptimizer::appendParameter(const Pose3& pose) {
  if (planar_) {
    planar_state_.parameters.push_back(Planar::fromPose3(pose));
    planar_state_.world.push_back(planar_state_.parameters.back());
  } else {
    spatial_.parameters.push_back(pose);
  }
}

void TreeOptimizer::parameterFromPoses(std::size_t v) {
  planar_ ? parameterFromPosesIn<Planar>(v) : parameterFromPosesIn<Spatial>(v);
}

void TreeOptimizer::parametersFromPoses() {
  for (std::size_t v = 0; v < graph_.numNodes(); ++v) parameterFromPoses(v);
}

void TreeOptimizer::chainInitialGuess() {
  planar_ ? chainInitialGuessIn<Planar>() : chainInitialGuessIn<Spatial>();
}

void TreeOptimizer::recomputePoses() { planar_ ? recomputePosesIn<Planar>() : recomputePosesIn<Spatial>(); }

template <class PoseAt>
void TreeOptimizer::placePoses(PoseAt pose_at) {
  for (std::size_t v = 0; v < graph_.numNodes(); ++v) {
    Pose3 pose = planar_ ? projectToPlane(pose_at(v)) : pose_at(v);
    pose.normalize();  // products of poses drift off the unit quaternion; the passes assume it
    graph_.setPoseAt(v, pose);
  }
  parametersFromPoses();
  // The poses are rebuilt from the parameters as after a pass, so both agree to the last bit and
  // the group's own world state (SE(2)) follows.
  recomputePoses();
}

void TreeOptimizer::setPoses(const std::vector<Pose3>& poses) {
  if (poses.size() != graph_.numNodes())
    throw std::invalid_argument("TreeOptimizer::setPoses: " + std::to_string(poses.size()) + " poses for " +
                                std::to_string(graph_.numNodes()) + " nodes");
  placePoses([&](std::size_t v) -> const Pose3& { return poses[v]; });
}

void TreeOptimizer::takeSolution(const PoseGraph& solution) {
  const std::size_t solved = solution.numNodes(), n = graph_.numNodes();
  if (solved > n)
    throw std::invalid_argument("TreeOptimizer::takeSolution: " + std::to_string(solved) + " poses for " +
                                std::to_string(n) + " nodes");
  // The nodes added since, parents first (a parent is nearer the root): each one's pose is its
  // parent's (the solution's, or placed so) times its current parameter, read from the current
  // poses, which stay as they are until every newer one is placed.
  newer_order_.clear();
  for (std::size_t v = solved; v < n; ++v) newer_order_.push_back(v);
  std::sort(newer_order_.begin(), newer_order_.end(),
            [&](std::size_t a, std::size_t b) { return tree_.level(a) < tree_.level(b); });
  newer_poses_.resize(n - solved);
  for (std::size_t v : newer_order_) {
    const std::size_t p = tree_.parent(v);
    newer_poses_[v - solved] = p == kNone ? graph_.node(v).pose
                                          : (p < solved ? solution.node(p).pose : newer_poses_[p - solved]) *
                                                relativePose(graph_.node(p).pose, graph_.node(v).pose);
  }
  // Then as setPoses, in index order (the tree's order jumps through memory: measured slower).
  placePoses([&](std::size_t v) -> const Pose3& {
    return v < solved ? solution.node(v).pose : newer_poses_[v - solved];
  });
}

void TreeOptimizer::updateConstraint(std::size_t c, double learning_rate) {
  planar_ ? updateConstraintIn<Planar>(c, learning_rate) : updateConstraintIn<Spatial>(c, learning_rate);
}

void TreeOptimizer::runPass(const std::vector<std::size_t>& constraints, double learning_rate, bool partial) {
  // The group is chosen once per pass, so the loop over constraints is the template's alone.
  if (planar_) {
    runPassIn<Planar>(constraints, learning_rate, partial);
  } else {
    runPassIn<Spatial>(constraints, learning_rate, partial);
  }
}

template <class G>
void TreeOptimizer::runPassIn(const std::vector<std::size_t>& constraints, double learning_rate, bool partial) {
  detail::TreeGroupState<G>& s = state<G>();
  record_moved_ = partial;
  if (partial && moved_mark_.size() < graph_.numNodes()) moved_mark_.resize(graph_.numNodes(), 0);
  const std::size_t n = constraints.size();
  for (std::size_t k = 0; k < n; ++k) {
    // The visiting order jumps through the per-constraint arrays: fetch what the constraint after
    // next reads first, so its cache misses overlap with this update.
    if (k + 2 < n) {
      const std::size_t ahead = constraints[k + 2];
      __builtin_prefetch(&constraint_rotation_info_[ahead]);
      __builtin_prefetch(&constraint_translation_info_[ahead]);
      __builtin_prefetch(&from_index_[ahead]);
      __builtin_prefetch(&to_index_[ahead]);
      __builtin_prefetch(&measured_axes_index_[ahead]);
      __builtin_prefetch(&s.measurements[ahead]);
    }
    // ...and, for the next one (whose endpoints are in cache by now), what its path starts from.
    if (k + 1 < n) {
      const std::size_t next = constraints[k + 1];
      for (std::size_t v : {from_index_[next], to_index_[next]}) {
        __builtin_prefetch(&s.parameters[v]);
        __builtin_prefetch(&tree_.levels()[v]);
        __builtin_prefetch(&tree_.parents()[v]);
        __builtin_prefetch(&inverse_weight_[v]);
      }
    }
    updateConstraintIn<G>(constraints[k], learning_rate);
  }
  record_moved_ = false;
  if (partial) {
    recomputeMovedPosesIn<G>();
  } else {
    recomputePosesIn<G>();
  }
}

// ---- parameters -------------------------------------------------------------------------------

template <class G>
void TreeOptimizer::registerGroupConstraintIn(std::size_t c) {
  detail::TreeGroupState<G>& s = state<G>();
  const Constraint& k = graph_.constraints()[c];
  s.measurements.push_back(G::fromPose3(k.measurement));
  const typename G::Stiffness stiffness = G::stiffness(k.information);
  base_translation_info_.push_back(stiffness.translation);
  base_rotation_info_.push_back(stiffness.rotation);
  constraint_translation_info_.push_back(stiffness.translation);
  constraint_rotation_info_.push_back(stiffness.rotation);
  if (stiffness.all_axes_measured) {
    measured_axes_index_.push_back(-1);
  } else {
    measured_axes_index_.push_back(static_cast<int>(s.measured_axes.size()));
    s.measured_axes.push_back(stiffness);
    if (!isLoopClosure(k)) ++odometry_with_unmeasured_axes_;
  }
}

template <class G>
void TreeOptimizer::parameterFromPosesIn(std::size_t v) {
  detail::TreeGroupState<G>& s = state<G>();
  const std::size_t p = tree_.parent(v);
  const Pose3& pose = graph_.node(v).pose;
  s.parameters[v] = p == kNone ? G::fromPose3(pose) : G::fromPose3(relativePose(graph_.node(p).pose, pose));
}

template <class G>
void TreeOptimizer::chainInitialGuessIn() {
  detail::TreeGroupState<G>& s = state<G>();
  for (std::size_t v : topological_order_) {
    const std::size_t p = tree_.parent(v);
    if (p == kNone) {
      s.parameters[v] = G::fromPose3(graph_.node(v).pose);  // a root keeps its given pose: the gauge
      continue;
    }
    // The first constraint (in graph order) between the node and its parent defines the guess.
    for (std::size_t c : incident_[v]) {
      if (from_index_[c] == p) {
        s.parameters[v] = s.measurements[c];
        break;
      }
      if (to_index_[c] == p) {
        s.parameters[v] = s.measurements[c].inverse();
        break;
      }
    }
  }
}

template <class G>
inline void TreeOptimizer::recomputePoseIn(std::size_t v) {
  detail::TreeGroupState<G>& s = state<G>();
  const std::size_t p = tree_.parent(v);
  if constexpr (G::kPlanar) {
    s.world[v] = p == kNone ? s.parameters[v] : s.world[p] * s.parameters[v];
    graph_.setPoseAt(v, G::toPose3(s.world[v]));
  } else {
    graph_.setPoseAt(v, p == kNone ? s.parameters[v] : graph_.node(p).pose * s.parameters[v]);
  }
}

template <class G>
inline void TreeOptimizer::recomputePosesIn() {
  // Every pose may move: the chi2 record and the journal start over.
  chi2_valid_ = false;
  changes_.markAll();
  if (topological_dirty_) {
    topological_order_ = tree_.topologicalOrder();
    topological_dirty_ = false;
  }
  for (std::size_t v : topological_order_) recomputePoseIn<G>(v);
}

template <class G>
void TreeOptimizer::recomputeMovedPosesIn() {
  // A node's pose is its parent's times its parameter, so exactly the subtrees of the nodes whose
  // parameters changed move.  Roots nearest the tree's root first: a changed node inside a subtree
  // already walked is skipped, and every walked node's parent is final when it is recomputed.
  std::sort(moved_roots_.begin(), moved_roots_.end(),
            [&](std::size_t a, std::size_t b) { return tree_.level(a) < tree_.level(b); });
  moved_.clear();
  if (region_.size() < graph_.numNodes()) region_.resize(graph_.numNodes(), kNone);
  for (std::size_t root : moved_roots_) {
    if (moved_mark_[root] == 2) continue;
    subtree_stack_.assign(1, root);
    while (!subtree_stack_.empty()) {
      const std::size_t v = subtree_stack_.back();
      subtree_stack_.pop_back();
      recomputePoseIn<G>(v);
      // A changed node starts a region; the others move with their parent's.
      region_[v] = moved_mark_[v] == 1 ? v : region_[tree_.parent(v)];
      moved_mark_[v] = 2;
      moved_.push_back(v);
      for (std::size_t child : tree_.children(v)) subtree_stack_.push_back(child);
    }
  }
  afterPosesMoved(moved_);  // reads the marks and regions of the walk
  for (std::size_t v : moved_roots_) moved_mark_[v] = 0;
  for (std::size_t v : moved_) moved_mark_[v] = 0;
  moved_roots_.clear();
}

// ---- the update of one constraint ---------------------------------------------------------------
//
// One visit (Eq. 19 of the IROS paper; in the plane, the RSS paper's update): the path's poses in
// the top node's frame are composed from the parameters; the rotation error is spread over them by
// the rotational shares, the translation residual (after the rotation of the first end) by the
// translational ones; then each parameter becomes the new pose of its node relative to the new
// pose of its parent (moveAndWriteBack).

template <class G>
inline void TreeOptimizer::updateConstraintIn(std::size_t c, double learning_rate) {
  // A loop closure whose robust weight vanished (infinite residual) has nothing to say.
  if (!(constraint_rotation_info_[c] > 0.0) && !(constraint_translation_info_[c] > 0.0)) return;
  const std::size_t a = from_index_[c], b = to_index_[c];
  const bool naive = !G::kPlanar && options_.rotation_update == RotationUpdate::kNaiveEuler;
  if (!naive && (tree_.parent(a) == b || tree_.parent(b) == a)) {
    updateParentEdge<G>(c, learning_rate, tree_.parent(a) == b);
    if (record_moved_) recordMoved(tree_.parent(a) == b ? a : b);
    return;
  }
  const std::size_t top = tree_.path(a, b, up_, down_);
  if (top == kNone) return;  // ends in different trees: cannot happen for a constraint of the graph
  detail::TreeGroupState<G>& s = state<G>();
  // Poses of the path nodes in the top node's frame; the top node itself is the identity there.
  // The scratch vectors only grow, so a visit never constructs or allocates.
  if (s.up_poses.size() < up_.size()) s.up_poses.resize(up_.size());
  if (s.down_poses.size() < down_.size()) s.down_poses.resize(down_.size());
  composeFromTop<G>(up_, s.up_poses);
  composeFromTop<G>(down_, s.down_poses);
  const double rotation_info = constraint_rotation_info_[c];
  const double translation_info = constraint_translation_info_[c];
  double rotation_sum = 0.0, translation_sum = 0.0;  // of the path's capped inverse stiffness
  if (rotation_info > 0.0 && translation_info > 0.0) {
    computeBothShares(up_, down_, inverse_weight_.data(), rotation_info, translation_info, up_rotation_share_, down_rotation_share_, up_translation_share_,
                      down_translation_share_, &rotation_sum, &translation_sum);
  } else if (rotation_info > 0.0) {
    rotation_sum = computeShares(up_, down_, inverse_weight_.data(), &InverseStiffness::rotation, rotation_info, up_rotation_share_,
                                 down_rotation_share_);
  } else {
    translation_sum = computeShares(up_, down_, inverse_weight_.data(), &InverseStiffness::translation, translation_info,
                                    up_translation_share_, down_translation_share_);
  }
  PathStep<G> step;
  if constexpr (!G::kPlanar) {
    // The naive variant moves the rotations itself; the loop below then only translates.
    if (options_.rotation_update == RotationUpdate::kNaiveEuler) {
      distributeRotationNaively(c, learning_rate, rotation_sum);
    } else {
      rotationStep<G>(c, learning_rate, rotation_sum, &step);
    }
  } else {
    rotationStep<G>(c, learning_rate, rotation_sum, &step);  // planar rotations commute: no naive variant
  }
  translationStep<G>(c, learning_rate, translation_sum, &step);
  moveAndWriteBack<G>(up_, up_rotation_share_, up_translation_share_, step, true, s.up_poses);
  moveAndWriteBack<G>(down_, down_rotation_share_, down_translation_share_, step, false, s.down_poses);
  if (record_moved_) {
    for (std::size_t v : up_) recordMoved(v);
    for (std::size_t v : down_) recordMoved(v);
  }
}

template <class G>
inline void TreeOptimizer::updateParentEdge(std::size_t c, double learning_rate, bool first_end_is_child) {
  // The general update for a path of one node (the child; its parent is the top), with the loops
  // written out: the same operations, so the same result bit for bit, without the walk, the share
  // vectors and the scratch poses that dominate such a short update.
  using Rotation = typename G::Rotation;
  detail::TreeGroupState<G>& s = state<G>();
  const std::size_t child = first_end_is_child ? from_index_[c] : to_index_[c];
  typename G::Pose& parameter = s.parameters[child];
  typename G::Pose pose = parameter;  // top_T_child: the parent is the top
  const typename G::Pose& measurement = s.measurements[c];
  const int axes = measured_axes_index_[c];
  const double rotation_info = constraint_rotation_info_[c];
  if (rotation_info > 0.0) {
    const Rotation identity = Rotation::Identity();
    const Rotation& qa = first_end_is_child ? pose.rotation() : identity;
    const Rotation& qb = first_end_is_child ? identity : pose.rotation();
    const Rotation& qz = measurement.rotation();
    typename G::Tangent error = G::log(qa * qz * qb.conjugate());
    if constexpr (!G::kPlanar) {
      if (axes >= 0 && s.measured_axes[axes].rotation_partial) {
        const Matrix3 r = (qa * qz).toRotationMatrix();
        error = r * (s.measured_axes[axes].rotation_projection * (r.transpose() * error));
      }
    }
    const double weight = std::min(inverse_weight_[child].rotation, 1.0 / rotation_info);
    const double share = first_end_is_child ? weight * -(1.0 / weight) : weight * (1.0 / weight);
    const double fraction = stepFraction(learning_rate, rotation_info, weight);
    pose.setRotationUnchecked(G::exp(share * fraction * error) * pose.rotation());
  }
  const double translation_info = constraint_translation_info_[c];
  if (translation_info > 0.0) {
    using Translation = typename G::Translation;
    // The first end after the rotation step: the child itself, or the top (identity).
    const typename G::Pose top_T_a = first_end_is_child ? pose : typename G::Pose();
    const Translation b = first_end_is_child ? Translation::Zero() : pose.translation();
    Translation residual = top_T_a * measurement.translation() - b;
    if (axes >= 0 && s.measured_axes[axes].translation_partial) {
      const auto r = (top_T_a.rotation() * measurement.rotation()).toRotationMatrix();
      residual = r * (s.measured_axes[axes].translation_projection * (r.transpose() * residual));
    }
    const double weight = std::min(inverse_weight_[child].translation, 1.0 / translation_info);
    const double share = first_end_is_child ? weight * -(1.0 / weight) : weight * (1.0 / weight);
    const double fraction = stepFraction(learning_rate * translation_rate_factor_, translation_info, weight);
    pose.setTranslation(pose.translation() + (share * fraction) * residual);
  }
  parameter = pose;
  parameter.renormalize();
}

template <class G>
inline void TreeOptimizer::composeFromTop(const std::vector<std::size_t>& branch,
                                          std::vector<typename G::Pose>& poses) {
  const std::size_t n = branch.size();
  if (n == 0) return;
  const std::size_t* nodes = branch.data();
  const typename G::Pose* parameters = state<G>().parameters.data();
  typename G::Pose* out = poses.data();
  // The running product stays in registers (the stores to `out` might alias `parameters` for all
  // the compiler knows, which made it reload each one).
  typename G::Pose top_T_node = parameters[nodes[n - 1]];
  out[n - 1] = top_T_node;
  for (std::size_t i = n - 1; i-- > 0;) {
    top_T_node = top_T_node * parameters[nodes[i]];
    out[i] = top_T_node;
  }
}

template <class G>
inline void TreeOptimizer::rotationStep(std::size_t c, double learning_rate, double weight_sum,
                                        PathStep<G>* step) {
  using Rotation = typename G::Rotation;
  const double info = constraint_rotation_info_[c];
  if (!(info > 0.0)) return;
  detail::TreeGroupState<G>& s = state<G>();
  const Rotation identity = Rotation::Identity();
  const Rotation& qa = up_.empty() ? identity : s.up_poses[0].rotation();
  const Rotation& qb = down_.empty() ? identity : s.down_poses[0].rotation();
  const Rotation& qz = s.measurements[c].rotation();
  // Rotation that, applied on the left (in the top frame), takes b's orientation to a * Z.
  step->rotation_error = G::log(qa * qz * qb.conjugate());
  if constexpr (!G::kPlanar) {
    const int axes = measured_axes_index_[c];
    if (axes >= 0 && s.measured_axes[axes].rotation_partial) {
      // The error in the top frame is R v for the constraint-frame error v, R = rotation of a * Z.
      const Matrix3 r = (qa * qz).toRotationMatrix();
      step->rotation_error =
          r * (s.measured_axes[axes].rotation_projection * (r.transpose() * step->rotation_error));
    }
  }
  step->rotation_fraction = stepFraction(learning_rate, info, weight_sum);
  step->rotate = true;
  if (!up_.empty()) {
    // The first end's new rotation: the translation residual is taken after it.
    step->first_end_rotation =
        G::exp(up_rotation_share_[0] * step->rotation_fraction * step->rotation_error) * qa;
  }
}

template <class G>
inline void TreeOptimizer::translationStep(std::size_t c, double learning_rate, double weight_sum,
                                           PathStep<G>* step) {
  using Pose = typename G::Pose;
  using Translation = typename G::Translation;
  const double info = constraint_translation_info_[c];
  if (!(info > 0.0)) return;
  detail::TreeGroupState<G>& s = state<G>();
  const Pose& measurement = s.measurements[c];
  // The first end as the rotation step leaves it (the top node's frame when it is the top).
  Pose top_T_a = up_.empty() ? Pose() : s.up_poses[0];
  if (step->rotate && !up_.empty()) top_T_a.setRotationUnchecked(step->first_end_rotation);
  const Translation b = down_.empty() ? Translation::Zero() : s.down_poses[0].translation();
  step->residual = top_T_a * measurement.translation() - b;
  const int axes = measured_axes_index_[c];
  if (axes >= 0 && s.measured_axes[axes].translation_partial) {
    const auto r = (top_T_a.rotation() * measurement.rotation()).toRotationMatrix();
    step->residual = r * (s.measured_axes[axes].translation_projection * (r.transpose() * step->residual));
  }
  step->translation_fraction = stepFraction(learning_rate * translation_rate_factor_, info, weight_sum);
  step->translate = true;
}

template <class G>
inline void TreeOptimizer::moveAndWriteBack(const std::vector<std::size_t>& branch,
                                            const std::vector<double>& rotation_share,
                                            const std::vector<double>& translation_share,
                                            const PathStep<G>& step, bool first_end_branch,
                                            std::vector<typename G::Pose>& poses) {
  using Pose = typename G::Pose;
  const std::size_t n = branch.size();
  if (n == 0) return;
  const std::size_t* nodes = branch.data();
  Pose* parameters = state<G>().parameters.data();
  Pose* pose = poses.data();
  // All partial rotations share one axis, so they commute and the two ends end up exactly
  // `fraction` of the error apart; each parameter then absorbs the increment between its parent's
  // correction and its own, conjugated into its parent's frame (Eq. 19).
  if (step.rotate) {
    // A loop of its own: an SE(3) exponential is a long chain of dependent operations, and only a
    // short loop body lets the processor overlap several nodes' chains (measured on sphere2500).
    const double* share = rotation_share.data();
    for (std::size_t i = first_end_branch ? 1 : 0; i < n; ++i) {
      pose[i].setRotationUnchecked(G::exp(share[i] * step.rotation_fraction * step.rotation_error) *
                                   pose[i].rotation());
    }
    // The first end's new rotation was computed for the translation residual already.
    if (first_end_branch) pose[0].setRotationUnchecked(step.first_end_rotation);
  }
  // Then the translations, and each parameter from its node's and its parent's new poses; each new
  // pose is used twice (its own parameter, its child's), so it is kept from one step to the next.
  const double* share = translation_share.data();
  Pose child;  // the new pose of node i - 1
  for (std::size_t i = 0; i < n; ++i) {
    Pose moved = pose[i];
    if (step.translate) {
      moved.setTranslation(moved.translation() + (share[i] * step.translation_fraction) * step.residual);
    }
    if (i > 0) {
      // New parameter of node i - 1 = (new pose of its parent, node i)^-1 * (its new pose).
      Pose& parameter = parameters[nodes[i - 1]];
      const typename G::Rotation parent_inverse = moved.rotation().conjugate();
      parameter.setRotationUnchecked(parent_inverse * child.rotation());
      parameter.setTranslation(parent_inverse * (child.translation() - moved.translation()));
      parameter.renormalize();
    }
    child = moved;
  }
  Pose& parameter = parameters[nodes[n - 1]];
  parameter = child;  // its parent is the top node: the identity in its own frame
  parameter.renormalize();
}

void TreeOptimizer::distributeRotationNaively(std::size_t c, double learning_rate, double weight_sum) {
  // The update the paper warns against (Fig. 2): add equal shares of the roll/pitch/yaw error to
  // every parameter as if rotations commuted.  Kept for the benchmark and the test that shows it fails.
  detail::TreeGroupState<Spatial>& s = spatial_;
  const Quaternion& qa = up_.empty() ? Quaternion::Identity() : s.up_poses[0].rotation();
  const Quaternion& qb = down_.empty() ? Quaternion::Identity() : s.down_poses[0].rotation();
  const Vector3 current = Pose3(qa.conjugate() * qb, Vector3::Zero()).rollPitchYaw();
  const Vector3 wanted = s.measurements[c].rollPitchYaw();
  Vector3 error;
  for (int i = 0; i < 3; ++i) error[i] = toro::wrapAngle(wanted[i] - current[i]);
  const double info = constraint_rotation_info_[c];
  if (!(info > 0.0)) return;
  const double fraction = stepFraction(learning_rate, info, weight_sum);
  // Each joint's own share is the difference of consecutive cumulative shares.
  const auto adjust = [&](const std::vector<std::size_t>& branch, const std::vector<double>& share,
                          std::vector<Pose3>& poses, double sign) {
    Quaternion above = Quaternion::Identity();
    for (std::size_t i = branch.size(); i-- > 0;) {
      const double own = std::abs(share[i]) - (i + 1 < branch.size() ? std::abs(share[i + 1]) : 0.0);
      const Vector3 rpy = s.parameters[branch[i]].rollPitchYaw() + sign * own * fraction * error;
      const Quaternion q = Pose3::fromRollPitchYaw(0, 0, 0, rpy.x(), rpy.y(), rpy.z()).rotation();
      above = (above * q).normalized();
      poses[i].setRotationUnchecked(above);
    }
  };
  adjust(up_, up_rotation_share_, s.up_poses, -1.0);
  adjust(down_, down_rotation_share_, s.down_poses, 1.0);
}

}  // namespace toro
