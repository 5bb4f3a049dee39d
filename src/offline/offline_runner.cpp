#include "toro_ros/offline/offline_runner.h"

#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <rosbag/view.h>
#include <nav_msgs/Odometry.h>

#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/offline/flat_yaml.h"
#include "toro_ros/offline/progress_bar.h"
#include "toro_ros/pipeline/graph_directory.h"
#include "toro_ros/pipeline/input_table.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

constexpr std::size_t kMaxPrintedWarnings = 20;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

}  // namespace

std::string OfflineOptions::validate() const {
  if (bag_path.empty()) return "bag: missing";
  if (output_dir.empty()) return "output directory: missing";
  if (final_iterations < 0) return "final_iterations must be >= 0";
  if (topic_namespace.empty() || topic_namespace[0] != '/') return "namespace must start with '/'";
  if (!(std::isfinite(start_sec) && start_sec >= 0)) return "start must be >= 0 s";
  if (!(std::isfinite(duration_sec) && duration_sec >= 0)) return "duration must be >= 0 s (0: to the end)";
  if (!(std::isfinite(optimality_every_sec) && optimality_every_sec >= 0)) return "optimality period must be >= 0 s";
  if (!(std::isfinite(optimality_after_loop_closure_sec) && optimality_after_loop_closure_sec >= 0))
    return "optimality delay after a loop closure must be >= 0 s";
  if (optimality_after_loop_closure_sec > 0 && !(optimality_every_sec > 0))
    return "optimality delay after a loop closure needs an optimality period (their minimum spacing) > 0 s";
  if (solver_threads) {
    if (const std::string e = toro::validateSolverThreads(*solver_threads); !e.empty()) return e;
  }
  return "";
}

std::string resolveName(const std::string& ns, const std::string& name) {
  if (!name.empty() && name[0] == '/') return name;
  return ns.back() == '/' ? ns + name : ns + "/" + name;
}

std::map<std::string, BagHandler> makeBagHandlers(const std::string& topic_namespace) {
  std::map<std::string, BagHandler> table;
  forEachPipelineInput([&](const char* topic, auto handler) {
    using M = MessageOf<decltype(handler)>;
    table[resolveName(topic_namespace, topic)] = [](const rosbag::MessageInstance& m, Pipeline& pipeline) {
      const boost::shared_ptr<const M> msg = m.instantiate<M>();
      if (!msg)
        throw std::runtime_error("topic " + m.getTopic() + " at " + stampString(m.getTime()) + " has type " +
                                 m.getDataType() + ", expected " + ros::message_traits::datatype<M>());
      feedPipeline(pipeline, PipelineMessage(msg));
    };
  });
  return table;
}

NodeOptions loadNodeOptionsFile(const std::string& path) {
  OptionsReport report;
  const NodeOptions options =
      loadNodeOptions(path.empty() ? XmlRpc::XmlRpcValue() : readFlatYaml(path), &report);
  std::ostringstream problems;
  for (const std::string& key : report.unknown_keys) problems << "\n  unknown key " << key;
  for (const std::string& e : report.errors) problems << "\n  " << e;
  if (!problems.str().empty()) throw std::invalid_argument(path + ": invalid parameters:" + problems.str());
  return options;
}

OfflineRunner::OfflineRunner(const OfflineOptions& options)
    : options_(options), node_options_(loadNodeOptionsFile(options.config_path)) {
  const std::string invalid = options.validate();
  if (!invalid.empty()) throw std::invalid_argument(invalid);
  // As the node does at start (process-wide; the command line's count before the config's).
  toro::setSolverThreads(options.solver_threads.value_or(node_options_.finish_threads));
  // This process is the runner's (a program or a test): OpenBLAS's kernels may be switched before
  // the first finish.  Said only when they were not the library's own choice.
  const toro::BlasKernels blas = toro::selectBlasKernels(/*may_switch=*/true);
  if (blas.unusual) std::cerr << blas.note << '\n';
  // As the node: relative load_path / autosave_path are taken from graph_directory.
  const std::string paths = GraphDirectory(node_options_.graph_directory)
                                .resolveOperatorPaths(&node_options_.load_path,
                                                      &node_options_.pipeline.persistence.autosave_path);
  if (!node_options_.load_path.empty() || !node_options_.pipeline.persistence.autosave_path.empty())
    std::cerr << paths << '\n';
  pipeline_ = std::make_unique<Pipeline>(
      node_options_.pipeline,
      [this](const std::string& w) {
        if (warnings_.size() < kMaxPrintedWarnings) std::cerr << "\nwarning: " << w << '\n';
        warnings_.push_back(w);
      },
      [](const std::string& i) { std::cerr << "\n" << i << '\n'; });
  const std::string resumed = loadOnStart(*pipeline_, node_options_.load_path);
  if (!resumed.empty()) std::cerr << resumed << '\n';
}

void OfflineRunner::drainSchedule(double stamp_sec, OfflineRun* run) {
  const auto record = [&] {
    const PipelineStatus s = pipeline_->status();
    run->curve.push_back(
        CurvePoint{run->curve.size() + 1, stamp_sec, s.keyframes, s.constraints, s.last_chi2, false});
  };
  // As the node's worker: after the input, run passes until nothing is due, and a background
  // finish where the node would start one, run inline and merged at once, so the run is
  // deterministic (the node merges it when its thread is done, a little later).  After a merge the
  // worker looks again at once, and a finish that may follow at once (one released held loop
  // closures: MapOptimizer::takeFinishJob) starts there; at most kFinishesPerMessage here, as a
  // bound (each follow-up needs a release by the one before).
  constexpr int kFinishesPerMessage = 4;
  for (int k = 0; k < kFinishesPerMessage; ++k) {
    do {
      const auto t0 = Clock::now();
      if (!pipeline_->runScheduledOptimization()) break;
      run->optimization_sec += since(t0);
      record();
    } while (pipeline_->hasScheduledWork());
    std::optional<FinishJob> job = pipeline_->takeFinishJob();
    if (!job) break;
    const auto t0 = Clock::now();
    pipeline_->mergeFinish(runFinishJob(std::move(*job)));
    run->optimization_sec += since(t0);
    ++run->finishes;
    record();
  }
}

void OfflineRunner::traceRobot(const rosbag::MessageInstance& m, OfflineRun* run) const {
  if (m.getDataType() != ros::message_traits::datatype<nav_msgs::Odometry>()) return;
  const auto odometry = m.instantiate<nav_msgs::Odometry>();
  const KeyframeIndex& keyframes = pipeline_->keyframes();
  if (!odometry || keyframes.empty()) return;
  // map_T_odom = (corrected newest keyframe) * (its odometry pose)^-1, as Snapshot has it.
  const toro::Pose3 map_T_odom = pipeline_->graph().node(keyframes.size() - 1).pose * keyframes.newest().odom_T_base.inverse();
  run->robot_in_map.push_back(OfflineRun::RobotInMap{
      m.getTime().toSec(), map_T_odom * poseFromMsg(odometry->pose.pose).translation(), map_T_odom});
}

void OfflineRunner::sampleOptimality(double stamp_sec, double since_loop_closure_sec, OfflineRun* run) const {
  const toro::PoseGraph& published = pipeline_->graph();
  if (published.numConstraints() == 0) return;
  toro::PoseGraph best = published;
  toro::FinishOptions o;
  if (!toro::cholmodAvailable()) o.linear_solver = toro::LinearSolverType::kSimplicialLDLT;
  toro::LevenbergMarquardt(o).optimize(best);
  const FinishOutcome weighted = runFinishJob(pipeline_->optimumJob());
  OfflineRun::Optimality sample;
  sample.stamp_sec = stamp_sec;
  sample.published_chi2 = toro::g2oChi2(published);
  sample.optimum_chi2 = toro::g2oChi2(best);
  sample.published_weighted_chi2 = weighted.success ? weighted.chi2_before : kNaN;
  sample.weighted_optimum_chi2 = weighted.success ? weighted.chi2_after : kNaN;
  sample.constraints = published.numConstraints();
  sample.since_loop_closure_sec = since_loop_closure_sec;
  run->optimality.push_back(sample);
}

void OfflineRunner::finalPasses(OfflineRun* run) {
  if (options_.final_iterations <= 0 || pipeline_->graph().numConstraints() == 0) return;
  const auto n = static_cast<unsigned>(options_.final_iterations);
  if (options_.iteration_curve) {
    // The same passes on a copy, to record chi2 after each one (Pipeline::optimize reports only
    // the end); the copy starts from the same poses and schedule, so its end matches the pipeline's.
    toro::TreeOptimizer copy(pipeline_->optimizerOptions());
    copy.setGraph(pipeline_->graph(), toro::InitialGuess::kFromGraph);
    for (unsigned i = 0; i < n; ++i) {
      copy.iterate();
      const toro::PoseGraph& g = copy.graph();
      run->curve.push_back(
          CurvePoint{run->curve.size() + 1, 0.0, g.numNodes(), g.numConstraints(), toro::g2oChi2(g), true});
    }
  }
  const auto t0 = Clock::now();
  run->final_result = pipeline_->optimize(n, "full");
  run->optimization_sec += since(t0);
}

OfflineRun OfflineRunner::run() {
  const auto t0 = Clock::now();
  OfflineRun run;
  rosbag::Bag bag;
  try {
    bag.open(options_.bag_path, rosbag::bagmode::Read);
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(options_.bag_path + ": cannot open the bag: " + e.what());
  }
  const std::map<std::string, BagHandler> handlers = makeBagHandlers(options_.topic_namespace);
  std::vector<std::string> topics;
  for (const auto& entry : handlers) topics.push_back(entry.first);
  rosbag::View whole(bag, rosbag::TopicQuery(topics));
  if (whole.size() == 0)
    throw std::runtime_error(options_.bag_path + ": no message on " + topics.front() + " or " +
                             topics.back());
  const ros::Time bag_begin = whole.getBeginTime();
  const ros::Time begin = bag_begin + ros::Duration(options_.start_sec);
  const ros::Time end = options_.duration_sec > 0 ? begin + ros::Duration(options_.duration_sec) : whole.getEndTime();
  rosbag::View view(bag, rosbag::TopicQuery(topics), begin, end);
  run.bag_duration_sec = (end - begin).toSec();
  ProgressBar bar(std::cerr, options_.progress);
  // Regular samples: the next one at or after next_optimality.  After loop closures: the next one
  // at next_optimality once a loop closure set it (sample_due), and never before spaced_until.
  const bool after_loop_closures = options_.optimality_after_loop_closure_sec > 0;
  ros::Time next_optimality = begin, spaced_until = begin;
  bool sample_due = !after_loop_closures;
  double newest_loop_closure_sec = kNaN;
  for (const rosbag::MessageInstance& m : view) {
    const std::uint64_t loop_closures_before = pipeline_->counters().loop_closures_received;
    try {
      handlers.at(m.getTopic())(m, *pipeline_);
    } catch (const std::exception& e) {
      throw std::runtime_error(options_.bag_path + ": " + e.what());
    }
    ++run.messages;
    ++run.messages_by_topic[m.getTopic()];
    drainSchedule(m.getTime().toSec(), &run);
    traceRobot(m, &run);
    const double stamp_sec = (m.getTime() - begin).toSec();
    if (pipeline_->counters().loop_closures_received != loop_closures_before) {
      newest_loop_closure_sec = stamp_sec;
      if (after_loop_closures && !sample_due) {
        sample_due = true;
        next_optimality =
            std::max(m.getTime() + ros::Duration(options_.optimality_after_loop_closure_sec), spaced_until);
      }
    }
    if (options_.optimality_every_sec > 0 && sample_due && m.getTime() >= next_optimality) {
      sampleOptimality(stamp_sec, stamp_sec - newest_loop_closure_sec, &run);
      if (after_loop_closures) {
        sample_due = false;
        spaced_until = m.getTime() + ros::Duration(options_.optimality_every_sec);
      } else {
        while (next_optimality <= m.getTime())
          next_optimality += ros::Duration(options_.optimality_every_sec);
      }
    }
    bar.update(run.bag_duration_sec > 0 ? stamp_sec / run.bag_duration_sec : 1.0, run.messages);
  }
  bar.finish(run.messages);
  if (warnings_.size() > kMaxPrintedWarnings)
    std::cerr << "(" << warnings_.size() - kMaxPrintedWarnings << " more warnings not printed)\n";
  finalPasses(&run);
  run.wall_sec = since(t0);
  run.blas_kernels = toro::selectBlasKernels(/*may_switch=*/false).in_use;  // what the finishes ran with
  return run;
}

}  // namespace offline
}  // namespace toro_ros
