// rostest client for the node's diagnostics about its input (diagnostics.test: stale odometry
// after 1 s, 4 updates a second).  In order: nothing received yet -> WARN; odometry flowing ->
// OK; odometry stopped -> WARN "no odometry for"; odometry that is all refused (wrong frame) ->
// ERROR naming the reason; good odometry again -> OK.
#include <gtest/gtest.h>

#include "../pipeline/drift_scenario.h"
#include "node_test_client.h"

using namespace toro_ros;

namespace {

using Client = toro_ros::testing::NodeTestClient;
using toro_ros::testing::Observed;

Client* client = nullptr;
double next_stamp = 200.0;

// Odometry at 20 Hz of wall time for `seconds`, moving 5 cm per message, in `frame`.
void drive(double seconds, const std::string& frame) {
  static double x = 0;
  for (int i = 0; i < static_cast<int>(seconds * 20); ++i) {
    nav_msgs::Odometry m = toro_ros::testing::odometryMsg(ros::Time(next_stamp),
                                                          toro::Pose3::fromRollPitchYaw(x, 0, 0, 0, 0, 0));
    m.header.frame_id = frame;
    client->publishOdometry(m);
    next_stamp += 0.05;
    x += 0.05;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

// Waits for a diagnostics status of `level` whose message contains every one of `parts`.
bool waitForStatus(std::uint8_t level, const std::vector<std::string>& parts, double timeout_sec = 10.0) {
  return client->waitObserved(
      [&](const Observed& o) {
        if (!o.diagnostics || o.diagnostics->level != level) return false;
        for (const std::string& p : parts)
          if (o.diagnostics->message.find(p) == std::string::npos) return false;
        return true;
      },
      timeout_sec);
}

std::string lastStatus() {
  return client->observedCopy<std::string>([](const Observed& o) {
    return o.diagnostics ? std::to_string(o.diagnostics->level) + " " + o.diagnostics->message : "none";
  });
}

}  // namespace

TEST(Diagnostics, WarnBeforeTheFirstOdometry) {
  ASSERT_TRUE(client->connect());
  EXPECT_TRUE(waitForStatus(diagnostic_msgs::DiagnosticStatus::WARN, {"no odometry received"}))
      << lastStatus();
}

TEST(Diagnostics, OkWhileOdometryFlows) {
  std::thread publisher([] { drive(2.0, "odom"); });
  EXPECT_TRUE(waitForStatus(diagnostic_msgs::DiagnosticStatus::OK, {"running"})) << lastStatus();
  publisher.join();
}

TEST(Diagnostics, WarnWhenOdometryStops) {
  // diagnostics_stale_odometry_sec is 1 s in the test's launch file.
  EXPECT_TRUE(waitForStatus(diagnostic_msgs::DiagnosticStatus::WARN, {"no odometry for"})) << lastStatus();
  EXPECT_EQ(client->status().odometry_messages, 40u);
}

TEST(Diagnostics, ErrorWhenEveryOdometryMessageIsRefused) {
  std::thread publisher([] { drive(2.0, "wheel_odom"); });
  EXPECT_TRUE(waitForStatus(diagnostic_msgs::DiagnosticStatus::ERROR,
                            {"odometry messages of the last", "refused", "odometry: wrong frame"}))
      << lastStatus();
  publisher.join();
  // The refusal rate (20/s) is above diagnostics_max_refusals_per_sec as well; both are said.
  EXPECT_TRUE(client->logged("is in frame 'wheel_odom'"));
}

TEST(Diagnostics, OkAgainWhenOdometryIsAccepted) {
  std::thread publisher([] { drive(2.0, "odom"); });
  EXPECT_TRUE(waitForStatus(diagnostic_msgs::DiagnosticStatus::OK, {"running"})) << lastStatus();
  publisher.join();
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "diagnostics_test_client");
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(2);
  spinner.start();
  Client c;
  client = &c;
  const int result = RUN_ALL_TESTS();
  client = nullptr;
  spinner.stop();
  return result;
}
