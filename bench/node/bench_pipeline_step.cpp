// In-process profile of the worker's per-loop-closure work at 20,000 keyframes, on the graph of
// bench_node_latency (a 500-keyframe circuit, a loop closure every 100 keyframes to one lap back):
// the affected TORO pass (+ the g2o chi2 the pipeline computes after it), the Snapshot after it
// and after each new keyframe (what the worker makes at every revision), the whole-graph chi2
// alone, an autosave of the whole graph, a ~save_graph over it (check + save), the ~graph message
// and ~path + ~graph_markers (built and serialised, as published at most every
// visualizationPeriodSec); then, for 25 more loop closures, the merge of a background finish and
// the snapshot after it.  No ROS master, no threads.
// Usage: bench_pipeline_step [keyframes] [keyframes per loop closure (100; run_node_bench.sh at
// 250 Hz makes one every 250)]
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <ros/serialization.h>

#include "toro_ros/core/metrics.h"
#include "toro_ros/node/graph_message.h"
#include "toro_ros/pipeline/graph_directory.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/pipeline.h"
#include "toro_ros/pipeline/visualization.h"

using namespace toro_ros;

namespace {

double msSince(std::chrono::steady_clock::time_point t0) {
  return 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

nav_msgs::Odometry odometry(const ros::Time& t, const toro::Pose3& pose) {
  nav_msgs::Odometry m;
  m.header.stamp = t;
  m.pose.pose = poseToMsg(pose);
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  const int total = argc > 1 ? std::stoi(argv[1]) : 20000;
  const int lap = 500;
  const int loop_every = argc > 2 ? std::stoi(argv[2]) : 100;
  PipelineOptions o;
  o.keyframer.distance_m = 0.005;  // every message a keyframe, as in run_node_bench.sh
  o.optimization.full_iterations = 0;
  // Each loop closure applied at once: held for support, a lone one (one per loop_every keyframes,
  // nothing near it) waits for a finish to release it, and without finishes the passes timed
  // below would have nothing to do (they measured 0.00 ms that way).
  o.optimization.hold_until_supported = false;
  Pipeline p(o);
  toro::Pose3 truth, odom;
  std::vector<toro::Pose3> truths;
  std::vector<ros::Time> stamps;
  double affected_ms = 0, after_pass_snapshot_ms = 0, keyframe_snapshot_ms = 0;
  int affected_n = 0, keyframe_n = 0;
  // Background finishes, after the figures below (so those stay comparable with earlier runs): for
  // kMergesMeasured more loop closures a finish is taken after the pass, run here (not timed: the
  // node runs it in a thread of its own) and merged one keyframe later (timed, with the snapshot
  // after it: what the worker spends on a merge).
  constexpr int kMergesMeasured = 25;
  std::optional<FinishOutcome> finished;
  std::vector<double> merge_ms, merge_snapshot_ms;
  // One message (every one a keyframe), and a loop closure every loop_every.
  const auto drive = [&](int i) {
    const bool measured = i >= total * 3 / 4 && i < total;
    const ros::Time t(100 + 0.01 * i);
    p.handleOdometry(odometry(t, odom));
    if (finished) {
      const auto t0 = std::chrono::steady_clock::now();
      const bool merged = p.mergeFinish(*finished);
      const double ms = msSince(t0);
      const auto t1 = std::chrono::steady_clock::now();
      p.makeSnapshot();
      if (merged) {
        merge_ms.push_back(ms);
        merge_snapshot_ms.push_back(msSince(t1));
      }
      finished.reset();
    }
    {
      // The worker makes a snapshot at every revision: here every message is a keyframe.
      const auto t0 = std::chrono::steady_clock::now();
      p.makeSnapshot();
      if (measured) {
        keyframe_snapshot_ms += msSince(t0);
        ++keyframe_n;
      }
    }
    truths.push_back(truth);
    stamps.push_back(t);
    if (i >= lap && i % loop_every == 0) {
      LoopClosure lc;
      lc.id_from = lc.id_to = -1;
      lc.stamp_from = stamps[i - lap];
      lc.stamp_to = t;
      lc.from_T_to = poseToMsg(toro::relativePose(truths[i - lap], truth));
      for (int k = 0; k < 6; ++k) lc.covariance[7 * k] = 1e-4;
      p.handleLoopClosure(lc);
      const auto t0 = std::chrono::steady_clock::now();
      p.runScheduledOptimization();
      const double pass_ms = msSince(t0);
      const auto t1 = std::chrono::steady_clock::now();
      p.makeSnapshot();
      if (measured) {
        affected_ms += pass_ms;
        after_pass_snapshot_ms += msSince(t1);
        ++affected_n;
      }
      if (i >= total) {
        if (std::optional<FinishJob> job = p.takeFinishJob()) finished = runFinishJob(std::move(*job));
      }
    }
    truth = truth * toro::Pose3::fromRollPitchYaw(0.01, 0, 0, 0, 0, 2 * M_PI / lap);
    odom = odom * toro::Pose3::fromRollPitchYaw(0.0101, 0, 0, 0, 0, 1.002 * 2 * M_PI / lap);
  };
  for (int i = 0; i < total; ++i) drive(i);
  constexpr int kRepeats = 20;
  auto t0 = std::chrono::steady_clock::now();
  double sink = 0;
  for (int k = 0; k < kRepeats; ++k) sink += toro::g2oChi2(p.graph());
  const double chi2_ms = msSince(t0) / kRepeats;
  // An autosave: graph + sidecar to temporary files, fsync, rename (what the worker does every
  // autosave_period_sec); median of 5.
  // Then ~save_graph over that save: GraphDirectory::forSave (resolve the name, open the
  // directory, read the existing graph and sidecar to check they may be replaced) and the save.
  char dir[] = "/tmp/toro_bench_save_XXXXXX";
  std::vector<double> save_ms, check_ms, service_save_ms;
  if (mkdtemp(dir) != nullptr) {
    for (int k = 0; k < 5; ++k) {
      t0 = std::chrono::steady_clock::now();
      const std::string error = p.saveGraph(std::string(dir) + "/map.g2o");
      save_ms.push_back(msSince(t0));
      if (!error.empty()) std::printf("save failed: %s\n", error.c_str());
    }
    const GraphDirectory graphs(dir);
    for (int k = 0; k < 5; ++k) {
      t0 = std::chrono::steady_clock::now();
      const ConfinedFile target = graphs.forSave("map.g2o");
      check_ms.push_back(msSince(t0));
      if (!target.file) {
        std::printf("forSave refused: %s\n", target.error.c_str());
        break;
      }
      t0 = std::chrono::steady_clock::now();
      const std::string error = p.saveGraph(*target.file);
      service_save_ms.push_back(msSince(t0));
      if (!error.empty()) std::printf("save failed: %s\n", error.c_str());
    }
    std::filesystem::remove_all(dir);
  }
  // ~graph: built from a snapshot and the pipeline, then serialised (roscpp does that in publish()).
  const std::shared_ptr<const Snapshot> snapshot = p.makeSnapshot();
  std::uint32_t graph_bytes = 0;
  unsigned byte_sink = 0;  // keeps the serialisation from being optimised away
  t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < kRepeats; ++k) {
    const PoseGraph msg = graphMessage(p, *snapshot, "map");
    graph_bytes = ros::serialization::serializationLength(msg);
    std::vector<std::uint8_t> buffer(graph_bytes);
    ros::serialization::OStream stream(buffer.data(), graph_bytes);
    ros::serialization::serialize(stream, msg);
    byte_sink += buffer[graph_bytes / 2];
  }
  const double graph_ms = msSince(t0) / kRepeats;
  // ~path and ~graph_markers from the snapshot, serialised (both latched: roscpp serialises them
  // at every publish).
  std::uint32_t visualization_bytes = 0;
  t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < kRepeats; ++k) {
    const nav_msgs::Path path = pathFromSnapshot(*snapshot, "map", ros::Time(1));
    const visualization_msgs::MarkerArray markers =
        markersFromSnapshot(*snapshot, "map", ros::Time(1), MarkerOptions{}, false);
    visualization_bytes = ros::serialization::serializationLength(path) + ros::serialization::serializationLength(markers);
    std::vector<std::uint8_t> buffer(visualization_bytes);
    ros::serialization::OStream stream(buffer.data(), visualization_bytes);
    ros::serialization::serialize(stream, path);
    ros::serialization::serialize(stream, markers);
    byte_sink += buffer[visualization_bytes / 2];
  }
  const double visualization_ms = msSince(t0) / kRepeats;
  const std::uint64_t applied = p.status().counters.loop_closures_applied;
  std::printf("keyframes %zu, constraints %zu, loop closures applied %llu (chi2 %.3g)\n",
              p.keyframes().size(), p.graph().numConstraints(), static_cast<unsigned long long>(applied),
              sink / kRepeats);
  if (applied == 0) std::printf("WARNING: no loop closure was applied: the timings below measure nothing\n");
  std::printf("affected pass + chi2, mean over the last quarter's loop closures: %.2f ms (n=%d)\n",
              affected_ms / affected_n, affected_n);
  std::printf("makeSnapshot after that pass: %.3f ms, after a new keyframe: %.3f ms (mean of %d)   g2oChi2 alone: %.2f ms\n",
              after_pass_snapshot_ms / affected_n, keyframe_snapshot_ms / keyframe_n, keyframe_n, chi2_ms);
  std::printf("~path + ~graph_markers: build + serialise %.2f ms, %u bytes (%.3f ms per 1,000 keyframes)\n",
              visualization_ms, visualization_bytes, visualization_ms * 1e3 / static_cast<double>(p.keyframes().size()));
  std::printf("~graph message: build + serialise %.2f ms, %u bytes (%.0f per keyframe) [%u]\n", graph_ms, graph_bytes,
              static_cast<double>(graph_bytes) / static_cast<double>(p.keyframes().size()), byte_sink % 2);
  for (int i = total; i < total + kMergesMeasured * loop_every; ++i) drive(i);
  const auto median = [](const char* what, std::vector<double> ms) {
    if (ms.empty()) return;
    std::sort(ms.begin(), ms.end());
    std::printf("%s: median %.1f ms of %zu (min %.1f, max %.1f)\n", what, ms[ms.size() / 2], ms.size(),
                ms.front(), ms.back());
  };
  median("mergeFinish of a background finish (25 more loop closures)", merge_ms);
  median("makeSnapshot after that merge", merge_snapshot_ms);
  median("saveGraph (autosave)", save_ms);
  median("~save_graph check (GraphDirectory::forSave over the existing pair)", check_ms);
  median("~save_graph save (confined file)", service_save_ms);
  return 0;
}
