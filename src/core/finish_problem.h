// Internal: the least-squares problem of the sparse finish for one model (SE(3) or planar).
// Holds the states, the per-constraint data and the normal equations, whose sparsity pattern is
// built once; linearize() writes J^T Omega J straight into the matrix's value array through
// offsets precomputed per constraint, so no iteration allocates or searches.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <memory>
#include <stdexcept>
#include <vector>

#include "sparse_cholesky.h"
#include "toro_ros/core/finish_residuals.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/robust_kernel.h"

namespace toro {
namespace detail {

// The 3D problem: states are poses, residuals the g2o SE(3) error.
struct ModelSE3 {
  static constexpr int kDim = 6;
  using State = Pose3;
  using Vec = Vector6;
  using Mat = Matrix6;
  using Lin = Linearization3D;
  static State stateOf(const Pose3& pose) { return pose; }
  static Pose3 poseOf(const State& state, const Pose3& /*original*/) { return state; }
  static Mat informationOf(const Matrix6& information) { return information; }
  static Vec error(const State& a, const State& b, const State& z) { return errorSE3(a, b, z); }
  static void linearize(const State& a, const State& b, const State& z, Lin* out) {
    linearizeSE3(a, b, z, out);
  }
  static State retract(const State& s, const Vec& d) { return retractSE3(s, d); }
};

// The planar problem of lifted 2D graphs: states (x, y, theta), residuals the 2D g2o error.
struct ModelSE2 {
  static constexpr int kDim = 3;
  using State = Vector3;
  using Vec = Vector3;
  using Mat = Matrix3;
  using Lin = Linearization2D;
  static State stateOf(const Pose3& pose) {
    return State(pose.translation().x(), pose.translation().y(), pose.rollPitchYaw().z());
  }
  static Pose3 poseOf(const State& s, const Pose3& original) {
    return Pose3::fromRollPitchYaw(s.x(), s.y(), original.translation().z(), 0.0, 0.0, s.z());
  }
  static Mat informationOf(const Matrix6& information) { return planarInformation(information); }
  static Vec error(const State& a, const State& b, const State& z) { return errorSE2(a, b, z); }
  static void linearize(const State& a, const State& b, const State& z, Lin* out) {
    linearizeSE2(a, b, z, out);
  }
  static State retract(const State& s, const Vec& d) { return s + d; }
};

// Which nodes are held (gauge): the FIX nodes, plus the smallest id of every connected component
// without one.  Indexed by dense node index.
std::vector<bool> heldNodes(const PoseGraph& graph);

template <class Model>
class FinishProblem {
 public:
  static constexpr int D = Model::kDim;
  // Entries of the dense right-hand side of one innovation solve at most (32 MB).
  static constexpr std::size_t kMaxInnovationRhs = std::size_t{1} << 22;
  // A constraint in the problem gives no leave-one-out innovation when the rest of the graph
  // contributes less than this share of what H knows along some direction of its error (removing
  // it would leave that direction free, and the difference Sigma_w - J H^-1 J^T loses the digits).
  static constexpr double kMinShareOfTheRest = 1e-9;
  using State = typename Model::State;
  using Vec = typename Model::Vec;
  using Mat = typename Model::Mat;

  // Copies states and constraints; repairs information that is not positive definite (counted).
  // With `robust` enabled, loop closures (isLoopClosure) enter as rho(chi2) (robust_kernel.h): the
  // objective is sum rho, the normal equations are weighted by rho'(chi2) at the linearisation
  // point (iteratively reweighted least squares; rho'' is left out, as g2o and Ceres do).
  // Robust edges whose weight at the start is below `set_aside_weight` are set aside: left out of
  // the sparsity pattern and the factorisation (a wrong loop closure between far-apart poses adds
  // fill-in there, measured 10x slower with 1000 on sphere2500), but not out of the problem: they
  // stay in the objective and the gradient, and their part of the normal equations enters the
  // step through preconditioned conjugate gradients, the factorisation without them as the
  // preconditioner (exact up to the tolerance; cheap while their weights are small).
  // setAsideRegained() tells whether any of them regained weight (then a new problem with them
  // in the pattern is cheaper).  `scaled_damping`: see damping().
  FinishProblem(const PoseGraph& graph, LinearSolverType solver, const RobustOptions& robust = {},
                double set_aside_weight = 0.0, bool scaled_damping = false);

  std::size_t numFree() const { return static_cast<std::size_t>(b_.size()) / D; }
  std::size_t numHeld() const { return held_count_; }
  std::size_t repairedInformation() const { return repaired_; }
  std::vector<State>& states() { return states_; }

  // The objective at `states`: sum of chi2, with rho(chi2) for robust edges.
  double cost(const std::vector<State>& states) const {
    double total = 0.0;
    for (const std::vector<Edge>* list : {&edges_, &set_aside_}) {
      for (const Edge& e : *list) {
        const Vec r = Model::error(states[e.i], states[e.j], e.z);
        const double chi2 = r.dot(e.information * r);
        total += e.robust ? robustCost(robust_, chi2) : chi2;
      }
    }
    return total;
  }
  // Plain chi2 of all edges (set-aside ones included) at states() and, per constraint index, its
  // weight rho'(chi2) (1 unless robust).
  double plainChi2(std::vector<double>* weights) const {
    double total = 0.0;
    if (weights) weights->assign(edges_.size() + set_aside_.size(), 1.0);
    for (const std::vector<Edge>* list : {&edges_, &set_aside_}) {
      for (const Edge& e : *list) {
        const Vec r = Model::error(states_[e.i], states_[e.j], e.z);
        const double chi2 = r.dot(e.information * r);
        total += chi2;
        if (weights && e.robust) (*weights)[e.index] = robustWeight(robust_, chi2);
      }
    }
    return total;
  }
  std::size_t numSetAside() const { return set_aside_.size(); }
  // How many set-aside edges now weigh kRegainFactor times the threshold they were set aside by.
  std::size_t setAsideRegained() const {
    std::size_t n = 0;
    for (const Edge& e : set_aside_) {
      const Vec r = Model::error(states_[e.i], states_[e.j], e.z);
      n += robustWeight(robust_, r.dot(e.information * r)) >= kRegainFactor * set_aside_threshold_ ? 1 : 0;
    }
    return n;
  }

  // The objective at states(), and the normal equations there: H = J^T W Omega J (lower),
  // b = J^T W Omega e, W the robust weights (1 without robust edges).
  double linearize() { return linearize(true); }
  // The objective and b only, when nothing set aside needs H there: H follows when a step or the
  // innovation test needs it (the same H, as linearize() would have left).  Why: most background
  // finishes stop after their first step, on the decrease predicted from b alone, and H's
  // accumulation is most of a linearisation.
  double relinearizeGradient() { return linearize(!set_aside_.empty()); }
  const Eigen::VectorXd& b() const { return b_; }
  double maxDiagonal() const { return diagonal_.size() ? diagonal_.maxCoeff() : 0.0; }
  // Solves (H + D) step = -b, D the damping (damping()); false if the factorisation failed.
  bool solveStep(double lambda, Eigen::VectorXd* step);
  // Whether the last solveStep's conjugate-gradient correction for the set-aside edges failed to
  // converge: they are too stiff against the factorised part to be left out of it (a loop closure
  // with tight information, as manhattan.g2o has some, resists a step along the chain of odometry
  // between its ends thousands of times more than the chain does, even at a weight of 1e-5), and
  // the step it returned is not a solution.  A new problem with them factorised is then cheaper.
  bool setAsideTooStiff() const { return set_aside_too_stiff_; }
  // What LM's damping lambda adds to diagonal entry k.  Plain finishes: lambda (Levenberg's
  // identity, as measured for the clean files, bench/finish_results.md).  Robust finishes with
  // FinishOptions::robust_scaled_damping: Marquardt's scaling, lambda times the entry relative to
  // the largest (floored at 1e-6 of it, so no entry goes undamped).  Why there: a robust finish
  // from a map that wrong loop closures bent rejects many steps, and where the information spans
  // orders of magnitude the lambda that tames the stiffest directions, times the identity,
  // freezes the soft ones (kitti_02 with 100 random wrong ones stopped 0.042 m from the clean
  // optimum, scaled 0.002 m; bench/robust_results.md, session 33).
  double damping(int k, double lambda) const {
    if (!scaled_damping_) return lambda;
    return lambda * std::max(diagonal_[k], 1e-6 * diagonal_max_) / diagonal_max_;
  }
  // h^T D h, D the damping above: the damping term of the decrease LM's model predicts.
  double dampedSquaredNorm(const Eigen::VectorXd& h, double lambda) const {
    if (!scaled_damping_) return lambda * h.squaredNorm();
    double sum = 0.0;
    for (int k = 0; k < h.size(); ++k) sum += damping(k, lambda) * h[k] * h[k];
    return sum;
  }
  // Conjugate-gradient iterations spent on set-aside edges so far.
  std::size_t conjugateGradientIterations() const { return cg_iterations_; }
  // The decrease -h^T b that the next step h would bring, estimated with the factorisation of
  // the previous (successful) solveStep and the current b: near the optimum H hardly changes, so
  // this costs two triangular solves instead of a factorisation.  Negative if not available.
  // Without set-aside edges b^T (H + D)^-1 b is |L^-1 P b|^2, the forward half of the solve.
  double estimatedNextDecrease() {
    if (!factorized_) return -1.0;
    if (set_aside_.empty()) {
      Eigen::MatrixXd y;
      if (cholesky_->forwardSolveColumns(b_, &y)) return y.allFinite() ? y.squaredNorm() : -1.0;
    }
    Eigen::VectorXd step = cholesky_->solve(-b_);
    if (!set_aside_.empty()) refineWithSetAside(-b_, last_lambda_, &step);
    return step.allFinite() ? -step.dot(b_) : -1.0;
  }

  // The innovation chi2 of each candidate, a constraint the problem does not hold, against the
  // problem at states(): e^T (Sigma_z + J H^-1 J^T)^-1 e, e its error, Sigma_z its covariance, J
  // its Jacobian and H the Hessian linearize() left (undamped; set-aside edges left out, which
  // only makes H^-1 larger).  In a linear-Gaussian model this is the rise of the optimum's chi2
  // when the candidate is added, chi-square distributed for a right one.  -1 for a candidate
  // whose ends are not both nodes, and for all when H cannot be factorised.  Costs one
  // factorisation and one solve with D right-hand-side columns per candidate, solved together.
  // `included`: constraints the problem holds (the result follows the candidates', in their
  // order): their leave-one-out innovation, the statistic a candidate gets, against its own
  // information (the graph's over IncludedConstraint::weight), from the problem with it at weight
  // w in H (that weight times a robust kernel's).  Whitened by w's information (W^T W = w Omega):
  // with A = W J H^-1 J^T W^T = V (I - L) V^T (L the share of the rest of the graph per direction,
  // in [0, 1]) and f = V^T W e, it is sum_i f_i^2 / (l_i (1 - (1 - w) l_i)); at w = 1
  // e^T (Sigma_z - J H^-1 J^T)^-1 e.  In a linear-Gaussian model that is exactly the innovation
  // against the optimum without it.  -1 for one set aside, and for one that nothing else
  // constrains along a direction (l_i ~ 0: removing it leaves its ends free there).
  std::vector<double> innovationChi2(const PoseGraph& graph, const std::vector<Constraint>& candidates,
                                     const std::vector<IncludedConstraint>& included = {});

  std::vector<State> retracted(const Eigen::VectorXd& step) const {
    std::vector<State> out = states_;
    for (std::size_t n = 0; n < out.size(); ++n) {
      if (block_[n] >= 0) out[n] = Model::retract(out[n], step.template segment<D>(block_[n] * D));
    }
    return out;
  }

  void writeBack(PoseGraph& graph) const {
    for (std::size_t n = 0; n < states_.size(); ++n) {
      graph.setPoseAt(n, Model::poseOf(states_[n], graph.node(n).pose));
    }
  }

 private:
  struct Edge {
    std::size_t index = 0;     // constraint index in the graph
    std::size_t i = 0, j = 0;  // dense node indices
    int bi = -1, bj = -1;      // state blocks, -1 when held
    State z;
    Mat information;
    bool robust = false;  // a loop closure under the robust kernel
    std::array<int, D> diag_i{}, diag_j{}, off{};
  };

  // Renumbers the state blocks by a fill-reducing ordering (AMD) of the graph of blocks, so the
  // sparse Cholesky factorises in the given order (SparseCholesky): ordering the 6x6 (3x3) blocks
  // instead of the scalar entries gives it a 1/36 (1/9) of the pattern to order, and supernodes
  // that never split a block.
  void orderBlocks(int free_blocks);
  void buildPattern();
  // Moves the robust edges whose weight is below relative_weight times the median weight of the
  // robust edges into set_aside_ (before the pattern is built).
  void setAside(double relative_weight);
  // y += (set-aside part of H) x, from the linearisations stored by linearize().
  void addSetAsideProduct(const Eigen::VectorXd& x, Eigen::VectorXd* y) const;
  // Improves `x` towards (H_factorised + D + H_set_aside) x = rhs by preconditioned CG, D the
  // damping at lambda; false when it did not converge (the set-aside edges are too stiff for this
  // preconditioner).
  bool refineWithSetAside(const Eigen::VectorXd& rhs, double lambda, Eigen::VectorXd* x);
  // Adds the lower triangle of a diagonal block, `diagonal` its diagonal entries' offsets.
  void addLower(const std::array<int, D>& diagonal, const Mat& block);
  double linearize(bool with_hessian);
  // H (and its diagonal) at states(), if the last linearisation left it out.
  void ensureHessian() {
    if (!hessian_current_) linearize(true);
  }
  // Adds an off-diagonal block (r, c), r > c, `offsets` its first row's offsets per column.
  void addFull(const std::array<int, D>& offsets, const Mat& block);

  RobustOptions robust_;
  std::vector<State> states_;
  std::vector<int> block_;
  std::size_t held_count_ = 0;
  std::size_t repaired_ = 0;
  std::vector<Edge> edges_;
  std::vector<Edge> set_aside_;  // robust edges left out of the pattern (see the constructor)
  // Their linearisation at the last linearize(): J_from, J_to and the weighted information.
  struct SetAsideLinearization {
    Mat d_from, d_to, information;
  };
  std::vector<SetAsideLinearization> set_aside_lin_;
  double last_lambda_ = 0.0;
  double set_aside_threshold_ = 0.0;
  // A set-aside edge counts as regained at this many times its threshold (not at the threshold
  // itself, so an edge near it does not restart the finish over and over).
  static constexpr double kRegainFactor = 10.0;
  std::size_t cg_iterations_ = 0;
  bool set_aside_too_stiff_ = false;
  double diagonal_max_ = 1.0;  // the largest of diagonal_, set with it
  bool scaled_damping_ = false;
  SparseMatrix h_;
  Eigen::VectorXd b_, diagonal_;
  std::vector<int> diagonal_index_;
  std::unique_ptr<SparseCholesky> cholesky_;
  bool factorized_ = false;       // cholesky_ holds a valid factorisation
  bool hessian_current_ = false;  // h_ and diagonal_ belong to states()
};

template <class Model>
FinishProblem<Model>::FinishProblem(const PoseGraph& graph, LinearSolverType solver,
                                    const RobustOptions& robust, double set_aside_weight, bool scaled_damping)
    : robust_(robust), scaled_damping_(scaled_damping && robust.enabled()) {
  const std::vector<bool> held = heldNodes(graph);
  int free_blocks = 0;
  for (std::size_t n = 0; n < graph.numNodes(); ++n) {
    states_.push_back(Model::stateOf(graph.node(n).pose));
    block_.push_back(held[n] ? -1 : free_blocks++);
    held_count_ += held[n] ? 1 : 0;
  }
  for (std::size_t index = 0; index < graph.numConstraints(); ++index) {
    const Constraint& c = graph.constraints()[index];
    Edge e;
    e.index = index;
    e.i = graph.indexOf(c.from);
    e.j = graph.indexOf(c.to);
    e.bi = block_[e.i];
    e.bj = block_[e.j];
    e.z = Model::stateOf(c.measurement);
    Matrix6 information = c.information;
    // addConstraint keeps non-positive-definite matrices out, but a matrix at the edge of
    // definiteness can still fail a factorisation; the repair is the readers' one.
    if (Eigen::LLT<Matrix6>(information).info() != Eigen::Success && repairInformation(information))
      ++repaired_;
    e.information = Model::informationOf(information);
    e.robust = robust_.enabled() && isLoopClosure(c);
    edges_.push_back(e);
  }
  if (set_aside_weight > 0.0) setAside(set_aside_weight);
  orderBlocks(free_blocks);
  b_.setZero(free_blocks * D);
  buildPattern();
  cholesky_ = makeSparseCholesky(solver);
  cholesky_->analyzePattern(h_);
}

template <class Model>
void FinishProblem<Model>::setAside(double relative_weight) {
  // Relative to the median weight of the robust edges: from dead reckoning every right loop
  // closure starts with a small weight too, and the ones far below it are the far-off wrong ones.
  std::vector<double> weight(edges_.size(), 1.0), robust;
  for (std::size_t k = 0; k < edges_.size(); ++k) {
    const Edge& e = edges_[k];
    if (!e.robust) continue;
    const Vec r = Model::error(states_[e.i], states_[e.j], e.z);
    weight[k] = robustWeight(robust_, r.dot(e.information * r));
    robust.push_back(weight[k]);
  }
  if (robust.empty()) return;
  const auto middle = robust.begin() + static_cast<std::ptrdiff_t>(robust.size() / 2);
  std::nth_element(robust.begin(), middle, robust.end());
  const double threshold = relative_weight * *middle;
  set_aside_threshold_ = threshold;
  std::vector<Edge> kept;
  for (std::size_t k = 0; k < edges_.size(); ++k) (weight[k] < threshold ? set_aside_ : kept).push_back(edges_[k]);
  edges_.swap(kept);
}

template <class Model>
void FinishProblem<Model>::orderBlocks(int free_blocks) {
  if (free_blocks < 3) return;
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(static_cast<std::size_t>(free_blocks) + 2 * edges_.size());
  for (int blk = 0; blk < free_blocks; ++blk) triplets.emplace_back(blk, blk, 1.0);
  for (const Edge& e : edges_) {
    if (e.bi < 0 || e.bj < 0 || e.bi == e.bj) continue;
    triplets.emplace_back(e.bi, e.bj, 1.0);
    triplets.emplace_back(e.bj, e.bi, 1.0);
  }
  SparseMatrix blocks(free_blocks, free_blocks);
  blocks.setFromTriplets(triplets.begin(), triplets.end());
  const std::vector<int> position = fillReducingPositions(blocks);
  const auto renumber = [&](int& b) {
    if (b >= 0) b = position[static_cast<std::size_t>(b)];
  };
  for (int& b : block_) renumber(b);
  for (std::vector<Edge>* list : {&edges_, &set_aside_}) {
    for (Edge& e : *list) {
      renumber(e.bi);
      renumber(e.bj);
    }
  }
}

template <class Model>
void FinishProblem<Model>::buildPattern() {
  // Written straight into the compressed arrays (a sort of 6x6 triplets per block and a search
  // per entry took 5 % of a replay's time, most finishes being warm starts of one iteration).
  const int n = static_cast<int>(b_.size());
  const int blocks = n / D;
  // The block rows of each block column of the lower triangle, ascending; the diagonal first.
  std::vector<std::vector<int>> rows(static_cast<std::size_t>(blocks));
  for (std::size_t c = 0; c < rows.size(); ++c) rows[c].push_back(static_cast<int>(c));
  for (const Edge& e : edges_) {
    if (e.bi >= 0 && e.bj >= 0 && e.bi != e.bj)
      rows[static_cast<std::size_t>(std::min(e.bi, e.bj))].push_back(std::max(e.bi, e.bj));
  }
  std::size_t nonzeros = 0;
  for (std::vector<int>& r : rows) {
    std::sort(r.begin() + 1, r.end());
    r.erase(std::unique(r.begin() + 1, r.end()), r.end());
    nonzeros += D * (D * (r.size() - 1)) + D * (D + 1) / 2;
  }
  h_.resize(n, n);
  h_.resizeNonZeros(static_cast<Eigen::Index>(nonzeros));
  int* outer = h_.outerIndexPtr();
  int* inner = h_.innerIndexPtr();
  int next = 0;
  for (int c = 0; c < blocks; ++c) {
    const std::vector<int>& r = rows[static_cast<std::size_t>(c)];
    for (int k = 0; k < D; ++k) {
      outer[c * D + k] = next;
      for (int a = k; a < D; ++a) inner[next++] = c * D + a;
      for (std::size_t q = 1; q < r.size(); ++q)
        for (int a = 0; a < D; ++a) inner[next++] = r[q] * D + a;
    }
  }
  outer[n] = next;
  std::fill(h_.valuePtr(), h_.valuePtr() + nonzeros, 0.0);
  // Where block (r, c) starts in each of column c's scalar columns: r = c, its diagonal entry
  // (the column's first); r > c, the block's first row.
  auto offsets = [&](int r, int c) {
    std::array<int, D> o;
    if (r == c) {
      for (int k = 0; k < D; ++k) o[k] = outer[c * D + k];
      return o;
    }
    const std::vector<int>& list = rows[static_cast<std::size_t>(c)];
    const int position = static_cast<int>(std::lower_bound(list.begin() + 1, list.end(), r) - list.begin());
    for (int k = 0; k < D; ++k) o[k] = outer[c * D + k] + (D - k) + D * (position - 1);
    return o;
  };
  for (Edge& e : edges_) {
    if (e.bi >= 0) e.diag_i = offsets(e.bi, e.bi);
    if (e.bj >= 0) e.diag_j = offsets(e.bj, e.bj);
    if (e.bi >= 0 && e.bj >= 0) e.off = offsets(std::max(e.bi, e.bj), std::min(e.bi, e.bj));
  }
  diagonal_index_.resize(n);
  for (int k = 0; k < n; ++k) diagonal_index_[k] = outer[k];
  diagonal_.setZero(n);
}

template <class Model>
void FinishProblem<Model>::addLower(const std::array<int, D>& diagonal, const Mat& block) {
  double* values = h_.valuePtr();
  for (int k = 0; k < D; ++k) {
    for (int a = k; a < D; ++a) values[diagonal[k] + (a - k)] += block(a, k);
  }
}

template <class Model>
void FinishProblem<Model>::addFull(const std::array<int, D>& offsets, const Mat& block) {
  double* values = h_.valuePtr();
  for (int k = 0; k < D; ++k) {
    for (int a = 0; a < D; ++a) values[offsets[k] + a] += block(a, k);
  }
}

template <class Model>
double FinishProblem<Model>::linearize(bool with_hessian) {
  if (with_hessian) std::fill(h_.valuePtr(), h_.valuePtr() + h_.nonZeros(), 0.0);
  hessian_current_ = with_hessian;
  b_.setZero();
  double objective = 0.0;
  typename Model::Lin lin;
  Mat scaled;
  for (const Edge& e : edges_) {
    Model::linearize(states_[e.i], states_[e.j], e.z, &lin);
    Vec weighted_error = e.information * lin.error;
    const double chi2 = lin.error.dot(weighted_error);
    const Mat* information_ptr = &e.information;
    if (e.robust) {
      objective += robustCost(robust_, chi2);
      const double weight = robustWeight(robust_, chi2);
      weighted_error *= weight;
      scaled = weight * e.information;
      information_ptr = &scaled;
    } else {
      objective += chi2;
    }
    if (!with_hessian) {
      if (e.bi >= 0) b_.template segment<D>(e.bi * D) += lin.d_from.transpose() * weighted_error;
      if (e.bj >= 0) b_.template segment<D>(e.bj * D) += lin.d_to.transpose() * weighted_error;
      continue;
    }
    const Mat& information = *information_ptr;
    const Mat w_to = information * lin.d_to;
    if (e.bi >= 0) {
      const Mat w_from = information * lin.d_from;
      addLower(e.diag_i, lin.d_from.transpose() * w_from);
      b_.template segment<D>(e.bi * D) += lin.d_from.transpose() * weighted_error;
      if (e.bj >= 0) {
        const Mat h_ij = lin.d_from.transpose() * w_to;
        addFull(e.off, e.bi > e.bj ? h_ij : Mat(h_ij.transpose()));
      }
    }
    if (e.bj >= 0) {
      addLower(e.diag_j, lin.d_to.transpose() * w_to);
      b_.template segment<D>(e.bj * D) += lin.d_to.transpose() * weighted_error;
    }
  }
  set_aside_lin_.resize(set_aside_.size());
  for (std::size_t k = 0; k < set_aside_.size(); ++k) {
    const Edge& e = set_aside_[k];
    Model::linearize(states_[e.i], states_[e.j], e.z, &lin);
    const Vec weighted_error = e.information * lin.error;
    const double chi2 = lin.error.dot(weighted_error);
    objective += robustCost(robust_, chi2);
    const double weight = robustWeight(robust_, chi2);
    set_aside_lin_[k] = SetAsideLinearization{lin.d_from, lin.d_to, weight * e.information};
    if (e.bi >= 0) b_.template segment<D>(e.bi * D) += weight * (lin.d_from.transpose() * weighted_error);
    if (e.bj >= 0) b_.template segment<D>(e.bj * D) += weight * (lin.d_to.transpose() * weighted_error);
  }
  if (with_hessian) {
    for (int k = 0; k < diagonal_.size(); ++k) diagonal_[k] = h_.valuePtr()[diagonal_index_[k]];
    diagonal_max_ = diagonal_.size() ? std::max(diagonal_.maxCoeff(), 1e-300) : 1.0;
  }
  return objective;
}

template <class Model>
void FinishProblem<Model>::addSetAsideProduct(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
  for (std::size_t k = 0; k < set_aside_.size(); ++k) {
    const Edge& e = set_aside_[k];
    const SetAsideLinearization& l = set_aside_lin_[k];
    Vec u = Vec::Zero();
    if (e.bi >= 0) u += l.d_from * x.template segment<D>(e.bi * D);
    if (e.bj >= 0) u += l.d_to * x.template segment<D>(e.bj * D);
    const Vec v = l.information * u;
    if (e.bi >= 0) y->template segment<D>(e.bi * D) += l.d_from.transpose() * v;
    if (e.bj >= 0) y->template segment<D>(e.bj * D) += l.d_to.transpose() * v;
  }
}

template <class Model>
bool FinishProblem<Model>::refineWithSetAside(const Eigen::VectorXd& rhs, double lambda, Eigen::VectorXd* x) {
  // A = H_pattern + D + H_set_aside; M = H_pattern + D (factorised by cholesky_), D the damping.
  // Why these limits: LM only needs a step that lowers the model well, and its gain-ratio test
  // rejects a poor one; 1e-6 of the right-hand side is far below what moves the objective.
  constexpr int kMaxIterations = 50;
  constexpr double kRelativeTolerance = 1e-6;
  // Not converged: a residual above kFailedResidual of the right-hand side at the end, or above
  // kStalledResidual after kStallCheck iterations.  Where the set-aside edges are soft against
  // the factorised part, M^-1 A is near the identity and the correction converges in 2-15
  // iterations (sphere2500 with wrong loop closures, 3D); where they are stiff its residual stays
  // near the right-hand side's size for all 50 (manhattan with 100 random wrong ones: 297 of 327
  // corrections, LM then rejecting most steps, lambda rising 1e13-fold, 100 iterations instead of
  // about 20).
  constexpr double kFailedResidual = 1e-2;
  constexpr int kStallCheck = 10;
  constexpr double kStalledResidual = 0.5;
  const auto apply = [&](const Eigen::VectorXd& v) {
    Eigen::VectorXd out = h_.template selfadjointView<Eigen::Lower>() * v;
    for (int k = 0; k < diagonal_.size(); ++k)
      out[k] += (diagonal_[k] + damping(k, lambda) - h_.valuePtr()[diagonal_index_[k]]) * v[k];
    addSetAsideProduct(v, &out);
    return out;
  };
  Eigen::VectorXd r = rhs - apply(*x);
  const double stop = kRelativeTolerance * rhs.norm();
  if (!(r.norm() > stop)) return true;
  Eigen::VectorXd z = cholesky_->solve(r);
  Eigen::VectorXd p = z;
  double rz = r.dot(z);
  for (int it = 0; it < kMaxIterations; ++it) {
    ++cg_iterations_;
    const Eigen::VectorXd ap = apply(p);
    const double pap = p.dot(ap);
    if (!(pap > 0.0)) break;
    const double alpha = rz / pap;
    *x += alpha * p;
    r -= alpha * ap;
    if (!(r.norm() > stop)) break;
    if (it + 1 == kStallCheck && r.norm() > kStalledResidual * rhs.norm()) return false;
    z = cholesky_->solve(r);
    const double rz_next = r.dot(z);
    p = z + (rz_next / rz) * p;
    rz = rz_next;
  }
  return r.norm() <= kFailedResidual * rhs.norm();
}

template <class Model>
std::vector<double> FinishProblem<Model>::innovationChi2(const PoseGraph& graph,
                                                         const std::vector<Constraint>& candidates,
                                                         const std::vector<IncludedConstraint>& included) {
  std::vector<double> out(candidates.size() + included.size(), -1.0);
  if (out.empty() || b_.size() == 0) return out;
  ensureHessian();
  // Undamped first; a Hessian at the edge of definiteness (a node held by one weak constraint)
  // takes the least damping that factorises, which only narrows the predicted spread a little.
  double* values = h_.valuePtr();
  bool ok = cholesky_->factorize(h_);
  const double scale = std::max(maxDiagonal(), 1e-300);
  for (double damping = 1e-12; !ok && damping <= 1e-6; damping *= 100.0) {
    for (int k = 0; k < diagonal_.size(); ++k) values[diagonal_index_[k]] = diagonal_[k] + damping * scale;
    ok = cholesky_->factorize(h_);
  }
  for (int k = 0; k < diagonal_.size(); ++k) values[diagonal_index_[k]] = diagonal_[k];
  factorized_ = false;  // no longer LM's last factorisation (estimatedNextDecrease)
  if (!ok) return out;
  // J^T of every candidate as columns (nonzero in the blocks of its two ends only), solved in
  // batches of at most kMaxInnovationRhs entries so the dense right-hand side stays small.
  struct Candidate {
    std::size_t k;
    int bi, bj;
    typename Model::Lin lin;
    Mat covariance;       // left out: Sigma_z
    Mat whitening;        // included: W with W^T W its information in H (its weight times its own)
    double weight = 1.0;  // included: that weight
    bool included = false;
  };
  std::vector<Candidate> usable;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    const Constraint& c = candidates[k];
    if (!graph.hasNode(c.from) || !graph.hasNode(c.to)) continue;
    Candidate u;
    u.k = k;
    const std::size_t i = graph.indexOf(c.from), j = graph.indexOf(c.to);
    u.bi = block_[i];
    u.bj = block_[j];
    Model::linearize(states_[i], states_[j], Model::stateOf(c.measurement), &u.lin);
    Matrix6 information = c.information;
    if (Eigen::LLT<Matrix6>(information).info() != Eigen::Success && !repairInformation(information))
      continue;
    u.covariance = Model::informationOf(information).inverse();
    usable.push_back(u);
  }
  if (!included.empty()) {
    std::vector<std::size_t> edge_of(graph.numConstraints(), edges_.size());
    for (std::size_t e = 0; e < edges_.size(); ++e)
      if (edges_[e].index < edge_of.size()) edge_of[edges_[e].index] = e;
    for (std::size_t k = 0; k < included.size(); ++k) {
      const std::size_t c = included[k].index;
      if (c >= edge_of.size() || edge_of[c] == edges_.size()) continue;  // set aside
      const Edge& e = edges_[edge_of[c]];
      Candidate u;
      u.k = candidates.size() + k;
      u.included = true;
      u.bi = e.bi;
      u.bj = e.bj;
      Model::linearize(states_[e.i], states_[e.j], e.z, &u.lin);
      const double kernel =
          e.robust ? robustWeight(robust_, u.lin.error.dot(e.information * u.lin.error)) : 1.0;
      u.weight = kernel * included[k].weight;
      const Eigen::LLT<Mat> llt(kernel * e.information);
      if (!(u.weight > 0.0 && u.weight <= 1.0) || llt.info() != Eigen::Success) continue;
      u.whitening = llt.matrixL().transpose();
      usable.push_back(u);
    }
  }
  // J H^-1 J^T of every candidate.  Y^T Y with Y = L^-1 P J^T over the rows the forward solve reaches
  // from J's two blocks when the factorisation can (SparseCholesky::forwardGram): a held loop
  // closure's test then costs the supernodes on two paths to the root, not the whole factor (the
  // dense solve below was 60 % of kitti_00's replay with 1000 wrong loop closures).
  std::vector<Mat> spread(usable.size(), Mat::Zero());
  bool sparse = true;
  std::vector<Eigen::Triplet<double>> entries;
  Eigen::MatrixXd gram;
  for (std::size_t m = 0; m < usable.size() && sparse; ++m) {
    const Candidate& u = usable[m];
    entries.clear();
    for (int c = 0; c < D; ++c)
      for (int r = 0; r < D; ++r) {
        if (u.bi >= 0) entries.emplace_back(u.bi * D + r, c, u.lin.d_from(c, r));
        if (u.bj >= 0) entries.emplace_back(u.bj * D + r, c, u.lin.d_to(c, r));
      }
    SparseMatrix jt(b_.size(), D);
    jt.setFromTriplets(entries.begin(), entries.end());
    sparse = cholesky_->forwardGram(jt, &gram);
    if (sparse) spread[m] = gram;
  }
  // Else in batches of at most kMaxInnovationRhs entries of a dense right-hand side.
  if (!sparse) spread.assign(usable.size(), Mat::Zero());
  const std::size_t rows = static_cast<std::size_t>(b_.size());
  const std::size_t per_batch = std::max<std::size_t>(1, kMaxInnovationRhs / (rows * D));
  for (std::size_t first = 0; !sparse && first < usable.size(); first += per_batch) {
    const std::size_t count = std::min(per_batch, usable.size() - first);
    Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(b_.size(), static_cast<Eigen::Index>(count * D));
    for (std::size_t m = 0; m < count; ++m) {
      const Candidate& u = usable[first + m];
      const auto col = static_cast<Eigen::Index>(m * D);
      if (u.bi >= 0) rhs.block(u.bi * D, col, D, D) = u.lin.d_from.transpose();
      if (u.bj >= 0) rhs.block(u.bj * D, col, D, D) += u.lin.d_to.transpose();
    }
    // Y^T Y with Y = L^-1 P J^T (the forward half of the solve: on manhattan's replay, where held
    // loop closures are tested at most finishes, the full solve of these columns was a quarter of
    // the run), else J X with X = H^-1 J^T.
    Eigen::MatrixXd y;
    const bool forward = cholesky_->forwardSolveColumns(rhs, &y);
    if (!forward) y = cholesky_->solveColumns(rhs);
    for (std::size_t m = 0; m < count; ++m) {
      const Candidate& u = usable[first + m];
      const auto col = static_cast<Eigen::Index>(m * D);
      Mat& out_spread = spread[first + m];
      if (forward) {
        const auto ym = y.middleCols(col, D);
        out_spread.noalias() = ym.transpose() * ym;
      } else {
        if (u.bi >= 0) out_spread += u.lin.d_from * y.block(u.bi * D, col, D, D);
        if (u.bj >= 0) out_spread += u.lin.d_to * y.block(u.bj * D, col, D, D);
        out_spread = (0.5 * (out_spread + out_spread.transpose())).eval();
      }
    }
  }
  for (std::size_t m = 0; m < usable.size(); ++m) {
    const Candidate& u = usable[m];
    double chi2 = -1.0;
    if (u.included) {
      // See the declaration: l = eigenvalues of I - A.  Why it holds, in W's units (where its
      // covariance in H is I and its own w I): the rest of the graph predicts its error with
      // covariance C = A (I - A)^-1 (Woodbury), its error left out is (I + C) W e, and the
      // innovation weighs that by (w I + C)^-1.
      const Mat a = u.whitening * spread[m] * u.whitening.transpose();
      const Eigen::SelfAdjointEigenSolver<Mat> eigen(Mat::Identity() - 0.5 * (a + a.transpose()));
      if (eigen.info() != Eigen::Success || !(eigen.eigenvalues().minCoeff() > kMinShareOfTheRest)) continue;
      const typename Model::Vec f = eigen.eigenvectors().transpose() * (u.whitening * u.lin.error);
      const auto& l = eigen.eigenvalues().array();
      chi2 = (f.array().square() / (l * (1.0 - (1.0 - u.weight) * l))).sum();
    } else {
      const Eigen::LDLT<Mat> ldlt(u.covariance + spread[m]);
      if (ldlt.info() != Eigen::Success) continue;
      chi2 = u.lin.error.dot(ldlt.solve(u.lin.error));
    }
    if (std::isfinite(chi2) && chi2 >= 0.0) out[u.k] = chi2;
  }
  return out;
}

template <class Model>
bool FinishProblem<Model>::solveStep(double lambda, Eigen::VectorXd* step) {
  ensureHessian();
  double* values = h_.valuePtr();
  for (int k = 0; k < diagonal_.size(); ++k) values[diagonal_index_[k]] = diagonal_[k] + damping(k, lambda);
  const bool ok = cholesky_->factorize(h_);
  factorized_ = ok;
  last_lambda_ = lambda;
  if (ok) *step = cholesky_->solve(-b_);
  // The pattern values hold diagonal + damping here; refineWithSetAside accounts for that.
  set_aside_too_stiff_ = ok && !set_aside_.empty() && !refineWithSetAside(-b_, lambda, step);
  for (int k = 0; k < diagonal_.size(); ++k) values[diagonal_index_[k]] = diagonal_[k];
  return ok && step->allFinite();
}

}  // namespace detail
}  // namespace toro
