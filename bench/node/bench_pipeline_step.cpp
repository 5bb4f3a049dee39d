// In-process profile of the worker's per-loop-closure work at 20,000 keyframes, on the graph of
// bench_node_latency (a 500-keyframe circuit, a loop closure every 100 keyframes to one lap back):
// the affected TORO pass (+ the g2o chi2 the pipeline computes after it), a Snapshot, and the chi2
// alone, an autosave of the whole graph, and a ~save_graph over it (check + save).  No ROS
// master, no threads.  Usage: bench_pipeline_step [keyframes]
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/graph_directory.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/pipeline.h"

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
  PipelineOptions o;
  o.keyframer.distance_m = 0.005;  // every message a keyframe, as in run_node_bench.sh
  o.optimization.full_iterations = 0;
  Pipeline p(o);
  toro::Pose3 truth, odom;
  std::vector<toro::Pose3> truths;
  std::vector<ros::Time> stamps;
  double affected_ms = 0;
  int affected_n = 0;
  for (int i = 0; i < total; ++i) {
    const ros::Time t(100 + 0.01 * i);
    p.handleOdometry(odometry(t, odom));
    truths.push_back(truth);
    stamps.push_back(t);
    if (i >= lap && i % 100 == 0) {
      LoopClosure lc;
      lc.id_from = lc.id_to = -1;
      lc.stamp_from = stamps[i - lap];
      lc.stamp_to = t;
      lc.from_T_to = poseToMsg(toro::relativePose(truths[i - lap], truth));
      for (int k = 0; k < 6; ++k) lc.covariance[7 * k] = 1e-4;
      p.handleLoopClosure(lc);
      const auto t0 = std::chrono::steady_clock::now();
      p.runScheduledOptimization();
      if (i >= total * 3 / 4) {
        affected_ms += msSince(t0);
        ++affected_n;
      }
    }
    truth = truth * toro::Pose3::fromRollPitchYaw(0.01, 0, 0, 0, 0, 2 * M_PI / lap);
    odom = odom * toro::Pose3::fromRollPitchYaw(0.0101, 0, 0, 0, 0, 1.002 * 2 * M_PI / lap);
  }
  constexpr int kRepeats = 20;
  auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < kRepeats; ++k) p.makeSnapshot();
  const double snapshot_ms = msSince(t0) / kRepeats;
  t0 = std::chrono::steady_clock::now();
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
    for (auto* v : {&save_ms, &check_ms, &service_save_ms}) std::sort(v->begin(), v->end());
  }
  std::printf("keyframes %zu, constraints %zu (chi2 %.3g)\n", p.keyframes().size(),
              p.graph().numConstraints(), sink / kRepeats);
  std::printf("affected pass + chi2, mean over the last quarter's loop closures: %.2f ms (n=%d)\n",
              affected_ms / affected_n, affected_n);
  std::printf("makeSnapshot: %.2f ms   g2oChi2 alone: %.2f ms\n", snapshot_ms, chi2_ms);
  const auto median = [](const char* what, const std::vector<double>& ms) {
    if (ms.size() == 5) std::printf("%s: median %.1f ms of 5 (min %.1f, max %.1f)\n", what, ms[2], ms.front(), ms.back());
  };
  median("saveGraph (autosave)", save_ms);
  median("~save_graph check (GraphDirectory::forSave over the existing pair)", check_ms);
  median("~save_graph save (confined file)", service_save_ms);
  return 0;
}
