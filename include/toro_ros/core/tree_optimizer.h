// TORO: stochastic gradient descent on a tree parameterisation of the pose graph, in 3D
// (Grisetti, Grzonka, Stachniss, Pfaff, Burgard, IROS 2007) or in the plane (Grisetti, Stachniss,
// Grzonka, Burgard, RSS 2007).
//
// Each node's parameter is its pose relative to its tree parent; a node's pose is the product of
// the parameters along the tree path from the root.  One iteration visits every constraint once,
// ordered by the level of its top node; each visit moves only the parameters on the constraint's
// tree path, so the top node (and everything outside the path's subtrees) keeps its pose.
//
// The group is chosen once (TreeOptimizerOptions::parameterization): SE(3) parameters with
// rotation-vector errors, or SE(2) parameters (x, y, theta) whose rotation shares simply add.  The
// tree, the step fractions, the preconditioner, the schedule and the robust weights are the same
// code for both; only the update of one path is a template over the group (tree_groups.h).  On a
// planar graph the two give the same poses up to rounding, SE(2) several times faster.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "toro_ros/core/change_journal.h"
#include "toro_ros/core/loop_closure_innovation.h"
#include "toro_ros/core/parameter_tree.h"
#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/robust_kernel.h"
#include "toro_ros/core/tree_groups.h"

namespace toro {

enum class InitialGuess {
  kChainOnTree,  // compose the measurements along the tree from the root (the paper's tools)
  kFromGraph,    // keep the poses stored in the graph
  // Compose odometry (constraints that are not loop closures, isLoopClosure) outward from each
  // component's smallest id, and loop closures only to reach what odometry does not: a wrong loop
  // closure that is a tree edge would otherwise place a whole subtree by its wrong measurement.
  // The start for robust estimation.
  kChainOdometry,
};

enum class RotationUpdate {
  kSlerp,       // the paper's update: slerp with the exact incremental decomposition (Eq. 19)
  kNaiveEuler,  // spread equal shares of roll/pitch/yaw error, ignoring non-commutativity
                // (bench/test only: it shows why the paper's update is needed, Fig. 2)
};

// The group of the parameters.
enum class Parameterization {
  // SE(2) for a 2D graph (GraphDimension::k2D), SE(3) otherwise, decided by each setGraph (an
  // optimiser that only grows by addNode/addConstraint from the start is SE(3)).
  kFromGraph,
  // SE(2): the optimiser's graph is 2D (k2D), and every pose and constraint given to it is
  // projected onto the plane first (planar.h: z, roll and pitch dropped, the x, y, yaw block of
  // the information kept), so its poses are exactly planar (z = 0, roll = pitch = 0).
  kPlanar,
  // SE(3), whatever the graph (also a 2D one: the comparison of the two codes).
  kSpatial,
};
const char* parameterizationName(Parameterization p);

struct TreeOptimizerOptions {
  // Learning rate of iteration k is 1 / (gamma * k) for the rotational part of each update...
  double gamma = 1.0;
  // ...and 1 / (translation_gamma * k) for the translational part.  Translation gets the larger
  // rate because every rotational update re-creates translational error downstream (lever arms),
  // which a rate decaying as fast as the rotational one cannot keep up with; 0.1 was chosen by
  // measurement on sphere2500, parking-garage, smallGrid3D and sphere_bignoise (bench/results.md).
  double translation_gamma = 0.1;
  // kNaiveEuler applies to SE(3) only: planar rotations commute, so in SE(2) both are the same.
  RotationUpdate rotation_update = RotationUpdate::kSlerp;
  Parameterization parameterization = Parameterization::kFromGraph;
  // Robust loop closures (robust_kernel.h): each loop closure's information, in its step and in the
  // preconditioner, is scaled by a weight from its chi2 at the start of the pass that visits it
  // (a new one's at its arrival), so a wrong one moves the map by a weighted fraction only.
  // Odometry (isLoopClosure() false) keeps weight 1.  Off (kNone) by default.
  RobustOptions robust;
  // The chi2 the robust weights come from: the loop closure's leave-one-out innovation against its
  // tree path (loop_closure_innovation.h: a right loop closure closing a long loop is judged
  // against the drift the path allows) or, false, its plain chi2 e^T Omega e.
  bool robust_by_innovation = true;
  // weightedChi2() leaves out constraints weighted below this (in [0, 1)): the pipeline sets it to
  // the sparse finish's set-aside weight, so it reports the cost the finish minimises.
  double weighted_chi2_set_aside = 1e-3;
  // Constraints are visited in increasing level of their top node (root side first).
  // Returns an empty string when valid, else what is wrong.
  std::string validate() const;
};

struct IterationStats {
  std::size_t iteration = 0;      // 1-based index of the iteration just run
  std::size_t constraints = 0;    // constraints visited
  double learning_rate = 0.0;
};

class TreeOptimizer {
 public:
  explicit TreeOptimizer(const TreeOptimizerOptions& options = {});

  // Takes the graph (nodes, constraints, poses), builds the tree, the initial parameters and the
  // preconditioner.  Resets the iteration counter.  Chooses the group (Parameterization); in SE(2)
  // the optimiser's graph is the projection of `graph` onto the plane (planar.h).
  void setGraph(const PoseGraph& graph, InitialGuess guess = InitialGuess::kChainOnTree);

  // Online growth.  A new node needs an initial pose (e.g. its parent's pose times the odometry);
  // ids of new nodes should increase (older ids work but trigger a tree rebuild).  In SE(2) the
  // pose and the constraint are projected onto the plane first.
  void addNode(NodeId id, const Pose3& pose);
  // Validated like PoseGraph::addConstraint (throws GraphError); returns the constraint's index.
  // With may_be_tree_edge false it does not shape the tree (nobody's parent link; see
  // ParameterTree) until admitToTree: for a loop closure held out of the map (weight 0), whose
  // tree edge would leave the paths through it without information.
  std::size_t addConstraint(const Constraint& constraint, bool may_be_tree_edge = true);
  void admitToTree(std::size_t c);

  // One full pass over all constraints; the learning rate decays with the iteration counter.
  // Afterwards no constraint counts as new for iterateAffected().
  IterationStats iterate();
  // One pass over the constraints affected by what was added (the new constraints and every
  // constraint touching a node on their tree paths), with the learning rate of the given iteration
  // index.  Does not advance the iteration counter; call it repeatedly with growing indices to
  // settle a new loop closure.  "Added" counts from the last full pass, clearAffected(), or the
  // previous settling: a call with index 1 starts a new settling and leaves out the constraints
  // the calls before it covered (they had their passes; those at the new paths are visited again
  // as touching them).  So a pass costs what the new constraints reach, not what was added since
  // the last full pass: without full passes that would become the whole graph.  Only the subtrees
  // of the nodes it changed are recomputed.
  // Constraints with an index below `settled` enter only as new (or marked) ones, not for touching
  // a path: for a map at the optimum of its first `settled` constraints (a sparse finish merged),
  // whose residuals are that optimum's balance rather than errors to correct.  A pass at learning
  // rate 1 over them trades the balance for each one's own residual (sphere2500 replayed with a
  // finish every second: one loop closure's pass raised chi2 from 318 to 1763, where passes that
  // leave the settled ones alone stay within 1 to 4 % of the finished chi2); what the new
  // constraints move, the next finish settles.  0: every constraint that touches a path.
  IterationStats iterateAffected(std::size_t learning_rate_iteration = 1, std::size_t settled = 0);
  // One update of one constraint with the given learning rate (the building block of the passes
  // above), followed by a refresh of all poses.  For tests and custom schedules.
  void applyUpdate(std::size_t constraint_index, double learning_rate);
  // Forgets what counts as "new" for iterateAffected() without a full pass.
  void clearAffected();
  // Makes constraint c count as new for the next iterateAffected(), as if it had just been added
  // (its path and the constraints touching it are visited).
  void markAffected(std::size_t c);
  // Replaces every pose (by dense node index; projected onto the plane when planar()) and derives
  // the parameters from them, keeping the tree, the weights, the preconditioner and the affected
  // set: a solution found elsewhere (the sparse finish) taken over without a rebuild.
  void setPoses(const std::vector<Pose3>& poses);
  // setPoses for a solution of an earlier state of the graph (a background finish): node v <
  // solution.numNodes() takes solution.node(v)'s pose, the nodes added since keep their pose
  // relative to their tree parent, so they move with it.  The same poses and parameters, to the
  // bit, as setPoses given those poses, without the array of every pose and the breadth-first
  // order a caller needs to build them (at 100,000 keyframes 3.1 ms instead of 4.3 ms, median of
  // 25 merges in bench_pipeline_step, timed by a temporary trace: bench/node_results.md).
  void takeSolution(const PoseGraph& solution);

  // Constraint indices at a node, and a constraint's dense endpoints (for path computations).
  const std::vector<std::size_t>& incident(std::size_t node) const { return incident_[node]; }
  std::size_t fromIndex(std::size_t c) const { return from_index_[c]; }
  std::size_t toIndex(std::size_t c) const { return to_index_[c]; }

  // Robust weight of each constraint (1 for odometry and when robust estimation is off), as used by
  // the last pass that visited it (or at its arrival), by constraint index.
  const std::vector<double>& weights() const { return robust_weight_; }
  // The chi2 each robust loop closure was weighted by when it arrived (addConstraint; -1 for the
  // others and for constraints given to setGraph), by constraint index.
  const std::vector<double>& arrivalChi2() const { return arrival_chi2_; }
  // Whether constraint c is weighted robustly (a loop closure with options().robust enabled).
  bool isRobust(std::size_t c) const { return robust_[c] != 0; }
  // Recomputes the robust weights of all loop closures from the current poses (a full pass does
  // this itself first); returns how many changed noticeably.
  std::size_t refreshWeights();
  // The same for the given constraints only (non-robust ones are skipped); the preconditioner
  // follows (incrementally) when a weight changed by more than a tolerance.
  std::size_t refreshWeights(const std::vector<std::size_t>& constraints);
  // Changes the robust kernel's width (graduated robustness: a wide kernel first, narrowed over
  // iterations); takes effect at the next weight refresh.
  void setRobustWidth(double width) { options_.robust.width = width; }
  // An upper bound on robust loop closure c's weight, in [0, 1] (1 unless set): the weight is the
  // kernel's, but never above the cap.  The caller's judgement on top of the residual's (the
  // pipeline holds a loop closure at 0 until another one agrees with it).  The weight and the
  // preconditioner follow at once.  No effect on constraints that are not robust.
  void setWeightCap(std::size_t c, double cap);
  double weightCap(std::size_t c) const { return weight_cap_[c]; }

  // The g2o chi2 of graph() (toro::g2oChi2, equal up to rounding) and of one constraint
  // (toro::constraintChi2).  Kept per constraint: an affected pass updates the constraints at the
  // nodes it moved, so after one the cost is proportional to what moved, not to the graph; after a
  // full pass, setGraph, setPoses or applyUpdate (every pose may have moved) the first call
  // computes all of them.  Non-const: they fill that record.
  double chi2();
  double constraintChi2(std::size_t c);
  // The chi2 with each constraint's information scaled by its robust weight (odometry: 1), those
  // weighted below options().weighted_chi2_set_aside left out.  Kept like chi2(), and a weight
  // change (setWeightCap, a refresh) updates it by that constraint's share alone.
  double weightedChi2();
  // What changed since the last call (change_journal.h): nodes whose pose changed, constraints
  // whose chi2 or robust weight changed, or everything (setGraph, setPoses, a full pass,
  // applyUpdate, a copy or move of the optimiser).  Nodes and constraints added since are not listed: the consumer
  // sees them by the graph's size.
  OptimizerChanges takeChanges() { return changes_.take(); }

  // The graph with the current pose estimates (2D, exactly planar, when planar()).
  const PoseGraph& graph() const { return graph_; }
  // Odometry constraints (isLoopClosure false) with an axis whose information is negligible
  // (kUnmeasuredInformationRatio): the passes move them along their measured axes only.  The
  // odometry chain, every axis measured, determines every pose relative to the root, so the exact
  // optimum is determined whatever axes the loop closures leave free; an odometry step with a free
  // axis leaves it free for everything after the step unless loop closures happen to measure it.
  std::size_t odometryConstraintsWithUnmeasuredAxes() const { return odometry_with_unmeasured_axes_; }
  // Whether the parameters are SE(2) (see Parameterization).
  bool planar() const { return planar_; }
  const ParameterTree& tree() const { return tree_; }
  std::size_t iteration() const { return iteration_; }
  const TreeOptimizerOptions& options() const { return options_; }
  void setIteration(std::size_t iteration) { iteration_ = iteration; }

 private:
  using Spatial = detail::SpatialGroup;
  using Planar = detail::PlanarGroup;

  void resetGraph(const PoseGraph& graph);
  void chainOdometryGuess();
  // Per-constraint data: endpoints, stiffness, robust flags; the group's part through
  // registerGroupConstraint.
  void registerConstraint(std::size_t c);
  void setWeight(std::size_t c, double weight);
  // Parameters of re-parented nodes from their poses; the structure is marked dirty when other
  // paths changed.  True when it was.
  bool takeReparented(const std::vector<std::size_t>& reparented);
  void adjustPreconditioner(std::size_t c, double rotation_delta, double translation_delta);
  // Preconditioner and visiting order, both from one walk over every constraint's path.
  void refreshStructure();
  void addToPreconditioner(std::size_t c);
  std::vector<std::size_t> sortedByTopLevel(std::vector<std::size_t> constraints);
  // A robust constraint's weight (options_.robust_by_innovation: from its innovation, see the
  // .cpp), and in `judged_chi2` the chi2 the kernel was applied to.
  double innovationWeight(std::size_t c, double* judged_chi2);  // the kernel's, capped (weight_cap_)
  double kernelWeight(std::size_t c, double* judged_chi2);

  // Group dispatchers (tree_optimizer_update.cpp): each calls the template for the chosen group.
  void clearParameters();
  void registerGroupConstraint(std::size_t c);
  void appendParameter(const Pose3& pose);
  void parameterFromPoses(std::size_t v);
  void chainInitialGuess();
  void parametersFromPoses();
  void recomputePoses();
  // partial: recompute only the subtrees of the nodes the pass changed (iterateAffected), and
  // keep chi2 and the journal from them; else every pose (a full pass).
  void runPass(const std::vector<std::size_t>& constraints, double learning_rate, bool partial = false);
  // A node whose parameter the running partial pass changed.
  void recordMoved(std::size_t v) {
    if (!moved_mark_[v]) {
      moved_mark_[v] = 1;
      moved_roots_.push_back(v);
    }
  }
  // After a partial recompute: the moved nodes and their constraints go into the journal and the
  // chi2 record.
  void afterPosesMoved(const std::vector<std::size_t>& moved);
  void sumChi2();
  // Constraint c's part of weightedChi2() at the given plain chi2 and its current weight.
  double weightedShare(std::size_t c, double chi2) const {
    const double w = robust_weight_[c];
    return w < options_.weighted_chi2_set_aside ? 0.0 : w * chi2;
  }
  void updateConstraint(std::size_t c, double learning_rate);

  template <class G>
  detail::TreeGroupState<G>& state() {
    if constexpr (G::kPlanar) {
      return planar_state_;
    } else {
      return spatial_;
    }
  }
  template <class G>
  void registerGroupConstraintIn(std::size_t c);
  template <class G>
  void parameterFromPosesIn(std::size_t v);
  template <class G>
  void chainInitialGuessIn();
  template <class G>
  void recomputePosesIn();
  // setPoses and takeSolution: node v's pose pose_at(v), projected (planar) and normalised, then the
  // parameters derived and the poses recomposed from them.
  template <class PoseAt>
  void placePoses(PoseAt pose_at);
  template <class G>
  void recomputePoseIn(std::size_t v);
  // The subtrees of moved_roots_ (each node once, parents first), then afterPosesMoved.
  template <class G>
  void recomputeMovedPosesIn();
  template <class G>
  void runPassIn(const std::vector<std::size_t>& constraints, double learning_rate, bool partial);
  template <class G>
  void updateConstraintIn(std::size_t c, double learning_rate);
  // What one visit moves its path by: the rotation error and the translation residual in the top
  // node's frame, each with the fraction of it that is removed (0 when its information is 0).
  template <class G>
  struct PathStep {
    typename G::Tangent rotation_error{};
    double rotation_fraction = 0.0;
    bool rotate = false;
    typename G::Rotation first_end_rotation = G::Rotation::Identity();  // after the step, if rotate
    typename G::Translation residual = G::Translation::Zero();
    double translation_fraction = 0.0;
    bool translate = false;
  };
  template <class G>
  void rotationStep(std::size_t c, double learning_rate, double weight_sum, PathStep<G>* step);
  template <class G>
  void translationStep(std::size_t c, double learning_rate, double weight_sum, PathStep<G>* step);
  template <class G>
  void updateParentEdge(std::size_t c, double learning_rate, bool first_end_is_child);
  template <class G>
  void composeFromTop(const std::vector<std::size_t>& branch, std::vector<typename G::Pose>& poses);
  // first_end_branch: `branch` is the one of the constraint's first end (step.first_end_rotation).
  template <class G>
  void moveAndWriteBack(const std::vector<std::size_t>& branch, const std::vector<double>& rotation_share,
                        const std::vector<double>& translation_share, const PathStep<G>& step,
                        bool first_end_branch, std::vector<typename G::Pose>& poses);
  // The shares of the path were computed by the caller; weight_sum is their total.
  void distributeRotationNaively(std::size_t c, double learning_rate, double weight_sum);  // SE(3) only

  TreeOptimizerOptions options_;
  bool planar_ = false;  // SE(2) parameters (Parameterization)
  PoseGraph graph_;
  ParameterTree tree_;
  // Parameters, measurements and per-update scratch of the group in use (the other one is empty).
  detail::TreeGroupState<Spatial> spatial_;
  detail::TreeGroupState<Planar> planar_state_;
  std::vector<double> rotation_weight_;  // preconditioner per node: sum of rotational information
  std::vector<double> translation_weight_;
  // 1 / rotation_weight_ and 1 / translation_weight_, kept beside them; side by side per node,
  // because every update reads both for each path node.
  struct InverseStiffness {
    double rotation;
    double translation;
  };
  std::vector<InverseStiffness> inverse_weight_;
  std::vector<std::size_t> from_index_, to_index_;  // dense endpoints per constraint
  // Scalar information per constraint (block_stiffness.h): base_* as the information gives it,
  // constraint_* = base * robust weight, used by the steps and the preconditioner.
  std::vector<double> base_rotation_info_, base_translation_info_;
  std::vector<double> constraint_rotation_info_;
  std::vector<double> constraint_translation_info_;
  std::vector<double> robust_weight_;  // per constraint, 1 unless robust_
  std::vector<double> weight_cap_;     // per constraint, the caller's bound on robust_weight_
  std::vector<char> outside_tree_;     // per constraint: kept out of the tree's shape (admitToTree)
  std::vector<double> arrival_chi2_;   // per constraint, see arrivalChi2()
  std::vector<double> preconditioned_weight_;  // the weight whose share the preconditioner holds
  std::vector<char> robust_;           // per constraint: a loop closure weighted robustly
  // Constraints with unmeasured axes move only along their measured ones: the projectors live in
  // the group state (measured_axes), indexed from here (-1: every axis measured).
  std::vector<int> measured_axes_index_;
  std::size_t odometry_with_unmeasured_axes_ = 0;  // see odometryConstraintsWithUnmeasuredAxes
  std::vector<std::size_t> order_;       // constraints sorted by top-node level
  std::vector<int> top_level_;           // level of each constraint's top node (refreshStructure)
  bool structure_dirty_ = true;          // tree changed since refreshStructure()
  std::vector<std::size_t> topological_order_;
  // The tree was re-shaped (a loop closure re-parented a node) since topological_order_ was made:
  // it is remade when a full recompute needs it, not at every loop closure (it is O(nodes)).
  bool topological_dirty_ = false;
  // takeSolution's nodes added since the solution, parents first, and their poses (by index minus
  // the solution's node count).  Members, so merges reuse them instead of allocating.
  std::vector<std::size_t> newer_order_;
  std::vector<Pose3> newer_poses_;
  std::vector<std::size_t> new_constraints_;
  std::size_t covered_new_ = 0;  // new_constraints_[0, covered_new_) had an affected pass
  std::vector<std::vector<std::size_t>> incident_;  // constraints per node
  std::size_t iteration_ = 0;
  double translation_rate_factor_ = 1.0;  // gamma / translation_gamma
  // Scratch buffers reused by updateConstraint (no allocation in the hot loop).
  std::vector<std::size_t> up_, down_;
  // Signed fraction of the correction per path node, rotational and translational.
  std::vector<double> up_rotation_share_, down_rotation_share_;
  std::vector<double> up_translation_share_, down_translation_share_;
  std::vector<char> affected_mark_;
  InnovationScratch innovation_scratch_;
  // Partial passes: the nodes whose parameters changed (moved_mark_ 1) and, during the subtree
  // walk, the nodes recomputed (2); scratch, empty between passes.
  bool record_moved_ = false;
  std::vector<std::size_t> moved_roots_, moved_, subtree_stack_, touched_constraints_;
  std::vector<char> moved_mark_, constraint_mark_;
  // During the walk: the changed node whose subtree gave each walked node its new pose.  Nodes of
  // one region moved rigidly together, so only constraints between regions change their chi2.
  std::vector<std::size_t> region_;
  // g2o chi2 per constraint and their sums (chi2(), weightedChi2()); chi2_valid_ false: to be
  // computed in full.  The sums are updated by differences and re-summed every kChi2ResumEvery
  // partial updates, so rounding cannot drift far from the exact sums.
  std::vector<double> chi2_;
  double chi2_total_ = 0.0;
  double weighted_chi2_total_ = 0.0;
  bool chi2_valid_ = false;
  std::size_t chi2_updates_ = 0;
  ChangeJournal changes_;
};

}  // namespace toro
