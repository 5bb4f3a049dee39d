#include "toro_ros/core/sparse_finisher.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include "finish_problem.h"

namespace toro {

namespace detail {

namespace {
std::size_t findRoot(std::vector<std::size_t>& parent, std::size_t i) {
  while (parent[i] != i) i = parent[i] = parent[parent[i]];
  return i;
}
}  // namespace

std::vector<bool> heldNodes(const PoseGraph& graph) {
  const std::size_t n = graph.numNodes();
  std::vector<std::size_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0);
  for (const Constraint& c : graph.constraints()) {
    parent[findRoot(parent, graph.indexOf(c.from))] = findRoot(parent, graph.indexOf(c.to));
  }
  std::vector<bool> held(n, false), component_held(n, false);
  for (NodeId id : graph.fixedNodes()) {
    if (!graph.hasNode(id)) continue;
    const std::size_t i = graph.indexOf(id);
    held[i] = true;
    component_held[findRoot(parent, i)] = true;
  }
  // Per component root: the node index with the smallest id.
  std::vector<std::size_t> smallest(n, n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t r = findRoot(parent, i);
    if (smallest[r] == n || graph.node(i).id < graph.node(smallest[r]).id) smallest[r] = i;
  }
  for (std::size_t r = 0; r < n; ++r) {
    if (smallest[r] < n && !component_held[r]) held[smallest[r]] = true;
  }
  return held;
}

}  // namespace detail

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// The quadratic model matched the actual decrease closely.
bool gainRatioIsReliable(double rho) { return rho > 0.9 && rho < 1.1; }

// Nielsen's damping update after an accepted step with gain ratio rho (Madsen, Nielsen,
// Tingleff, "Methods for non-linear least squares problems", 2004, eq. 3.16): shrink lambda
// by up to 3 when the quadratic model predicted the decrease well.
double shrinkFactor(double rho) {
  const double t = 2.0 * rho - 1.0;
  return std::max(1.0 / 3.0, 1.0 - t * t * t);
}

// One Levenberg-Marquardt run: the loop state and one method per part of an iteration.
template <class Model>
class LmRun {
 public:
  // With `end_when_regained`, the run stops (kSetAsideRegained) as soon as a set-aside loop closure
  // regains weight, so the caller can rebuild the problem with it in the factorisation.
  LmRun(PoseGraph& graph, const FinishOptions& options, bool end_when_regained = false)
      : options_(options),
        problem_(graph, options.linear_solver, options.robust,
                 options.robust.enabled() ? options.robust_set_aside_weight : 0.0,
                 options.robust_scaled_damping),
        end_when_regained_(end_when_regained) {}

  FinishReport run(PoseGraph& graph, const FinishCallback& callback,
                   const std::vector<Constraint>& candidates,
                   const std::vector<IncludedConstraint>& included);

 private:
  // Solves for and tries one step; fills `it` and updates the state and report.stop.
  void iterate(FinishIteration* it);
  void accept(std::vector<typename Model::State> trial, double new_chi2, FinishIteration* it);
  void reject();
  double gradientNorm() const { return 2.0 * problem_.b().template lpNorm<Eigen::Infinity>(); }

  const FinishOptions& options_;
  Clock::time_point start_ = Clock::now();  // before problem_: setup counts in report_.seconds
  detail::FinishProblem<Model> problem_;
  FinishReport report_;
  bool end_when_regained_ = false;
  double chi2_ = 0.0, gradient_ = 0.0, lambda_ = 0.0, nu_ = 2.0, diagonal_scale_ = 1.0;
  Eigen::VectorXd step_;
};

template <class Model>
FinishReport LmRun<Model>::run(PoseGraph& graph, const FinishCallback& callback,
                               const std::vector<Constraint>& candidates,
                               const std::vector<IncludedConstraint>& included) {
  report_.held_nodes = problem_.numHeld();
  report_.set_aside = problem_.numSetAside();
  report_.repaired_information = problem_.repairedInformation();
  chi2_ = problem_.linearize();
  report_.initial_objective = chi2_;
  report_.initial_chi2 = options_.robust.enabled() ? problem_.plainChi2(nullptr) : chi2_;
  if (graph.numConstraints() == 0 || problem_.numFree() == 0) {
    report_.stop = FinishStop::kNoConstraints;
  } else {
    gradient_ = gradientNorm();
    diagonal_scale_ = std::max(problem_.maxDiagonal(), 1e-300);
    lambda_ = options_.initial_lambda_factor * diagonal_scale_;
    if (gradient_ < options_.gradient_tolerance) report_.stop = FinishStop::kGradient;
  }
  while (report_.stop == FinishStop::kNotRun) {
    if (report_.iterations >= options_.max_iterations) {
      report_.stop = FinishStop::kMaxIterations;
      break;
    }
    FinishIteration it;
    iterate(&it);
    report_.history.push_back(it);
    if (callback) callback(it);
  }
  problem_.writeBack(graph);
  std::vector<double> innovations = problem_.innovationChi2(graph, candidates, included);
  report_.included_innovation_chi2.assign(
      innovations.begin() + static_cast<std::ptrdiff_t>(candidates.size()), innovations.end());
  innovations.resize(candidates.size());
  report_.innovation_chi2 = std::move(innovations);
  report_.final_objective = chi2_;
  if (options_.robust.enabled()) {
    report_.final_chi2 = problem_.plainChi2(&report_.weights);
    report_.conjugate_gradient_iterations = problem_.conjugateGradientIterations();
  } else {
    report_.final_chi2 = chi2_;
    report_.weights.assign(graph.numConstraints(), 1.0);
  }
  report_.seconds = secondsSince(start_);
  return report_;
}

template <class Model>
void LmRun<Model>::iterate(FinishIteration* it) {
  it->iteration = ++report_.iterations;
  it->lambda = lambda_;
  it->gradient_norm = gradient_;
  const Clock::time_point solve_start = Clock::now();
  const bool solved = problem_.solveStep(lambda_, &step_);
  report_.factorization_seconds += secondsSince(solve_start);
  if (solved && problem_.setAsideTooStiff()) {
    // The step is not a solution; the next round factorises the set-aside loop closures.
    report_.stop = FinishStop::kSetAsideTooStiff;
    it->accepted = false;
    it->chi2 = chi2_;
    it->seconds = secondsSince(start_);
    return;
  }
  double new_chi2 = chi2_;
  std::vector<typename Model::State> trial;
  if (solved) {
    it->step_norm = step_.lpNorm<Eigen::Infinity>();
    trial = problem_.retracted(step_);
    new_chi2 = problem_.cost(trial);
    // Decrease predicted by the damped quadratic model: -h^T b + h^T D h (> 0).
    const double predicted = -step_.dot(problem_.b()) + problem_.dampedSquaredNorm(step_, lambda_);
    it->gain_ratio = predicted > 0.0 ? (chi2_ - new_chi2) / predicted : -1.0;
  }
  it->accepted = solved && std::isfinite(new_chi2) && it->gain_ratio > 0.0 && new_chi2 < chi2_;
  if (it->accepted) {
    accept(std::move(trial), new_chi2, it);
  } else {
    reject();
  }
  if (solved && it->step_norm < options_.step_tolerance) report_.stop = FinishStop::kStep;
  it->chi2 = chi2_;
  it->seconds = secondsSince(start_);
}

template <class Model>
void LmRun<Model>::accept(std::vector<typename Model::State> trial, double new_chi2, FinishIteration* it) {
  const double relative_decrease = (chi2_ - new_chi2) / chi2_;
  problem_.states() = std::move(trial);
  chi2_ = problem_.relinearizeGradient();
  gradient_ = gradientNorm();
  lambda_ *= shrinkFactor(it->gain_ratio);
  nu_ = 2.0;
  if (relative_decrease < options_.relative_decrease_tolerance) {
    report_.stop = FinishStop::kRelativeDecrease;
  } else if (gainRatioIsReliable(it->gain_ratio) &&
             it->lambda <= options_.initial_lambda_factor * diagonal_scale_) {
    // Quadratic convergence: when the model was right about this step, ask it about the next
    // one before paying for its factorisation (saves the last, confirming iteration).  Only in
    // the Gauss-Newton regime: with a large lambda the damped estimate b^T (H + lambda I)^-1 b
    // underestimates the next decrease and would stop too early.
    const double next = problem_.estimatedNextDecrease();
    if (next >= 0.0 && next < options_.relative_decrease_tolerance * chi2_) {
      report_.stop = FinishStop::kPredictedDecrease;
    }
  }
  if (gradient_ < options_.gradient_tolerance) report_.stop = FinishStop::kGradient;
  if (report_.stop == FinishStop::kNotRun && end_when_regained_ && problem_.numSetAside() > 0 &&
      problem_.setAsideRegained() > 0) {
    report_.stop = FinishStop::kSetAsideRegained;
  }
}

template <class Model>
void LmRun<Model>::reject() {
  lambda_ *= nu_;
  nu_ *= 2.0;
  if (lambda_ > options_.max_lambda_factor * diagonal_scale_) report_.stop = FinishStop::kLambdaTooLarge;
}

}  // namespace

std::string FinishOptions::validate() const {
  std::ostringstream s;
  if (max_iterations == 0) s << "max_iterations must be at least 1; ";
  if (!(relative_decrease_tolerance >= 0.0)) s << "relative_decrease_tolerance must be >= 0; ";
  if (!(gradient_tolerance >= 0.0)) s << "gradient_tolerance must be >= 0; ";
  if (!(step_tolerance >= 0.0)) s << "step_tolerance must be >= 0; ";
  if (!(initial_lambda_factor > 0.0) || !std::isfinite(initial_lambda_factor)) {
    s << "initial_lambda_factor must be positive and finite; ";
  }
  if (!(max_lambda_factor > initial_lambda_factor) || !std::isfinite(max_lambda_factor)) {
    s << "max_lambda_factor must be finite and larger than initial_lambda_factor; ";
  }
  if (!(robust_set_aside_weight >= 0.0 && robust_set_aside_weight < 1.0))
    s << "robust_set_aside_weight must be in [0, 1); ";
  const std::string robust_problem = robust.validate();
  if (!robust_problem.empty()) s << robust_problem << "; ";
  std::string out = s.str();
  if (!out.empty()) out.resize(out.size() - 2);
  return out;
}

const char* finishStopName(FinishStop stop) {
  switch (stop) {
    case FinishStop::kNotRun:
      return "not run";
    case FinishStop::kRelativeDecrease:
      return "relative decrease below tolerance";
    case FinishStop::kPredictedDecrease:
      return "predicted next decrease below tolerance";
    case FinishStop::kGradient:
      return "gradient below tolerance";
    case FinishStop::kStep:
      return "step below tolerance";
    case FinishStop::kMaxIterations:
      return "iteration limit";
    case FinishStop::kLambdaTooLarge:
      return "no further decrease (damping limit)";
    case FinishStop::kNoConstraints:
      return "nothing to optimise";
    case FinishStop::kSetAsideRegained:
      return "set-aside loop closures regained weight";
    case FinishStop::kSetAsideTooStiff:
      return "set-aside loop closures too stiff to leave out of the factorisation";
  }
  return "unknown";
}

LevenbergMarquardt::LevenbergMarquardt(const FinishOptions& options) : options_(options) {
  const std::string problem = options_.validate();
  if (!problem.empty()) throw std::invalid_argument("FinishOptions: " + problem);
  if (options_.linear_solver != LinearSolverType::kSimplicialLDLT && !cholmodAvailable()) {
    throw std::invalid_argument(std::string("FinishOptions: linear solver ") +
                                linearSolverName(options_.linear_solver) + " is not built in");
  }
}

namespace {

// Runs the finish; when set-aside loop closures regain weight, again with them in the
// factorisation (at most kMaxSetAsideRounds rounds; the last one runs to the end regardless,
// exact through the conjugate-gradient correction), and when they are too stiff to be left out
// (FinishProblem::setAsideTooStiff), at once with every loop closure factorised; one report.
template <class Model>
FinishReport optimizeWith(PoseGraph& graph, const FinishOptions& options, const FinishCallback& callback,
                          const std::vector<Constraint>& candidates,
                          const std::vector<IncludedConstraint>& included) {
  FinishReport total;
  FinishOptions round_options = options;
  for (std::size_t round = 1;; ++round) {
    LmRun<Model> run(graph, round_options, round < kMaxSetAsideRounds);
    FinishReport r = run.run(graph, callback, candidates, included);
    if (round == 1) {
      total = r;
    } else {
      total.final_chi2 = r.final_chi2;
      total.final_objective = r.final_objective;
      total.weights = std::move(r.weights);
      total.innovation_chi2 = std::move(r.innovation_chi2);
      total.included_innovation_chi2 = std::move(r.included_innovation_chi2);
      total.iterations += r.iterations;
      total.stop = r.stop;
      total.set_aside = r.set_aside;
      total.rounds = round;
      total.seconds += r.seconds;
      total.factorization_seconds += r.factorization_seconds;
      total.conjugate_gradient_iterations += r.conjugate_gradient_iterations;
      total.history.insert(total.history.end(), r.history.begin(), r.history.end());
    }
    const bool new_round = r.stop == FinishStop::kSetAsideRegained || r.stop == FinishStop::kSetAsideTooStiff;
    if (!new_round || total.iterations >= options.max_iterations) {
      if (new_round) total.stop = FinishStop::kMaxIterations;
      return total;
    }
    round_options.max_iterations = options.max_iterations - total.iterations;
    // Too stiff: every loop closure in the factorisation from now on (setting aside by weight
    // again would leave the same ones out).
    if (r.stop == FinishStop::kSetAsideTooStiff) round_options.robust_set_aside_weight = 0.0;
  }
}

}  // namespace

FinishReport LevenbergMarquardt::optimize(PoseGraph& graph, const FinishCallback& callback,
                                          const std::vector<Constraint>& candidates,
                                          const std::vector<IncludedConstraint>& included) const {
  if (graph.dimension() == GraphDimension::k2D)
    return optimizeWith<detail::ModelSE2>(graph, options_, callback, candidates, included);
  return optimizeWith<detail::ModelSE3>(graph, options_, callback, candidates, included);
}

}  // namespace toro
