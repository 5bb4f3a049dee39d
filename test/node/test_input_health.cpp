// InputHealth: the rules the node's diagnostics apply to its input, sample by sample.
#include <gtest/gtest.h>

#include <diagnostic_msgs/DiagnosticStatus.h>

#include "toro_ros/node/input_health.h"

using namespace toro_ros;
using diagnostic_msgs::DiagnosticStatus;

namespace {

InputSample sample(double now, std::optional<double> last_odometry, std::uint64_t odometry,
                   std::uint64_t refused) {
  InputSample s;
  s.now_sec = now;
  s.start_sec = 0.0;
  s.last_odometry_sec = last_odometry;
  s.counters.odometry_messages = odometry;
  s.counters.odometry_refused = refused;
  if (refused > 0) s.counters.refused_by_reason["odometry: wrong frame"] = refused;
  return s;
}

std::string describe(const std::vector<HealthFinding>& f) {
  std::string out;
  for (const HealthFinding& x : f) out += std::to_string(x.level) + ": " + x.message + "\n";
  return out;
}

bool has(const std::vector<HealthFinding>& f, std::uint8_t level, const std::string& text) {
  for (const HealthFinding& x : f)
    if (x.level == level && x.message.find(text) != std::string::npos) return true;
  return false;
}

}  // namespace

TEST(InputHealth, HealthyInputHasNoFindings) {
  InputHealth h(InputHealthOptions{});
  EXPECT_TRUE(h.update(sample(1.0, 0.95, 20, 0)).empty());
  EXPECT_TRUE(h.update(sample(2.0, 1.95, 40, 0)).empty());
  EXPECT_EQ(h.refusalRate(), 0.0);
}

TEST(InputHealth, StaleOdometryWarnsAfterTheConfiguredTime) {
  InputHealthOptions o;
  o.stale_odometry_sec = 2.0;
  InputHealth h(o);
  EXPECT_TRUE(h.update(sample(1.5, std::nullopt, 0, 0)).empty());  // just started
  const auto none = h.update(sample(2.5, std::nullopt, 0, 0));
  EXPECT_TRUE(has(none, DiagnosticStatus::WARN, "no odometry received in the 2.5 s since the start"))
      << describe(none);
  EXPECT_TRUE(h.update(sample(4.0, 3.9, 10, 0)).empty());
  EXPECT_TRUE(h.update(sample(5.5, 3.9, 10, 0)).empty());  // 1.6 s: not yet
  const auto stale = h.update(sample(30.0, 3.9, 10, 0));
  EXPECT_TRUE(has(stale, DiagnosticStatus::WARN, "no odometry for 26.1 s")) << describe(stale);
  o.stale_odometry_sec = 0.0;  // off
  h.setOptions(o);
  EXPECT_TRUE(h.update(sample(60.0, 3.9, 10, 0)).empty());
}

TEST(InputHealth, AllOdometryRefusedIsAnErrorNamingTheReason) {
  InputHealth h(InputHealthOptions{});
  // 108 of 108 since the start.
  const auto all = h.update(sample(1.0, 0.99, 108, 108));
  ASSERT_FALSE(all.empty());
  EXPECT_EQ(all.front().level, DiagnosticStatus::ERROR);
  EXPECT_TRUE(has(all, DiagnosticStatus::ERROR,
                  "all 108 of 108 odometry messages refused (mostly 'odometry: wrong frame')"))
      << describe(all);
  // Later: some were accepted in between, but the last second's 20 were all refused.
  InputHealth g(InputHealthOptions{});
  g.update(sample(1.0, 0.99, 100, 0));
  const auto window = g.update(sample(2.0, 1.99, 120, 20));
  EXPECT_TRUE(has(window, DiagnosticStatus::ERROR, "all 20 odometry messages of the last 1.0 s refused"))
      << describe(window);
  // ... and 20 refusals/s are above the default 1/s.
  EXPECT_TRUE(has(window, DiagnosticStatus::WARN, "20 refusals/s")) << describe(window);
  EXPECT_DOUBLE_EQ(g.refusalRate(), 20.0);
  // Half refused: no error, but the rate warning.
  const auto half = g.update(sample(3.0, 2.99, 140, 30));
  EXPECT_FALSE(has(half, DiagnosticStatus::ERROR, "")) << describe(half);
  EXPECT_TRUE(has(half, DiagnosticStatus::WARN, "10 refusals/s")) << describe(half);
}

TEST(InputHealth, RefusalsBelowTheRateAreNotWarnedAbout) {
  InputHealthOptions o;
  o.max_refusals_per_sec = 5.0;
  InputHealth h(o);
  h.update(sample(1.0, 0.99, 100, 0));
  EXPECT_TRUE(h.update(sample(3.0, 2.99, 200, 8)).empty());  // 4/s
  EXPECT_DOUBLE_EQ(h.refusalRate(), 4.0);
  EXPECT_FALSE(h.update(sample(4.0, 3.99, 300, 20)).empty());  // 12/s
}

TEST(InputHealth, LoopClosuresNeverAppliedWarn) {
  InputHealth h(InputHealthOptions{});
  InputSample s = sample(1.0, 0.99, 100, 0);
  s.counters.loop_closures_received = 3;
  s.counters.loop_closures_refused = 3;
  s.counters.refused_by_reason["loop closure: no keyframe within tolerance"] = 3;
  const auto f = h.update(s);
  EXPECT_TRUE(has(f, DiagnosticStatus::WARN,
                  "none of the 3 loop closures received was applied (mostly 'loop closure: no keyframe "
                  "within tolerance')"))
      << describe(f);
  s.now_sec = 2.0;
  s.counters.loop_closures_received = 4;
  s.counters.loop_closures_applied = 1;
  EXPECT_TRUE(h.update(s).empty());
}

TEST(InputHealth, AGrowingQueueWarnsAStableOneDoesNot) {
  InputHealth h(InputHealthOptions{});
  double t = 0;
  auto at = [&](std::size_t queue) {
    t += 1.0;
    InputSample s = sample(t, t - 0.01, 100 * static_cast<std::uint64_t>(t), 0);
    s.queue_length = queue;
    return h.update(s);
  };
  for (std::size_t q : {50u, 40u, 60u, 45u}) EXPECT_TRUE(at(q).empty());  // busy but keeping up
  EXPECT_TRUE(at(60).empty());
  EXPECT_TRUE(at(80).empty());
  const auto growing = at(120);  // 45 -> 60 -> 80 -> 120
  EXPECT_TRUE(has(growing, DiagnosticStatus::WARN, "input queue growing (45 -> 60 -> 80 -> 120 messages)"))
      << describe(growing);
  EXPECT_TRUE(at(120).empty());  // stopped growing
  // Small queues growing by one message are noise.
  InputHealth small(InputHealthOptions{});
  for (std::size_t q : {1u, 2u, 3u, 4u}) {
    t += 1.0;
    InputSample s = sample(t, t - 0.01, 0, 0);
    s.queue_length = q;
    EXPECT_TRUE(small.update(s).empty());
  }
}

TEST(InputHealth, OptionsAreValidated) {
  InputHealthOptions o;
  EXPECT_EQ(o.validate(), "");
  o.max_refusals_per_sec = 0;
  EXPECT_NE(o.validate().find("diagnostics_max_refusals_per_sec"), std::string::npos);
  o = InputHealthOptions{};
  o.stale_odometry_sec = -1;
  EXPECT_NE(o.validate().find("diagnostics_stale_odometry_sec"), std::string::npos);
}
