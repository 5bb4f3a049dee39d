// TORO 3D: stochastic gradient descent on a tree parameterisation of the pose graph
// (Grisetti, Grzonka, Stachniss, Pfaff, Burgard, IROS 2007).
//
// Each node's parameter is its pose relative to its tree parent; a node's pose is the product of
// the parameters along the tree path from the root.  One iteration visits every constraint once,
// ordered by the level of its top node; each visit moves only the parameters on the constraint's
// tree path, so the top node (and everything outside the path's subtrees) keeps its pose.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "toro_ros/core/loop_closure_innovation.h"
#include "toro_ros/core/parameter_tree.h"
#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/robust_kernel.h"

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

struct TreeOptimizerOptions {
  // Learning rate of iteration k is 1 / (gamma * k) for the rotational part of each update...
  double gamma = 1.0;
  // ...and 1 / (translation_gamma * k) for the translational part.  Translation gets the larger
  // rate because every rotational update re-creates translational error downstream (lever arms),
  // which a rate decaying as fast as the rotational one cannot keep up with; 0.1 was chosen by
  // measurement on sphere2500, parking-garage, smallGrid3D and sphere_bignoise (bench/results.md).
  double translation_gamma = 0.1;
  RotationUpdate rotation_update = RotationUpdate::kSlerp;
  // Robust loop closures (robust_kernel.h): each loop closure's information, in its step and in the
  // preconditioner, is scaled by a weight from its chi2 at the start of the pass that visits it
  // (a new one's at its arrival), so a wrong one moves the map by a weighted fraction only.
  // Odometry (isLoopClosure() false) keeps weight 1.  Off (kNone) by default.
  RobustOptions robust;
  // The chi2 the robust weights come from: the loop closure's leave-one-out innovation against its
  // tree path (loop_closure_innovation.h: a right loop closure closing a long loop is judged
  // against the drift the path allows) or, false, its plain chi2 e^T Omega e.
  bool robust_by_innovation = true;
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
  // preconditioner.  Resets the iteration counter.
  void setGraph(const PoseGraph& graph, InitialGuess guess = InitialGuess::kChainOnTree);

  // Online growth.  A new node needs an initial pose (e.g. its parent's pose times the odometry);
  // ids of new nodes should increase (older ids work but trigger a tree rebuild).
  void addNode(NodeId id, const Pose3& pose);
  // Validated like PoseGraph::addConstraint (throws GraphError); returns the constraint's index.
  std::size_t addConstraint(const Constraint& constraint);

  // One full pass over all constraints; the learning rate decays with the iteration counter.
  // Afterwards no constraint counts as new for iterateAffected().
  IterationStats iterate();
  // One pass over the constraints affected by what was added since the last full pass (the new
  // constraints and every constraint touching a node on their tree paths), with the learning rate
  // of the given iteration index.  Does not advance the iteration counter; call it repeatedly with
  // growing indices to settle a new loop closure.
  IterationStats iterateAffected(std::size_t learning_rate_iteration = 1);
  // One update of one constraint with the given learning rate (the building block of the passes
  // above), followed by a refresh of all poses.  For tests and custom schedules.
  void applyUpdate(std::size_t constraint_index, double learning_rate);
  // Forgets what counts as "new" for iterateAffected() without a full pass.
  void clearAffected();

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
  // Changes the robust kernel's width (graduated robustness: a wide kernel first, narrowed over
  // iterations); takes effect at the next weight refresh.
  void setRobustWidth(double width) { options_.robust.width = width; }

  // The graph with the current pose estimates.
  const PoseGraph& graph() const { return graph_; }
  const ParameterTree& tree() const { return tree_; }
  std::size_t iteration() const { return iteration_; }
  const TreeOptimizerOptions& options() const { return options_; }
  void setIteration(std::size_t iteration) { iteration_ = iteration; }

 private:
  void chainInitialGuess();
  void chainOdometryGuess();
  void parametersFromPoses();
  void updateConstraint(std::size_t c, double learning_rate);
  void distributeRotation(std::size_t c, double learning_rate);
  void distributeRotationNaively(std::size_t c, double learning_rate);
  void distributeTranslation(std::size_t c, double learning_rate);
  void writeBackParameters();
  void recomputePoses();
  // Preconditioner and visiting order, both from one walk over every constraint's path.
  void refreshStructure();
  void addToPreconditioner(std::size_t c);
  void registerConstraint(std::size_t c);
  std::vector<std::size_t> sortedByTopLevel(std::vector<std::size_t> constraints);
  void runPass(const std::vector<std::size_t>& constraints, double learning_rate);
  // Robust weights of the given constraints from the current poses; the preconditioner follows
  // (incrementally) when a weight changed by more than a tolerance.  Returns how many changed.
  std::size_t refreshWeights(const std::vector<std::size_t>& constraints);
  void setWeight(std::size_t c, double weight);
  // A robust constraint's weight (options_.robust_by_innovation: from its innovation, see the
  // .cpp), and in `judged_chi2` the chi2 the kernel was applied to.
  double innovationWeight(std::size_t c, double* judged_chi2);
  void adjustPreconditioner(std::size_t c, double rotation_delta, double translation_delta);

  TreeOptimizerOptions options_;
  PoseGraph graph_;
  ParameterTree tree_;
  std::vector<Pose3> parameters_;        // parent_T_node per dense node index (root: world_T_root)
  std::vector<double> rotation_weight_;  // preconditioner per node: sum of rotational information
  std::vector<double> translation_weight_;
  std::vector<double> inverse_rotation_weight_;      // 1 / rotation_weight_, kept beside it
  std::vector<double> inverse_translation_weight_;
  std::vector<std::size_t> from_index_, to_index_;  // dense endpoints per constraint
  // Scalar information per constraint (block_stiffness.h): base_* as the information gives it,
  // constraint_* = base * robust weight, used by the steps and the preconditioner.
  std::vector<double> base_rotation_info_, base_translation_info_;
  std::vector<double> constraint_rotation_info_;
  std::vector<double> constraint_translation_info_;
  std::vector<double> robust_weight_;  // per constraint, 1 unless robust_
  std::vector<double> arrival_chi2_;   // per constraint, see arrivalChi2()
  std::vector<double> preconditioned_weight_;  // the weight whose share the preconditioner holds
  std::vector<char> robust_;           // per constraint: a loop closure weighted robustly
  // Constraints with unmeasured axes move only along their measured ones: projectors in the frame
  // of the constraint (its "to" end), kept only for them (index into measured_axes_, or -1).
  struct MeasuredAxes {
    Matrix3 translation = Matrix3::Identity();
    Matrix3 rotation = Matrix3::Identity();
    bool translation_partial = false;
    bool rotation_partial = false;
  };
  std::vector<int> measured_axes_index_;
  std::vector<MeasuredAxes> measured_axes_;
  std::vector<std::size_t> order_;       // constraints sorted by top-node level
  std::vector<int> top_level_;           // level of each constraint's top node (refreshStructure)
  bool structure_dirty_ = true;          // tree changed since refreshStructure()
  std::vector<std::size_t> topological_order_;
  std::vector<std::size_t> new_constraints_;
  std::vector<std::vector<std::size_t>> incident_;  // constraints per node
  std::size_t iteration_ = 0;
  double translation_rate_factor_ = 1.0;  // gamma / translation_gamma
  // Scratch buffers reused by updateConstraint (no allocation in the hot loop).
  std::vector<std::size_t> up_, down_;
  std::size_t top_ = 0;
  std::vector<Pose3> up_poses_, down_poses_;          // top_T_node for the path nodes
  std::vector<double> up_share_, down_share_;         // signed fraction of the correction per node
  std::vector<char> affected_mark_;
  InnovationScratch innovation_scratch_;
};

}  // namespace toro
