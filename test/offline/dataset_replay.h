// A shared dataset replayed through the Pipeline as toro_offline would see it as a bag: messages
// synthesised in memory as graph_to_bag writes them (one odometry message per keyframe at 4 Hz,
// loop closures at the stamp of their newer end), fed in stamp order, the scheduled optimisation
// and the background finishes run after each message as toro_offline runs them, then its final
// passes.  The datasets are not part of the
// package (../shared/datasets beside a checkout): callers skip without them
// (TORO_REQUIRE_DATASETS).
#pragma once

#include <algorithm>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "../core/shared_datasets.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/offline/graph_to_bag.h"
#include "toro_ros/offline/offline_runner.h"
#include "toro_ros/offline/robot_messages.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {
namespace offline {
namespace testing {

const std::string kReplayConfig = std::string(TORO_SOURCE_DIR) + "/config/replay_sample.yaml";
constexpr int kFinalPasses = 20;  // toro_offline's default final_iterations

struct DatasetReplay {
  toro::PoseGraph graph;  // the dataset (sorted by id), plus what a caller added at the end
  std::size_t clean_constraints = 0;
  RobotTimeline timeline;
  GraphToBagOptions options;
  std::string file;
  // Run the background finish where the node would start one, inline, as toro_offline does.  The
  // gate's tests were measured without (the gate decides before any finish could).
  bool background_finishes = true;
};

// The messages of r.graph as it is now (call again after adding constraints to it).
inline void makeMessages(DatasetReplay* r) {
  r->timeline = makeTimeline(r->graph, r->options, r->file);
  addCovariances(r->graph, &r->timeline);
}

// `graph` (sorted by id) replayed one keyframe per node at 4 Hz, as graph_to_bag
// --keyframe-period 0.25 writes it; its first `clean_constraints` are the clean ones (all if not
// given), `name` names it in messages.
inline DatasetReplay graphReplay(toro::PoseGraph graph, const std::string& name,
                                 std::optional<std::size_t> clean_constraints = std::nullopt) {
  DatasetReplay r;
  r.file = name;
  r.graph = std::move(graph);
  r.clean_constraints = clean_constraints.value_or(r.graph.numConstraints());
  r.options.odometry_rate_hz = 4.0;
  r.options.keyframe_period_sec = 0.25;
  makeMessages(&r);
  return r;
}

inline DatasetReplay loadDatasetReplay(const std::string& file) {
  return graphReplay(sortedById(toro::readGraph(toro_test::datasetPath(file))), file);
}

// The shipped replay configuration (every file node a keyframe), default parameters otherwise.
inline PipelineOptions replayOptions() { return loadNodeOptionsFile(kReplayConfig).pipeline; }

// Feeds every message of r to p in stamp order, then toro_offline's final passes.
// `after_odometry` (optional) is called after each odometry message and what it made due.
inline void replayThrough(Pipeline& p, const DatasetReplay& r,
                          const std::function<void(const Pipeline&)>& after_odometry = {}) {
  std::vector<std::pair<ros::Time, std::size_t>> closures;
  ros::Time when;
  for (std::size_t c = 0; c < r.graph.numConstraints(); ++c) {
    if (!r.timeline.is_loop_closure[c]) continue;
    loopClosureMessage(r.graph, r.timeline, c, r.options, &when);
    closures.emplace_back(when, c);
  }
  std::stable_sort(closures.begin(), closures.end(), [](auto& a, auto& b) { return a.first < b.first; });
  // As toro_offline: passes until nothing is due, then a background finish where the node would
  // start one, run inline and merged at once (OfflineRunner::drainSchedule).
  const auto drain = [&] {
    while (p.runScheduledOptimization() && p.hasScheduledWork()) {
    }
    if (!r.background_finishes) return;
    if (std::optional<FinishJob> job = p.takeFinishJob()) p.mergeFinish(runFinishJob(std::move(*job)));
  };
  auto next = closures.begin();
  for (long s = 0; s <= r.timeline.sample_of_keyframe.back(); ++s) {
    const nav_msgs::Odometry odom = odometryAtSample(r.timeline, s, r.options);
    for (; next != closures.end() && next->first < odom.header.stamp; ++next) {
      p.handleLoopClosure(loopClosureMessage(r.graph, r.timeline, next->second, r.options, &when));
      drain();
    }
    p.handleOdometry(odom);
    drain();
    if (after_odometry) after_odometry(p);
  }
  for (; next != closures.end(); ++next) {
    p.handleLoopClosure(loopClosureMessage(r.graph, r.timeline, next->second, r.options, &when));
    drain();
  }
  p.optimize(kFinalPasses, "full");
}

// The dataset's own constraints at the pipeline's final poses (node i of the pipeline is
// keyframe i, as makeTimeline makes one keyframe per file node).
inline toro::PoseGraph cleanGraphAtFinalPoses(const Pipeline& p, const DatasetReplay& r) {
  toro::PoseGraph clean;
  for (std::size_t i = 0; i < r.graph.numNodes(); ++i)
    clean.addNode(r.graph.node(i).id, p.graph().node(i).pose);
  for (std::size_t c = 0; c < r.clean_constraints; ++c) clean.addConstraint(r.graph.constraints()[c]);
  return clean;
}

}  // namespace testing
}  // namespace offline
}  // namespace toro_ros
