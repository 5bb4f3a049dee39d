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

int entryIndex(const SparseMatrix& m, int row, int col) {
  const int* begin = m.innerIndexPtr() + m.outerIndexPtr()[col];
  const int* end = m.innerIndexPtr() + m.outerIndexPtr()[col + 1];
  const int* it = std::lower_bound(begin, end, row);
  if (it == end || *it != row) throw std::logic_error("sparse finish: entry missing from the pattern");
  return static_cast<int>(it - m.innerIndexPtr());
}

}  // namespace detail

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Nielsen's damping update after an accepted step with gain ratio rho (Madsen, Nielsen,
// Tingleff, "Methods for non-linear least squares problems", 2004, eq. 3.16): shrink lambda
// by up to 3 when the quadratic model predicted the decrease well.
// The quadratic model matched the actual decrease closely.
bool gainRatioIsReliable(double rho) { return rho > 0.9 && rho < 1.1; }

double shrinkFactor(double rho) {
  const double t = 2.0 * rho - 1.0;
  return std::max(1.0 / 3.0, 1.0 - t * t * t);
}

template <class Model>
FinishReport runFinish(PoseGraph& graph, const FinishOptions& options, const FinishCallback& callback) {
  const Clock::time_point start = Clock::now();
  FinishReport report;
  detail::FinishProblem<Model> problem(graph, options.linear_solver);
  report.held_nodes = problem.numHeld();
  report.repaired_information = problem.repairedInformation();

  double chi2 = problem.linearize();
  report.initial_chi2 = report.final_chi2 = chi2;
  if (graph.numConstraints() == 0 || problem.numFree() == 0) {
    report.stop = FinishStop::kNoConstraints;
    report.seconds = secondsSince(start);
    return report;
  }
  double gradient = 2.0 * problem.b().template lpNorm<Eigen::Infinity>();
  const double diagonal_scale = std::max(problem.maxDiagonal(), 1e-300);
  double lambda = options.initial_lambda_factor * diagonal_scale;
  double nu = 2.0;
  Eigen::VectorXd step;
  if (gradient < options.gradient_tolerance) report.stop = FinishStop::kGradient;

  while (report.stop == FinishStop::kNotRun) {
    if (report.iterations >= options.max_iterations) {
      report.stop = FinishStop::kMaxIterations;
      break;
    }
    FinishIteration it;
    it.iteration = ++report.iterations;
    it.lambda = lambda;
    it.gradient_norm = gradient;
    const Clock::time_point solve_start = Clock::now();
    const bool solved = problem.solveStep(lambda, &step);
    report.factorization_seconds += secondsSince(solve_start);
    double new_chi2 = chi2;
    std::vector<typename Model::State> trial;
    if (solved) {
      it.step_norm = step.lpNorm<Eigen::Infinity>();
      trial = problem.retracted(step);
      new_chi2 = problem.cost(trial);
      // Decrease predicted by the damped quadratic model: -h^T b + lambda |h|^2 (> 0).
      const double predicted = -step.dot(problem.b()) + lambda * step.squaredNorm();
      it.gain_ratio = predicted > 0.0 ? (chi2 - new_chi2) / predicted : -1.0;
    }
    it.accepted = solved && std::isfinite(new_chi2) && it.gain_ratio > 0.0 && new_chi2 < chi2;
    if (it.accepted) {
      const double relative_decrease = (chi2 - new_chi2) / chi2;
      problem.states() = std::move(trial);
      chi2 = problem.linearize();
      gradient = 2.0 * problem.b().template lpNorm<Eigen::Infinity>();
      lambda *= shrinkFactor(it.gain_ratio);
      nu = 2.0;
      if (relative_decrease < options.relative_decrease_tolerance) {
        report.stop = FinishStop::kRelativeDecrease;
      } else if (gainRatioIsReliable(it.gain_ratio)) {
        // Quadratic convergence: when the model was right about this step, ask it about the
        // next one before paying for its factorisation (saves the last, confirming iteration).
        const double next = problem.estimatedNextDecrease();
        if (next >= 0.0 && next < options.relative_decrease_tolerance * chi2) {
          report.stop = FinishStop::kPredictedDecrease;
        }
      }
      if (gradient < options.gradient_tolerance) report.stop = FinishStop::kGradient;
    } else {
      lambda *= nu;
      nu *= 2.0;
      if (lambda > options.max_lambda_factor * diagonal_scale) report.stop = FinishStop::kLambdaTooLarge;
    }
    if (solved && it.step_norm < options.step_tolerance) report.stop = FinishStop::kStep;
    it.chi2 = chi2;
    it.seconds = secondsSince(start);
    report.history.push_back(it);
    if (callback) callback(it);
  }
  problem.writeBack(graph);
  report.final_chi2 = chi2;
  report.seconds = secondsSince(start);
  return report;
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

FinishReport LevenbergMarquardt::optimize(PoseGraph& graph, const FinishCallback& callback) const {
  if (graph.dimension() == GraphDimension::k2D) {
    return runFinish<detail::ModelSE2>(graph, options_, callback);
  }
  return runFinish<detail::ModelSE3>(graph, options_, callback);
}

}  // namespace toro
