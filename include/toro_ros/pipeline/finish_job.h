// A background finish as a value: the job (a graph, its weights, what to test) taken from the map
// by MapOptimizer::takeFinishJob, run anywhere by runFinishJob (the node: a thread of its own; the
// offline runner: inline), and its outcome, merged back by MapOptimizer::mergeFinish.  Nothing in
// here touches the map: a job owns what it reads.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <ros/time.h>

#include "toro_ros/core/pose_graph.h"
#include "toro_ros/core/sparse_finisher.h"

namespace toro_ros {

// A finish to run on a copy of the graph, away from the pipeline (any thread): runFinishJob.
struct FinishJob {
  std::uint64_t sequence = 0;   // 1, 2, ... per MapOptimizer
  std::uint64_t structure = 0;  // MapOptimizer's structure version when it was taken
  ros::Time stamp;              // newest message time then
  // The graph then; its poses (the current estimate) are the warm start.  Shared and never changed
  // while a job holds it: the MapOptimizer keeps it in step with the map between jobs
  // (finishGraph), so taking a job copies no constraint in the worker (a full copy was 24-38 ms
  // of the worker at 100,000 keyframes); runFinishJob works on a copy of its own.
  std::shared_ptr<const toro::PoseGraph> graph;
  // Each constraint's robust weight as TORO's passes use it (1 for odometry): the finish minimises
  // the chi2 with the loop closures' information scaled by them, so it agrees with the passes on
  // which loop closures count (its own re-weighting by plain residuals would judge a right loop
  // closure that closes a long drifted loop by the drift and drop it).  Loop closures weighted
  // below toro::FinishOptions's set-aside weight are left out (they only add fill-in).
  std::vector<double> weights;
  toro::FinishOptions options;
  // Held loop closures (constraint indices) whose innovation against the finished map the
  // outcome gives: the test by what the whole graph says of them (MapOptimizer::mergeFinish).
  std::vector<std::size_t> innovation_candidates;
  // Accepted loop closures (constraint indices, counted in the finish) whose leave-one-out
  // innovation the outcome gives: samples of the sender's right loop closures that calibrate the
  // test of the held ones (LoopClosureSupport::calibratedInnovationThreshold).  Only beside
  // innovation_candidates, whose factorisation they share.
  std::vector<std::size_t> calibration_samples;
  // Sum over loop closures of min(1, weight): the finish's redundancy over its dof.
  double loop_closure_weight = 0.0;
  // Also solve the graph from scratch (TORO from the odometry chain, then the finish) and keep
  // whichever of the two ends lower.  Set when loop closures an earlier finish had settled the
  // map with were held since (LoopClosureSupport::rejudgeAccepted): the map they bent is a basin of its
  // own, and a finish warm-started there stays in it (a synthetic sphere replayed with 150 wrong
  // loop closures a few poses apart, toro::addOutliers seed 2: accepted in the first ring, held
  // once the sender's scale was learnt; the warm finish stopped at chi2 75, the one from scratch
  // at 0.70, and the first revisit's right loop closures, measured against the bent map, were
  // held to the end: 0.27 m RMS against 0.087 m clean).
  bool from_scratch = false;
};

struct FinishOutcome {
  std::uint64_t sequence = 0;
  std::uint64_t structure = 0;
  ros::Time stamp;
  bool success = false;
  std::string error;            // when not success
  toro::PoseGraph graph;        // the job's nodes with the finished poses (and the constraints it used)
  std::size_t constraints = 0;  // constraints of the map when the job was taken
  double chi2_before = 0.0;
  double chi2_after = 0.0;
  std::size_t iterations = 0;
  double seconds = 0.0;  // wall time of the finish (reported only)
  // Per job.innovation_candidates entry: (constraint index, toro::FinishReport::innovation_chi2).
  std::vector<std::pair<std::size_t, double>> innovations;
  // Per job.calibration_samples entry that could be told: (constraint index, its leave-one-out
  // innovation chi2, toro::FinishReport::included_innovation_chi2).
  std::vector<std::pair<std::size_t, double>> calibration_innovations;
  double loop_closure_weight = 0.0;   // the job's
  std::vector<std::size_t> left_out;  // constraints the finish left out (weight below its set-aside weight)
  bool from_scratch_kept = false;     // the job's solution from scratch ended lower and was taken
};

// Runs the job's finish.  Thread-safe (touches nothing but the job); never throws: a failure is
// reported in the outcome.  `cancelled` (optional) is polled after every iteration: when it
// returns true the finish stops and the outcome says so (not success).
FinishOutcome runFinishJob(FinishJob job, const std::function<bool()>& cancelled = {});

}  // namespace toro_ros
