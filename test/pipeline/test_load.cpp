// Load test (issue 6): odometry at 1 kHz and loop closures at 50 Hz, driven straight into the
// Pipeline the way the node's worker does (message, then the scheduled optimisation).  Checks that
// every message is accounted for (applied, or refused under a reason), that the pending list stays
// within its bound and that memory grows no faster than the graph.  Sim time: TORO_LOAD_SIM_SEC
// (default 60 s, as the issue asks; bench/load_results.md has the figures).
#include <unistd.h>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;
using toro_ros::testing::odometryMsg;

namespace {

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
constexpr bool kSanitized = true;  // their allocators keep freed memory: RSS says nothing
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif
#else
constexpr bool kSanitized = false;
#endif

double residentMiB() {
  std::ifstream statm("/proc/self/statm");
  long pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

double simSeconds() {
  const char* env = std::getenv("TORO_LOAD_SIM_SEC");
  return env != nullptr ? std::atof(env) : 60.0;
}

// A circle of radius 10 m at 1 m/s; odometry over-reads distance by 1 %.
toro::Pose3 truthAt(double t) { return toro::Pose3::fromRollPitchYaw(10 * std::sin(t / 10), 10 - 10 * std::cos(t / 10), 0, 0, 0, t / 10); }
toro::Pose3 odomAt(double t) { return toro::Pose3::fromRollPitchYaw(10 * std::sin(1.01 * t / 10), 10 - 10 * std::cos(1.01 * t / 10), 0, 0, 0, 1.01 * t / 10); }

struct Lcg {  // deterministic, portable
  std::uint64_t state = 12345;
  std::uint64_t next() { return state = state * 6364136223846793005ULL + 1442695040888963407ULL; }
  double uniform() { return (next() >> 11) * (1.0 / 9007199254740992.0); }
};

}  // namespace

TEST(Load, OdometryAt1kHzLoopClosuresAt50HzAllAccountedForAndBounded) {
  PipelineOptions o;
  o.keyframer.distance_m = 0.5;
  o.keyframer.angle_rad = 0.3;
  const double start = 1000.0, duration = simSeconds();
  int shown = 0;
  Pipeline p(o, [&shown](const std::string& w) { if (std::getenv("TORO_LOAD_VERBOSE") && shown++ < 12) std::printf("%s\n", w.c_str()); });
  Lcg rng;
  std::vector<double> applied_stamps;  // stamps of keyframes made for loop closures (exact matches)
  std::uint64_t odometry_sent = 0, loop_closures_sent = 0, invalid_sent = 0, unknown_sent = 0;
  std::size_t max_pending = 0;
  const double rss_start = residentMiB();
  double rss_tenth = 0.0;
  std::size_t keyframes_tenth = 0;
  const long steps = std::lround(duration * 1000);
  for (long i = 1; i <= steps; ++i) {
    const double t = i * 1e-3;
    p.handleOdometry(odometryMsg(ros::Time(start + t), odomAt(t)));
    ++odometry_sent;
    if (i % 20 == 0) {
      // Most loop closures tie "now" to an earlier loop-closure stamp with the true relative pose;
      // every 10th names a stamp before the first odometry (refused), every 25th has a NaN pose.
      LoopClosure lc;
      lc.id_from = lc.id_to = -1;
      lc.stamp_to = ros::Time(start + t);
      // (the first loop closures have no earlier stamp to name and also name the unknown one).
      const bool unknown = applied_stamps.empty() || i % 200 == 0, invalid = i % 500 == 0;
      const double from = unknown ? start - 50.0
                                  : applied_stamps[static_cast<std::size_t>(rng.uniform() * applied_stamps.size())];
      lc.stamp_from = ros::Time(from);
      lc.from_T_to = poseToMsg(toro::relativePose(truthAt(from - start), truthAt(t)));
      for (int k = 0; k < 6; ++k) lc.covariance[7 * k] = k < 3 ? 1e-4 : 1e-5;
      if (invalid) lc.from_T_to.position.x = std::nan("");
      unknown_sent += unknown && !invalid;
      invalid_sent += invalid;
      p.handleLoopClosure(lc);
      ++loop_closures_sent;
      if (!invalid) applied_stamps.push_back(start + t);  // its keyframe exists either way
    }
    p.runScheduledOptimization();
    max_pending = std::max(max_pending, p.status().pending_loop_closures);
    if (i == steps / 10) {
      rss_tenth = residentMiB();
      keyframes_tenth = p.status().keyframes;
    }
  }
  const PipelineStatus s = p.status();
  const PipelineCounters& c = s.counters;
  const double rss_end = residentMiB();
  std::printf("load: %.0f s sim, %llu odometry, %llu loop closures -> %zu keyframes, %zu constraints, "
              "%llu applied, %llu refused, %zu pending (max %zu), %llu passes; RSS %.1f -> %.1f -> %.1f MiB\n",
              duration, static_cast<unsigned long long>(odometry_sent),
              static_cast<unsigned long long>(loop_closures_sent), s.keyframes, s.constraints,
              static_cast<unsigned long long>(c.loop_closures_applied),
              static_cast<unsigned long long>(c.loop_closures_refused), s.pending_loop_closures, max_pending,
              static_cast<unsigned long long>(c.optimization_passes), rss_start, rss_tenth, rss_end);
  for (const auto& [reason, n] : c.refused_by_reason) std::printf("  %s: %llu\n", reason.c_str(), static_cast<unsigned long long>(n));

  // Every message accounted for.
  EXPECT_EQ(c.odometry_messages, odometry_sent);
  EXPECT_EQ(c.odometry_refused, 0u);
  EXPECT_EQ(c.loop_closures_received, loop_closures_sent);
  EXPECT_EQ(c.loop_closures_applied + c.loop_closures_refused + s.pending_loop_closures, loop_closures_sent);
  EXPECT_EQ(c.refused_by_reason.at("loop closure: invalid message"), invalid_sent);
  EXPECT_EQ(c.refused_by_reason.at("loop closure: no keyframe within tolerance"), unknown_sent);
  EXPECT_EQ(c.loop_closures_refused, invalid_sent + unknown_sent);
  EXPECT_EQ(s.constraints, s.keyframes - 1 + c.loop_closures_applied);
  // Loop closures name "now": none waits, so the pending list never grows.
  EXPECT_LE(max_pending, o.matcher.max_pending);
  EXPECT_EQ(s.pending_loop_closures, 0u);
  // The map stays right: the newest keyframe is near the truth (odometry alone is off by 1 %).
  const toro::Pose3 newest = p.graph().pose(p.keyframes().newest().id);
  const double t_end = (p.keyframes().newest().stamp.toSec() - start);
  const double corrected_error = (newest.translation() - truthAt(t_end).translation()).norm();
  const double odometry_error = (odomAt(t_end).translation() - truthAt(t_end).translation()).norm();
  std::printf("load: newest keyframe %.3f m from the truth (odometry %.3f m)\n", corrected_error, odometry_error);
  EXPECT_LT(corrected_error, 0.5 * odometry_error);
  // Memory grows with the graph, not with the messages: after the first tenth, at most 16 KiB
  // per new keyframe (the graph, the tree, the odometry history of the last 60 s).
  if (!kSanitized) {
    const double per_keyframe_kib = (rss_end - rss_tenth) * 1024.0 / std::max<std::size_t>(1, s.keyframes - keyframes_tenth);
    std::printf("load: %.2f KiB of RSS per keyframe after the first tenth\n", per_keyframe_kib);
    EXPECT_LT(per_keyframe_kib, 16.0);
  }
}
