// Benchmark client for map_corrector_node (issue 4): publishes odometry at a fixed wall rate along
// a circuit (every message one keyframe, so the graph grows fast) and a loop closure every second
// to the same place one lap earlier; measures, in wall time, from publishing a loop closure to
// receiving the first /tf map->odom that differs from the previous one (the node must run with
// full rounds off, so map->odom changes only through loop closures: see run_node_bench.sh).
// Each revisit is `revisit` loop closures (default 3) between neighbouring keyframes, as a place
// recogniser reports one, sent together: the node's support holds a loop closure until two
// neighbours agree, so a lone one every second would be held and measure nothing; the latency is
// the last one's, which releases the revisit.
//   bench_node_latency <keyframes> <rate_hz> <lap_keyframes> <node_pid> [revisit]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include <ros/ros.h>
#include <tf2_msgs/TFMessage.h>

#include "toro_ros/GetStatus.h"
#include "toro_ros/LoopClosure.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace {

constexpr double kChangeThreshold = 1e-6;

long rssKiB(int pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string key;
  while (in >> key) {
    if (key == "VmRSS:") {
      long v = 0;
      in >> v;
      return v;
    }
    in.ignore(1 << 20, '\n');
  }
  return -1;
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const std::size_t i =
      std::min(v.size() - 1, static_cast<std::size_t>(std::ceil(p * v.size())) - (p > 0 ? 1 : 0));
  return v[i];
}

struct LatencyProbe {
  std::mutex mutex;                                              // guards everything below
  std::deque<std::pair<ros::WallTime, std::size_t>> unanswered;  // publish time, keyframes then
  geometry_msgs::Transform last;
  bool have_last = false;
  std::vector<std::pair<std::size_t, double>> latencies;  // (keyframes when sent, seconds)
  std::vector<std::size_t> superseded;  // keyframes when sent, of revisits a later one's answer passed

  void onTf(const tf2_msgs::TFMessage::ConstPtr& msg) {
    const ros::WallTime now = ros::WallTime::now();
    for (const auto& t : msg->transforms) {
      if (t.header.frame_id != "map" || t.child_frame_id != "odom") continue;
      std::lock_guard<std::mutex> lock(mutex);
      const auto& a = t.transform;
      // New keyframes move map->odom only by rounding (~1e-15); a loop closure by millimetres.
      const double moved =
          std::abs(a.translation.x - last.translation.x) + std::abs(a.translation.y - last.translation.y) +
          std::abs(a.translation.z - last.translation.z) + std::abs(a.rotation.x - last.rotation.x) +
          std::abs(a.rotation.y - last.rotation.y) + std::abs(a.rotation.z - last.rotation.z) +
          std::abs(a.rotation.w - last.rotation.w);
      const bool changed = !have_last || moved > kChangeThreshold;
      last = a;
      have_last = true;
      // A change answers the newest revisit sent before it; older ones still waiting were never
      // answered on their own (attributing it to the oldest would shift every later latency by
      // the revisit period once one revisit is held).
      if (changed && !unanswered.empty()) {
        latencies.emplace_back(unanswered.back().second, (now - unanswered.back().first).toSec());
        unanswered.pop_back();
        for (const auto& u : unanswered) superseded.push_back(u.second);
        unanswered.clear();
      }
    }
  }
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "bench_node_latency");
  if (argc != 5 && argc != 6) {
    std::fprintf(stderr,
                 "usage: bench_node_latency <keyframes> <rate_hz> <lap_keyframes> <node_pid> [revisit]\n");
    return 2;
  }
  const std::size_t revisit = argc == 6 ? std::stoul(argv[5]) : 3;
  const std::size_t total = std::stoul(argv[1]);
  const double rate = std::stod(argv[2]);
  const std::size_t lap = std::stoul(argv[3]);
  const int pid = std::stoi(argv[4]);
  ros::NodeHandle nh;
  LatencyProbe probe;
  ros::Publisher odom_pub = nh.advertise<nav_msgs::Odometry>("odom", 1000);
  ros::Publisher loop_pub = nh.advertise<toro_ros::LoopClosure>("loop_closure", 100);
  ros::Subscriber tf_sub =
      nh.subscribe("/tf", 1000, &LatencyProbe::onTf, &probe, ros::TransportHints().tcpNoDelay());
  ros::AsyncSpinner spinner(1);
  spinner.start();
  while (ros::ok() &&
         (odom_pub.getNumSubscribers() == 0 || loop_pub.getNumSubscribers() == 0 ||
          tf_sub.getNumPublishers() == 0 || !ros::service::exists("/map_corrector/get_status", false)))
    ros::WallDuration(0.05).sleep();
  const long rss_start = rssKiB(pid);

  // Circuit of `lap` keyframes, 1 cm apart; odometry over-reads distance by 1 % and yaw by 0.2 %.
  const double step = 0.01, turn = 2 * M_PI / static_cast<double>(lap);
  toro::Pose3 truth, odom;
  std::vector<toro::Pose3> truths;
  std::vector<ros::Time> stamps;
  truths.reserve(total);
  stamps.reserve(total);
  std::size_t max_queue = 0, keyframes = 0;
  std::map<std::size_t, unsigned long> merged_before;  // revisit (keyframes when sent) -> finishes merged
  std::set<std::size_t> merge_in_window;  // revisits answered when a merge may have been the answer
  std::size_t checked = 0;                // latencies looked at for merges so far
  // Marks the answers since the last call whose revisit saw fewer merges than `merged_now`
  // (the caller holds probe.mutex while the spinner runs).
  auto markMergesUpTo = [&](std::size_t answered, unsigned long merged_now) {
    for (; checked < answered; ++checked) {
      const auto it = merged_before.find(probe.latencies[checked].first);
      if (it == merged_before.end() || merged_now > it->second)
        merge_in_window.insert(probe.latencies[checked].first);
    }
  };
  ros::WallRate pace(rate);
  for (std::size_t i = 0; i < total && ros::ok(); ++i) {
    const ros::Time now = ros::Time::now();
    nav_msgs::Odometry m;
    m.header.stamp = now;
    m.header.frame_id = "odom";
    m.pose.pose = toro_ros::poseToMsg(odom);
    odom_pub.publish(m);
    truths.push_back(truth);
    stamps.push_back(now);
    if (i >= lap + 2 * revisit && i % static_cast<std::size_t>(rate) == 0) {
      // A background finish merged between this revisit's publication and its answer moves
      // map->odom too, so the first change may be the merge's: the merges counted before the
      // revisit and after its answer tell which answers are unambiguous.
      toro_ros::GetStatus before;
      if (ros::service::call("/map_corrector/get_status", before))
        merged_before[i] = before.response.finishes_merged;
      // Keyframes i - 2k (k = revisit - 1 .. 0) to their places a lap earlier, the newest last.
      for (std::size_t k = revisit; k-- > 0;) {
        const std::size_t to = i - 2 * k;
        toro_ros::LoopClosure lc;
        lc.header.stamp = now;
        lc.id_from = lc.id_to = -1;
        lc.stamp_from = stamps[to - lap];
        lc.stamp_to = stamps[to];
        lc.from_T_to = toro_ros::poseToMsg(toro::relativePose(truths[to - lap], truths[to]));
        for (int j = 0; j < 6; ++j) lc.covariance[7 * j] = 1e-4;
        if (k == 0) {
          std::lock_guard<std::mutex> lock(probe.mutex);
          probe.unanswered.emplace_back(ros::WallTime::now(), i);
        }
        loop_pub.publish(lc);
      }
    }
    std::size_t answered = 0;
    {
      std::lock_guard<std::mutex> lock(probe.mutex);
      answered = probe.latencies.size();
    }
    if (answered > checked) {
      toro_ros::GetStatus after;
      if (ros::service::call("/map_corrector/get_status", after)) {
        std::lock_guard<std::mutex> lock(probe.mutex);
        markMergesUpTo(answered, after.response.finishes_merged);
      }
    }
    if (i % (10 * static_cast<std::size_t>(rate)) == 0) {
      toro_ros::GetStatus s;
      if (ros::service::call("/map_corrector/get_status", s)) {
        max_queue = std::max<std::size_t>(max_queue, s.response.queue_length);
        keyframes = s.response.keyframes;
        std::fprintf(
            stderr,
            "sent %zu  keyframes %zu  queue %lu  loop closures %lu applied %lu refused  rss %ld KiB\n", i,
            keyframes, static_cast<unsigned long>(s.response.queue_length),
            static_cast<unsigned long>(s.response.loop_closures_applied),
            static_cast<unsigned long>(s.response.loop_closures_refused), rssKiB(pid));
      }
    }
    truth = truth * toro::Pose3::fromRollPitchYaw(step, 0, 0, 0, 0, turn);
    odom = odom * toro::Pose3::fromRollPitchYaw(1.01 * step, 0, 0, 0, 0, 1.002 * turn);
    pace.sleep();
  }
  ros::WallDuration(2.0).sleep();  // let the last answers arrive (measurement, not synchronisation)
  toro_ros::GetStatus s;
  ros::service::call("/map_corrector/get_status", s);
  const long rss_end = rssKiB(pid);
  spinner.stop();
  markMergesUpTo(probe.latencies.size(), s.response.finishes_merged);  // answered during the last wait
  std::vector<double> all, last_quarter, no_merge, no_merge_last_quarter;
  for (const auto& [k, l] : probe.latencies) {
    all.push_back(l * 1e3);
    if (k >= total * 3 / 4) last_quarter.push_back(l * 1e3);
    if (merge_in_window.count(k)) continue;
    no_merge.push_back(l * 1e3);
    if (k >= total * 3 / 4) no_merge_last_quarter.push_back(l * 1e3);
  }
  std::printf(
      "keyframes %lu, constraints %lu, revisits sent %zu (%zu loop closures each), "
      "loop closures applied %lu, refused %lu, revisits unanswered %zu\n",
      static_cast<unsigned long>(s.response.keyframes), static_cast<unsigned long>(s.response.constraints),
      probe.latencies.size() + probe.unanswered.size() + probe.superseded.size(), revisit,
      static_cast<unsigned long>(s.response.loop_closures_applied),
      static_cast<unsigned long>(s.response.loop_closures_refused),
      probe.unanswered.size() + probe.superseded.size());
  for (const std::size_t k : probe.superseded)
    std::fprintf(stderr, "revisit at keyframe %zu: no answer before the next revisit\n", k);
  for (const auto& u : probe.unanswered)
    std::fprintf(stderr, "revisit at keyframe %zu: no answer by the end\n", u.second);
  std::printf("queue: max seen %zu, at end %lu, dropped %lu\n", max_queue,
              static_cast<unsigned long>(s.response.queue_length),
              static_cast<unsigned long>(s.response.queue_dropped));
  std::printf("latency loop closure -> tf (ms), all: median %.1f  p99 %.1f  max %.1f  (n=%zu)\n",
              percentile(all, 0.5), percentile(all, 0.99),
              all.empty() ? NAN : *std::max_element(all.begin(), all.end()), all.size());
  std::printf("latency, last quarter (%zu..%zu keyframes): median %.1f  p99 %.1f  max %.1f  (n=%zu)\n",
              total * 3 / 4, total, percentile(last_quarter, 0.5), percentile(last_quarter, 0.99),
              last_quarter.empty() ? NAN : *std::max_element(last_quarter.begin(), last_quarter.end()),
              last_quarter.size());
  std::printf(
      "answers with no background finish merged between the revisit and the answer: all median %.1f  p99 "
      "%.1f  max %.1f  (n=%zu); last quarter median %.1f  p99 %.1f  (n=%zu); %zu answers had a merge in "
      "their window (their first change may be the merge's)\n",
      percentile(no_merge, 0.5), percentile(no_merge, 0.99),
      no_merge.empty() ? NAN : *std::max_element(no_merge.begin(), no_merge.end()), no_merge.size(),
      percentile(no_merge_last_quarter, 0.5), percentile(no_merge_last_quarter, 0.99),
      no_merge_last_quarter.size(), merge_in_window.size());
  std::printf("node RSS: %ld KiB at start, %ld KiB at end: %.2f KiB per keyframe\n", rss_start, rss_end,
              s.response.keyframes ? static_cast<double>(rss_end - rss_start) / s.response.keyframes : NAN);
  return 0;
}
