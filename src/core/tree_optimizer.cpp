#include "toro_ros/core/tree_optimizer.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <stdexcept>

#include "toro_ros/core/metrics.h"
#include "toro_ros/core/planar.h"

namespace toro {

namespace {

// Inverse stiffness of a node no constraint passes through yet (capped per update anyway).
constexpr double kUnconstrained = 1e300;

// A weight that changed by less than this fraction keeps its old share of the preconditioner (a
// preconditioner only needs to be roughly right; updating it walks the constraint's path).
constexpr double kPreconditionerWeightTolerance = 0.1;

// chi2() re-sums its per-constraint record after this many partial updates (each adds the
// differences of the constraints it touched), so rounding in the running total stays ~1e-16 of it.
constexpr std::size_t kChi2ResumEvery = 64;

}  // namespace

const char* parameterizationName(Parameterization p) {
  switch (p) {
    case Parameterization::kFromGraph:
      return "from-graph";
    case Parameterization::kPlanar:
      return "planar";
    case Parameterization::kSpatial:
      return "3d";
  }
  return "unknown";
}

std::string TreeOptimizerOptions::validate() const {
  if (!(gamma > 0.0) || !std::isfinite(gamma)) return "gamma must be a positive finite number";
  if (!(translation_gamma > 0.0) || !std::isfinite(translation_gamma)) {
    return "translation_gamma must be a positive finite number";
  }
  if (!(weighted_chi2_set_aside >= 0.0 && weighted_chi2_set_aside < 1.0))
    return "weighted_chi2_set_aside must be in [0, 1)";
  return robust.validate();
}

TreeOptimizer::TreeOptimizer(const TreeOptimizerOptions& options) : options_(options) {
  const std::string error = options_.validate();
  if (!error.empty()) throw std::invalid_argument("TreeOptimizerOptions: " + error);
  translation_rate_factor_ = options_.gamma / options_.translation_gamma;
  planar_ = options_.parameterization == Parameterization::kPlanar;
  if (planar_) graph_.setDimension(GraphDimension::k2D);
}

void TreeOptimizer::resetGraph(const PoseGraph& graph) {
  planar_ =
      options_.parameterization == Parameterization::kPlanar ||
      (options_.parameterization == Parameterization::kFromGraph && graph.dimension() == GraphDimension::k2D);
  if (planar_) {
    graph_ = projectToPlane(graph);
  } else {
    graph_ = graph;
  }
}

void TreeOptimizer::setGraph(const PoseGraph& graph, InitialGuess guess) {
  chi2_valid_ = false;  // another graph: its record is computed when asked
  resetGraph(graph);
  tree_.build(graph_);
  const std::size_t n = graph_.numNodes();
  incident_.assign(n, {});
  from_index_.clear();
  to_index_.clear();
  base_rotation_info_.clear();
  base_translation_info_.clear();
  constraint_rotation_info_.clear();
  constraint_translation_info_.clear();
  robust_weight_.clear();
  weight_cap_.clear();
  outside_tree_.clear();
  arrival_chi2_.clear();
  preconditioned_weight_.clear();
  robust_.clear();
  measured_axes_index_.clear();
  odometry_with_unmeasured_axes_ = 0;
  clearParameters();
  for (std::size_t c = 0; c < graph_.numConstraints(); ++c) registerConstraint(c);
  rotation_weight_.assign(n, 0.0);
  translation_weight_.assign(n, 0.0);
  inverse_weight_.assign(n, InverseStiffness{kUnconstrained, kUnconstrained});
  affected_mark_.assign(graph_.numConstraints(), 0);
  top_level_.assign(graph_.numConstraints(), 0);  // per constraint, like the vectors above
  topological_order_ = tree_.topologicalOrder();
  topological_dirty_ = false;
  for (std::size_t v = 0; v < n; ++v) appendParameter(Pose3());
  if (guess == InitialGuess::kFromGraph) {
    parametersFromPoses();
  } else if (guess == InitialGuess::kChainOdometry) {
    chainOdometryGuess();
    parametersFromPoses();
  } else {
    chainInitialGuess();
  }
  recomputePoses();
  structure_dirty_ = true;
  refreshWeights();  // from the initial guess; the structure refresh then uses them
  new_constraints_.clear();
  covered_new_ = 0;
  iteration_ = 0;
}

void TreeOptimizer::registerConstraint(std::size_t c) {
  const Constraint& k = graph_.constraints()[c];
  from_index_.push_back(graph_.indexOf(k.from));
  to_index_.push_back(graph_.indexOf(k.to));
  incident_[from_index_.back()].push_back(c);
  incident_[to_index_.back()].push_back(c);
  robust_weight_.push_back(1.0);
  weight_cap_.push_back(1.0);
  outside_tree_.push_back(0);
  arrival_chi2_.push_back(-1.0);
  preconditioned_weight_.push_back(1.0);
  robust_.push_back(options_.robust.enabled() && isLoopClosure(k) ? 1 : 0);
  // Stiffness (base_*, constraint_*), the measurement and measured axes in the group.
  registerGroupConstraint(c);
}

void TreeOptimizer::setWeight(std::size_t c, double weight) {
  if (weight != robust_weight_[c]) {
    // The cached covariances of the tree edges c may lie beside (innovation_scratch_).
    innovation_scratch_.forget(from_index_[c]);
    innovation_scratch_.forget(to_index_[c]);
    changes_.constraint(c, graph_.numConstraints());
    if (chi2_valid_) weighted_chi2_total_ -= weightedShare(c, chi2_[c]);
    robust_weight_[c] = weight;
    if (chi2_valid_) weighted_chi2_total_ += weightedShare(c, chi2_[c]);
  }
  constraint_rotation_info_[c] = base_rotation_info_[c] * weight;
  constraint_translation_info_[c] = base_translation_info_[c] * weight;
}

void TreeOptimizer::adjustPreconditioner(std::size_t c, double rotation_delta, double translation_delta) {
  tree_.path(from_index_[c], to_index_[c], up_, down_);
  for (const auto* branch : {&up_, &down_}) {
    for (std::size_t v : *branch) {
      rotation_weight_[v] = std::max(0.0, rotation_weight_[v] + rotation_delta);
      translation_weight_[v] = std::max(0.0, translation_weight_[v] + translation_delta);
      inverse_weight_[v].rotation = rotation_weight_[v] > 0.0 ? 1.0 / rotation_weight_[v] : kUnconstrained;
      inverse_weight_[v].translation =
          translation_weight_[v] > 0.0 ? 1.0 / translation_weight_[v] : kUnconstrained;
    }
  }
}

void TreeOptimizer::setWeightCap(std::size_t c, double cap) {
  if (c >= weight_cap_.size()) throw std::out_of_range("TreeOptimizer::setWeightCap: no constraint " + std::to_string(c));
  weight_cap_[c] = std::clamp(cap, 0.0, 1.0);
  refreshWeights(std::vector<std::size_t>{c});
}

double TreeOptimizer::innovationWeight(std::size_t c, double* judged_chi2) {
  if (!(weight_cap_[c] > 0.0)) return 0.0;  // held by the caller: no need to walk its path
  return std::min(weight_cap_[c], kernelWeight(c, judged_chi2));
}

double TreeOptimizer::kernelWeight(std::size_t c, double* judged_chi2) {
  const double plain = toro::constraintChi2(graph_, c);
  if (!options_.robust_by_innovation) {
    *judged_chi2 = plain;
    return robustWeight(options_.robust, plain);
  }
  const double innovation = loopClosureInnovationChi2(*this, c, innovation_scratch_);
  *judged_chi2 = innovation;
  // The fraction f of its innovation the loop closure may move the map by: the kernel's weight,
  // squared (the kernel's weight alone would let a loop closure 30 widths off move the map by 0.4 %
  // of its error, 2.5 cm for a 6 m wrong one; squared, 2e-5).  In the linear model a weight w
  // moves it by w S / (Sigma_z + w S), S the path's covariance, and Sigma_z / S = innovation /
  // (plain - innovation): so w = f / (1 - f) * Sigma_z / S.  A plausible one (f = 1) keeps full
  // weight however long the loop it closes; an implausible one on a long, compliant path gets
  // far less than f, which alone would let it drag the path.
  const double kernel = robustWeight(options_.robust, innovation);
  const double f = kernel * kernel;
  if (!(f < 1.0)) return 1.0;
  const double excess = plain - innovation;
  if (!(excess > 0.0)) return f;  // a stiff path: the plain chi2 is the innovation
  return std::min(1.0, f / (1.0 - f) * innovation / excess);
}

std::size_t TreeOptimizer::refreshWeights(const std::vector<std::size_t>& constraints) {
  std::size_t changed = 0;
  // Poses and the tree stay as they are below; setWeight forgets what a changed weight touches.
  struct Batch {
    InnovationScratch& scratch;
    ~Batch() { scratch.endBatch(); }
  } batch{innovation_scratch_};
  if (constraints.size() > 1) innovation_scratch_.beginBatch(graph_.numNodes());
  for (std::size_t c : constraints) {
    if (!robust_[c]) continue;
    double judged = 0.0;
    const double weight = innovationWeight(c, &judged);
    setWeight(c, weight);  // the step uses the new weight at once
    // The preconditioner follows only noticeable changes (it walks the path).
    const double held = preconditioned_weight_[c];
    if (!(std::abs(weight - held) > kPreconditionerWeightTolerance * std::max(weight, held))) continue;
    ++changed;
    preconditioned_weight_[c] = weight;
    if (!structure_dirty_)
      adjustPreconditioner(c, base_rotation_info_[c] * (weight - held), base_translation_info_[c] * (weight - held));
  }
  return changed;
}

std::size_t TreeOptimizer::refreshWeights() {
  if (!options_.robust.enabled()) return 0;
  std::vector<std::size_t> all(graph_.numConstraints());
  for (std::size_t c = 0; c < all.size(); ++c) all[c] = c;
  return refreshWeights(all);
}

void TreeOptimizer::chainOdometryGuess() {
  const std::size_t n = graph_.numNodes();
  std::vector<char> placed(n, 0);
  std::vector<std::size_t> by_id(n);
  for (std::size_t v = 0; v < n; ++v) by_id[v] = v;
  std::sort(by_id.begin(), by_id.end(), [&](std::size_t a, std::size_t b) { return graph_.node(a).id < graph_.node(b).id; });
  std::deque<std::size_t> odometry_front;
  std::deque<std::size_t> loop_closures;  // constraint indices seen from placed nodes
  const auto place = [&](std::size_t v, const Pose3& pose) {
    placed[v] = 1;
    graph_.setPoseAt(v, pose);
    odometry_front.push_back(v);
  };
  // Pose of the other end of c seen from placed end v.
  const auto across = [&](std::size_t c, std::size_t v) {
    const Constraint& k = graph_.constraints()[c];
    return from_index_[c] == v ? graph_.node(v).pose * k.measurement : graph_.node(v).pose * k.measurement.inverse();
  };
  for (std::size_t root : by_id) {
    if (placed[root]) continue;
    place(root, graph_.node(root).pose);  // a component's smallest id keeps its pose (the gauge)
    while (!odometry_front.empty() || !loop_closures.empty()) {
      if (odometry_front.empty()) {
        const std::size_t c = loop_closures.front();
        loop_closures.pop_front();
        const std::size_t a = from_index_[c], b = to_index_[c];
        if (placed[a] && !placed[b]) place(b, across(c, a));
        if (placed[b] && !placed[a]) place(a, across(c, b));
        continue;
      }
      const std::size_t v = odometry_front.front();
      odometry_front.pop_front();
      for (std::size_t c : incident_[v]) {
        const std::size_t u = from_index_[c] == v ? to_index_[c] : from_index_[c];
        if (placed[u]) continue;
        if (isLoopClosure(graph_.constraints()[c])) {
          loop_closures.push_back(c);
        } else {
          place(u, across(c, v));
        }
      }
    }
  }
}

void TreeOptimizer::addToPreconditioner(std::size_t c) {
  top_level_[c] = tree_.level(tree_.path(from_index_[c], to_index_[c], up_, down_));
  preconditioned_weight_[c] = robust_weight_[c];
  for (const auto* branch : {&up_, &down_}) {
    for (std::size_t v : *branch) {
      rotation_weight_[v] += constraint_rotation_info_[c];
      translation_weight_[v] += constraint_translation_info_[c];
      inverse_weight_[v].rotation = rotation_weight_[v] > 0.0 ? 1.0 / rotation_weight_[v] : kUnconstrained;
      inverse_weight_[v].translation =
          translation_weight_[v] > 0.0 ? 1.0 / translation_weight_[v] : kUnconstrained;
    }
  }
}

void TreeOptimizer::refreshStructure() {
  std::fill(rotation_weight_.begin(), rotation_weight_.end(), 0.0);
  std::fill(translation_weight_.begin(), translation_weight_.end(), 0.0);
  std::fill(inverse_weight_.begin(), inverse_weight_.end(), InverseStiffness{kUnconstrained, kUnconstrained});
  top_level_.assign(graph_.numConstraints(), 0);
  order_.resize(graph_.numConstraints());
  for (std::size_t c = 0; c < graph_.numConstraints(); ++c) {
    addToPreconditioner(c);
    order_[c] = c;
  }
  // Root side first: updates near the root move large subtrees; later, deeper updates refine them.
  std::stable_sort(order_.begin(), order_.end(),
                   [&](std::size_t a, std::size_t b) { return top_level_[a] < top_level_[b]; });
  structure_dirty_ = false;
}

IterationStats TreeOptimizer::iterate() {
  if (structure_dirty_) refreshStructure();
  refreshWeights();
  ++iteration_;
  const double learning_rate = 1.0 / (options_.gamma * static_cast<double>(iteration_));
  runPass(order_, learning_rate);
  new_constraints_.clear();  // a full pass has covered them
  covered_new_ = 0;
  return IterationStats{iteration_, order_.size(), learning_rate};
}

void TreeOptimizer::applyUpdate(std::size_t constraint_index, double learning_rate) {
  if (constraint_index >= graph_.numConstraints()) {
    throw std::out_of_range("TreeOptimizer::applyUpdate: no constraint " + std::to_string(constraint_index));
  }
  if (structure_dirty_) refreshStructure();
  updateConstraint(constraint_index, learning_rate);
  recomputePoses();
}

void TreeOptimizer::addNode(NodeId id, const Pose3& pose) {
  graph_.addNode(id, planar_ ? projectToPlane(pose) : pose);
  const std::size_t v = graph_.numNodes() - 1;
  tree_.addNode(graph_, v);
  appendParameter(graph_.node(v).pose);
  incident_.emplace_back();
  rotation_weight_.push_back(0.0);
  translation_weight_.push_back(0.0);
  inverse_weight_.push_back(InverseStiffness{kUnconstrained, kUnconstrained});
  if (!topological_dirty_) topological_order_.push_back(v);
}

std::size_t TreeOptimizer::addConstraint(const Constraint& constraint, bool may_be_tree_edge) {
  const std::size_t c = graph_.addConstraint(planar_ ? projectToPlane(constraint) : constraint);
  registerConstraint(c);
  if (chi2_valid_) {
    // At weight 1 until the robust weight below replaces it (setWeight moves its share).
    chi2_.push_back(toro::constraintChi2(graph_, c));
    chi2_total_ += chi2_.back();
    weighted_chi2_total_ += weightedShare(c, chi2_.back());
  }
  // A new loop closure is weighted before any pass moves the map for it, against the tree as it
  // was before it arrived.
  if (robust_[c]) {
    setWeight(c, innovationWeight(c, &arrival_chi2_[c]));
  }
  std::vector<std::size_t> reparented;
  outside_tree_[c] = tree_.addConstraint(graph_, c, &reparented, may_be_tree_edge) ? 0 : 1;
  affected_mark_.push_back(0);
  top_level_.push_back(0);
  takeReparented(reparented);
  if (!structure_dirty_) {
    addToPreconditioner(c);
    const auto pos = std::upper_bound(order_.begin(), order_.end(), top_level_[c],
                                      [&](int level, std::size_t other) { return level < top_level_[other]; });
    order_.insert(pos, c);
  } else {
    // Keep the stiffness of the new path up to date until the next full refresh.
    addToPreconditioner(c);
  }
  new_constraints_.push_back(c);
  return c;
}

bool TreeOptimizer::takeReparented(const std::vector<std::size_t>& reparented) {
  bool tree_reshaped = false;
  for (std::size_t v : reparented) {
    parameterFromPoses(v);
    // A node attached by its very first constraint (a new keyframe) changes no other path; any
    // other re-parenting changes the paths (top nodes, stiffness) of constraints through it.
    if (!(reparented.size() == 1 && tree_.children(v).empty() && incident_[v].size() == 1)) tree_reshaped = true;
  }
  if (tree_reshaped) {
    topological_dirty_ = true;
    structure_dirty_ = true;
  }
  return tree_reshaped;
}

void TreeOptimizer::admitToTree(std::size_t c) {
  if (c >= outside_tree_.size()) throw std::out_of_range("TreeOptimizer::admitToTree: no constraint " + std::to_string(c));
  if (!outside_tree_[c]) return;
  outside_tree_[c] = 0;
  std::vector<std::size_t> reparented;
  tree_.addConstraint(graph_, c, &reparented, true);
  // Its path (top node, preconditioner share) is that of the new tree from the next refresh on.
  if (!reparented.empty()) structure_dirty_ = true;
  takeReparented(reparented);
}

std::vector<std::size_t> TreeOptimizer::sortedByTopLevel(std::vector<std::size_t> constraints) {
  for (std::size_t c : constraints) {
    top_level_[c] = tree_.level(tree_.topNode(from_index_[c], to_index_[c]));
  }
  std::stable_sort(constraints.begin(), constraints.end(),
                   [&](std::size_t a, std::size_t b) { return top_level_[a] < top_level_[b]; });
  return constraints;
}

IterationStats TreeOptimizer::iterateAffected(std::size_t learning_rate_iteration, std::size_t settled) {
  if (learning_rate_iteration <= 1) {
    new_constraints_.erase(new_constraints_.begin(),
                           new_constraints_.begin() + static_cast<std::ptrdiff_t>(covered_new_));
  }
  covered_new_ = new_constraints_.size();
  std::vector<std::size_t> affected;
  const auto mark = [&](std::size_t c) {
    if (!affected_mark_[c]) {
      affected_mark_[c] = 1;
      affected.push_back(c);
    }
  };
  for (std::size_t c : new_constraints_) {
    mark(c);
    tree_.path(from_index_[c], to_index_[c], up_, down_);
    for (const auto* branch : {&up_, &down_}) {
      for (std::size_t v : *branch) {
        for (std::size_t other : incident_[v])
          if (other >= settled) mark(other);
      }
    }
  }
  for (std::size_t c : affected) affected_mark_[c] = 0;
  if (options_.robust.enabled()) refreshWeights(affected);
  affected = sortedByTopLevel(std::move(affected));
  const double learning_rate =
      1.0 / (options_.gamma * static_cast<double>(std::max<std::size_t>(1, learning_rate_iteration)));
  runPass(affected, learning_rate, /*partial=*/true);
  return IterationStats{learning_rate_iteration, affected.size(), learning_rate};
}

void TreeOptimizer::clearAffected() {
  new_constraints_.clear();
  covered_new_ = 0;
}

void TreeOptimizer::afterPosesMoved(const std::vector<std::size_t>& moved) {
  const std::size_t n = graph_.numNodes(), m = graph_.numConstraints();
  if (constraint_mark_.size() < m) constraint_mark_.resize(m, 0);
  touched_constraints_.clear();
  // A constraint whose ends moved with one region (moved_mark_ 2: walked) kept its relative pose,
  // so its chi2 (up to rounding); only those between regions, or to a node that did not move, are
  // evaluated again.  That is the path nodes' constraints, not every moved node's.
  for (std::size_t v : moved) {
    changes_.node(v, n);
    for (std::size_t c : incident_[v]) {
      if (constraint_mark_[c]) continue;
      const std::size_t other = from_index_[c] == v ? to_index_[c] : from_index_[c];
      if (moved_mark_[other] == 2 && region_[other] == region_[v]) continue;
      constraint_mark_[c] = 1;
      touched_constraints_.push_back(c);
    }
  }
  for (std::size_t c : touched_constraints_) {
    constraint_mark_[c] = 0;
    changes_.constraint(c, m);
    if (!chi2_valid_) continue;
    const double x = toro::constraintChi2(graph_, c);
    chi2_total_ += x - chi2_[c];
    weighted_chi2_total_ += weightedShare(c, x) - weightedShare(c, chi2_[c]);
    chi2_[c] = x;
  }
  if (chi2_valid_ && ++chi2_updates_ >= kChi2ResumEvery) sumChi2();
}

void TreeOptimizer::sumChi2() {
  // In constraint order, as toro::g2oChi2 sums: after a full recompute the two agree exactly.
  double sum = 0.0, weighted = 0.0;
  for (std::size_t c = 0; c < chi2_.size(); ++c) {
    sum += chi2_[c];
    weighted += weightedShare(c, chi2_[c]);
  }
  chi2_total_ = sum;
  weighted_chi2_total_ = weighted;
  chi2_updates_ = 0;
}

double TreeOptimizer::chi2() {
  if (!chi2_valid_) {
    chi2_.resize(graph_.numConstraints());
    for (std::size_t c = 0; c < chi2_.size(); ++c) chi2_[c] = toro::constraintChi2(graph_, c);
    chi2_valid_ = true;
    sumChi2();
  }
  return chi2_total_;
}

double TreeOptimizer::weightedChi2() {
  chi2();
  return weighted_chi2_total_;
}

double TreeOptimizer::constraintChi2(std::size_t c) {
  if (c >= graph_.numConstraints()) {
    throw std::out_of_range("TreeOptimizer::constraintChi2: no constraint " + std::to_string(c));
  }
  chi2();
  return chi2_[c];
}

void TreeOptimizer::markAffected(std::size_t c) {
  if (c >= graph_.numConstraints())
    throw std::out_of_range("TreeOptimizer::markAffected: no constraint " + std::to_string(c));
  new_constraints_.push_back(c);  // iterateAffected visits each affected constraint once
}

}  // namespace toro
