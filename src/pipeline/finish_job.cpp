#include "toro_ros/pipeline/finish_job.h"

#include <algorithm>
#include <stdexcept>

#include "toro_ros/core/graph_optimizer.h"

namespace toro_ros {

namespace {

// Thrown from the finish's iteration callback to stop it (runFinishJob's `cancelled`).
struct FinishCancelled {};

}  // namespace

FinishOutcome runFinishJob(FinishJob job, const std::function<bool()>& cancelled) {
  FinishOutcome out;
  out.sequence = job.sequence;
  out.structure = job.structure;
  out.stamp = job.stamp;
  out.constraints = job.graph ? job.graph->numConstraints() : 0;
  out.loop_closure_weight = job.loop_closure_weight;
  toro::PoseGraph g;
  try {
    if (!job.graph) throw std::invalid_argument("the job has no graph");
    // Our own copy, and the shared one let go at once: the map keeps it in step for the next job.
    g = *job.graph;
    job.graph.reset();
    if (job.weights.size() != g.numConstraints())
      throw std::invalid_argument("one weight per constraint expected");
    std::vector<toro::Constraint> candidates;
    for (std::size_t c : job.innovation_candidates)
      if (c < g.numConstraints()) candidates.push_back(g.constraints()[c]);
    // job.calibration_samples that are constraints of the finish, at their weights there.
    std::vector<std::size_t> sampled;
    std::vector<toro::IncludedConstraint> included;
    for (std::size_t c : job.calibration_samples)
      if (c < g.numConstraints() && !(job.weights[c] < job.options.robust_set_aside_weight)) {
        sampled.push_back(c);
        included.push_back({c, std::min(1.0, job.weights[c])});
      }
    const double drop_below = job.options.robust_set_aside_weight;
    if (std::any_of(job.weights.begin(), job.weights.end(), [&](double w) { return w < drop_below; })) {
      std::vector<double> weights;
      for (std::size_t c = 0; c < g.numConstraints(); ++c) {
        if (!(job.weights[c] < drop_below))
          weights.push_back(job.weights[c]);
        else
          out.left_out.push_back(c);
      }
      // The samples' indices in the graph without them (never left out themselves).
      for (toro::IncludedConstraint& c : included)
        c.index -= static_cast<std::size_t>(
            std::lower_bound(out.left_out.begin(), out.left_out.end(), c.index) - out.left_out.begin());
      g = toro::keepConstraints(g, [&](std::size_t c) { return !(job.weights[c] < drop_below); });
      job.weights = std::move(weights);
    }
    for (std::size_t c = 0; c < g.numConstraints(); ++c)
      if (job.weights[c] < 1.0) g.scaleInformation(c, job.weights[c]);
    toro::FinishCallback callback;
    if (cancelled)
      callback = [&cancelled](const toro::FinishIteration&) {
        if (cancelled()) throw FinishCancelled{};
      };
    toro::PoseGraph scratch;
    if (job.from_scratch) scratch = g;  // before the warm start moves its poses
    toro::FinishReport report =
        toro::LevenbergMarquardt(job.options).optimize(g, callback, candidates, included);
    double seconds = report.seconds;
    if (job.from_scratch) {
      // The same graph solved without the current estimate: TORO from the odometry chain (it finds
      // the basin of the optimum where a warm-started finish polishes whatever basin the map is
      // in), then the finish; the lower of the two ends is kept.
      toro::OptimizeOptions start;
      start.mode = toro::OptimizeMode::kToro;
      start.initial_guess = toro::InitialGuess::kChainOdometry;
      toro::OptimizeCallback toro_callback;
      if (cancelled)
        toro_callback = [&cancelled](const toro::OptimizeIteration&) {
          if (cancelled()) throw FinishCancelled{};
        };
      seconds += toro::optimizeGraph(scratch, start, toro_callback).seconds;
      toro::FinishOptions options = job.options;
      options.max_iterations = std::max(options.max_iterations, toro::FinishOptions{}.max_iterations);
      toro::FinishReport from_scratch =
          toro::LevenbergMarquardt(options).optimize(scratch, callback, candidates, included);
      seconds += from_scratch.seconds;
      if (from_scratch.final_chi2 < report.final_chi2) {
        from_scratch.initial_chi2 = report.initial_chi2;
        report = std::move(from_scratch);
        g = std::move(scratch);
        out.from_scratch_kept = true;
      }
    }
    for (std::size_t k = 0, i = 0; k < job.innovation_candidates.size() && i < report.innovation_chi2.size();
         ++k)
      if (job.innovation_candidates[k] < out.constraints)
        out.innovations.emplace_back(job.innovation_candidates[k], report.innovation_chi2[i++]);
    for (std::size_t k = 0; k < sampled.size() && k < report.included_innovation_chi2.size(); ++k)
      if (report.included_innovation_chi2[k] >= 0.0)
        out.calibration_innovations.emplace_back(sampled[k], report.included_innovation_chi2[k]);
    for (const toro::Node& n : g.nodes())
      if (!n.pose.isFinite())
        throw std::runtime_error("node " + std::to_string(n.id) + " ended with a non-finite pose");
    out.chi2_before = report.initial_chi2;
    out.chi2_after = report.final_chi2;
    out.iterations = report.iterations;
    out.seconds = seconds;
    out.success = true;
  } catch (const FinishCancelled&) {
    out.error = "cancelled";
  } catch (const std::exception& e) {
    out.error = std::string("finish failed: ") + e.what();
  }
  out.graph = std::move(g);
  return out;
}

}  // namespace toro_ros
